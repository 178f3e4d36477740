"""Stroke ordering: minimise pen-up travel from and back to the machine's start position.

The strokes and the start position form one closed tour: start -> stroke -> ... -> stroke
-> start. Each stroke may be cut in either direction. The tour is built in two steps:

1. Greedy nearest neighbour from the start position, with reversal allowed: from the
   current tool position go to the nearest endpoint of any stroke not yet cut, cut the
   stroke to its other end, repeat. A k-d tree (scipy ``cKDTree``) of all endpoints gives
   each endpoint's ``neighbours`` nearest endpoints once; a second tree of the endpoints
   still free answers the rare lookups whose near neighbours are all used.
2. Local search (:mod:`scratchfab.toolpath.local_search`, compiled with numba): 2-opt
   (reversing a stretch of the tour, which also turns its strokes round) and Or-opt
   (moving a chain of 1-3 strokes into another gap, either way round), over neighbour
   lists, until no move improves or the work cap ``passes * N`` is spent.

The result is never worse than the input order (it is returned instead if it is shorter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from scratchfab.toolpath.local_search import improve


@dataclass(frozen=True)
class OrderOptions:
    """Tuning of :func:`order_strokes`.

    Attributes:
        neighbours: Candidate endpoints considered per endpoint (greedy and local search).
        passes: Cap on local-search work, in visits of every stroke; 0 = greedy only.
        kicks_per_stroke: Perturbation trials after the local optimum, per stroke.
        kicks: Perturbation trials in all (overrides ``kicks_per_stroke``).
        seed: Seed of the perturbations (the result is deterministic for a seed).
        min_gain_mm: Moves that save less than this are ignored (rounding noise).
    """

    neighbours: int = 10
    passes: int = 50
    kicks_per_stroke: float = 25.0
    kicks: int | None = None
    seed: int = 0
    min_gain_mm: float = 1e-9


@dataclass(frozen=True)
class OrderResult:
    """An ordering of N strokes.

    Attributes:
        order: (N,) stroke indices in cut order.
        reverse: (N,) True where the stroke is cut from its p1 to its p0.
        travel_mm: Pen-up travel of the result, from the start and back to it.
        travel_input_mm: The same for the input order and directions.
        travel_greedy_mm: The same after the greedy step only.
        moves: Improving moves and perturbation trials kept by the local search.
        kept_input: True if the input order was shorter and is returned unchanged.
    """

    order: np.ndarray
    reverse: np.ndarray
    travel_mm: float
    travel_input_mm: float
    travel_greedy_mm: float
    moves: int
    kept_input: bool


def tour_travel(p0: np.ndarray, p1: np.ndarray, start: np.ndarray) -> float:
    """Pen-up travel of cutting p0[k] -> p1[k] in index order, from ``start`` and back to it."""
    if len(p0) == 0:
        return 0.0
    stops = np.vstack([start[None, :], p1])
    goes = np.vstack([p0, start[None, :]])
    return float(np.hypot(*(goes - stops).T).sum())


class _Tour:
    """A closed tour over N strokes and the depot (the start position), as arrays.

    Endpoint ids: 2k is stroke k's p0, 2k+1 its p1, 2N the depot. ``ent[p]`` is the
    endpoint where the item at tour position p is entered; it is left at ``exit_of(ent)``.
    """

    def __init__(self, points: np.ndarray, ent: np.ndarray) -> None:
        self.points = points
        self.depot = len(points) - 1
        self.ent = ent

    def exits(self) -> np.ndarray:
        ent = self.ent
        return np.where(ent == self.depot, ent, ent ^ 1)

    def edge_lengths(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Entry points A, exit points B and edge lengths L[p] = |B[p] -> A[p+1]|."""
        a = self.points[self.ent]
        b = self.points[self.exits()]
        lengths = np.hypot(*(np.roll(a, -1, axis=0) - b).T)
        return a, b, lengths

    def travel(self) -> float:
        return float(self.edge_lengths()[2].sum())

    def positions(self) -> tuple[np.ndarray, np.ndarray]:
        """Per endpoint: its tour position if it is an entry (else -1), and if it is an exit."""
        m = len(self.ent)
        pos_a = np.full(len(self.points), -1, dtype=np.int64)
        pos_b = np.full(len(self.points), -1, dtype=np.int64)
        pos_a[self.ent] = np.arange(m)
        pos_b[self.exits()] = np.arange(m)
        return pos_a, pos_b

    def stroke_order(self) -> tuple[np.ndarray, np.ndarray]:
        """Strokes in cut order from the depot, and whether each is cut p1 -> p0."""
        ent = np.roll(self.ent, -int(np.flatnonzero(self.ent == self.depot)[0]))[1:]
        return ent >> 1, (ent & 1).astype(bool)


def _greedy(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Entry endpoints in greedy nearest-neighbour order from the depot (the last point)."""
    n_end = len(points) - 1
    n = n_end // 2
    near = neighbours.tolist()
    used = bytearray(n)
    free_tree: cKDTree | None = None
    free_ids = np.empty(0, dtype=np.int64)
    entries = np.empty(n, dtype=np.int64)
    cur = n_end
    for step in range(n):
        nxt = -1
        for f in near[cur]:
            if f < n_end and not used[f >> 1]:
                nxt = f
                break
        if nxt < 0:
            while True:
                if free_tree is None:
                    free_mask = np.repeat(np.frombuffer(bytes(used), dtype=np.uint8) == 0, 2)
                    free_ids = np.flatnonzero(free_mask)
                    free_tree = cKDTree(points[free_ids])
                size = len(free_ids)
                for k in (16, 256):
                    _, hits = free_tree.query(points[cur], k=min(k, size))
                    for h in np.atleast_1d(hits).tolist():
                        f = int(free_ids[h])
                        if not used[f >> 1]:
                            nxt = f
                            break
                    if nxt >= 0 or k >= size:
                        break
                if nxt >= 0:
                    break
                free_tree = None
        used[nxt >> 1] = 1
        entries[step] = nxt
        cur = nxt ^ 1
    return entries


def order_strokes(
    p0: np.ndarray,
    p1: np.ndarray,
    start: tuple[float, float] | np.ndarray,
    options: OrderOptions | None = None,
) -> OrderResult:
    """Order strokes to minimise pen-up travel from ``start`` and back (see module docstring).

    Args:
        p0: (N, 2) stroke start points in mm.
        p1: (N, 2) stroke end points in mm.
        start: The machine's start position (x, y) in mm.
        options: Tuning; defaults to :class:`OrderOptions`.

    Returns:
        The order, per-stroke reversal and travel figures.
    """
    opts = options or OrderOptions()
    p0 = np.asarray(p0, dtype=np.float64).reshape(-1, 2)
    p1 = np.asarray(p1, dtype=np.float64).reshape(-1, 2)
    origin = np.asarray(start, dtype=np.float64).reshape(2)
    n = len(p0)
    travel_input = tour_travel(p0, p1, origin)
    identity = np.arange(n)
    no_flip = np.zeros(n, dtype=bool)
    if n < 2:
        return OrderResult(identity, no_flip, travel_input, travel_input, travel_input, 0, True)
    points = np.empty((2 * n + 1, 2))
    points[0 : 2 * n : 2] = p0
    points[1 : 2 * n : 2] = p1
    points[2 * n] = origin
    k = min(opts.neighbours, 2 * n - 1)
    _, near = cKDTree(points[: 2 * n]).query(points, k=k + 1, workers=-1)
    entries = _greedy(points, near)
    tour = _Tour(points, np.concatenate([[2 * n], entries]))
    travel_greedy = tour.travel()
    # Local search uses the neighbours other than the endpoint itself.
    own = near == np.arange(len(points))[:, None]
    cand = np.take_along_axis(near, np.argsort(own, axis=1, kind="stable"), axis=1)[:, :k]
    cand = np.ascontiguousarray(np.where(cand >= 2 * n, 2 * n, cand), dtype=np.int64)
    rounds = 0
    if opts.passes > 0:
        ent = np.ascontiguousarray(tour.ent, dtype=np.int64)
        if opts.kicks is None:
            # A trial's 2-opt reversals grow with N: cap the work at about 2e8 items.
            kicks = min(int(opts.kicks_per_stroke * n), 200_000_000 // (n + 1))
        else:
            kicks = opts.kicks
        rounds = improve(points, ent, cand, opts.passes, kicks, opts.seed, n + 1, opts.min_gain_mm)
        tour.ent = ent
    order, reverse = tour.stroke_order()
    travel = tour_travel(
        np.where(reverse[:, None], p1[order], p0[order]),
        np.where(reverse[:, None], p0[order], p1[order]),
        origin,
    )
    if travel_input <= travel:
        return OrderResult(
            identity, no_flip, travel_input, travel_input, travel_greedy, rounds, True
        )
    return OrderResult(order, reverse, travel, travel_input, travel_greedy, rounds, False)
