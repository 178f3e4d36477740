"""Stroke ordering: minimise pen-up travel from and back to the machine's start position.

The strokes and the start position form one closed tour: start -> stroke -> ... -> stroke
-> start. Each stroke may be cut in either direction. The tour is built in two steps:

1. Greedy nearest neighbour from the start position, with reversal allowed: from the
   current tool position go to the nearest endpoint of any stroke not yet cut, cut the
   stroke to its other end, repeat. A k-d tree (scipy ``cKDTree``) of all endpoints gives
   each endpoint's ``neighbours`` nearest endpoints once; a second tree of the endpoints
   still free answers the rare lookups whose near neighbours are all used.
2. Local search in rounds ("passes"), each vectorised with numpy over the whole tour:
   a 2-opt round reverses disjoint stretches of the tour (which also flips the strokes in
   them), an Or-opt round moves single strokes, either way round, into another gap.
   Candidate moves only join endpoints that are near neighbours; every round takes the
   best non-overlapping improving moves at once. Rounds stop when neither finds an
   improvement or after ``passes`` rounds.

The result is never worse than the input order (it is returned instead if it is shorter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class OrderOptions:
    """Tuning of :func:`order_strokes`.

    Attributes:
        neighbours: Candidate endpoints considered per endpoint (greedy and local search).
        passes: Cap on local-search rounds (each a 2-opt or an Or-opt round); 0 = greedy only.
        min_gain_mm: Moves that save less than this are ignored (rounding noise).
    """

    neighbours: int = 10
    passes: int = 60
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
        passes: Local-search rounds run.
        kept_input: True if the input order was shorter and is returned unchanged.
    """

    order: np.ndarray
    reverse: np.ndarray
    travel_mm: float
    travel_input_mm: float
    travel_greedy_mm: float
    passes: int
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


def _select(starts: np.ndarray, lengths: np.ndarray, m: int, cap: int) -> np.ndarray:
    """Greedily pick candidates (in the given order) whose cyclic edge ranges do not overlap."""
    occupied = bytearray(m)
    picked = []
    for c, (s, ln) in enumerate(zip(starts.tolist(), lengths.tolist(), strict=True)):
        e = s + ln
        if e <= m:
            if occupied.find(1, s, e) != -1:
                continue
            occupied[s:e] = b"\x01" * ln
        else:
            if occupied.find(1, s, m) != -1 or occupied.find(1, 0, e - m) != -1:
                continue
            occupied[s:m] = b"\x01" * (m - s)
            occupied[0 : e - m] = b"\x01" * (e - m)
        picked.append(c)
        if len(picked) >= cap:
            break
    return np.asarray(picked, dtype=np.int64)


def _two_opt_round(tour: _Tour, near: np.ndarray, min_gain: float) -> int:
    """One batch of disjoint 2-opt reversals between near endpoints; returns the moves made."""
    m = len(tour.ent)
    a, b, lengths = tour.edge_lengths()
    pos_a, pos_b = tour.positions()
    src = np.repeat(np.arange(len(tour.points)), near.shape[1])
    dst = near.ravel()
    # B-B pairs join exits (edges p, q); A-A pairs join entries (edges p-1, q-1).
    pb, qb = pos_b[src], pos_b[dst]
    pa, qa = pos_a[src], pos_a[dst]
    keep_b = (pb >= 0) & (qb >= 0) & (pb != qb)
    keep_a = (pa >= 0) & (qa >= 0) & (pa != qa)
    i = np.concatenate([pb[keep_b], (pa[keep_a] - 1) % m])
    j = np.concatenate([qb[keep_b], (qa[keep_a] - 1) % m])
    i, j = np.minimum(i, j), np.maximum(i, j)
    i1, j1 = (i + 1) % m, (j + 1) % m
    gain = lengths[i] + lengths[j] - np.hypot(*(b[i] - b[j]).T) - np.hypot(*(a[i1] - a[j1]).T)
    good = gain > min_gain
    if not np.any(good):
        return 0
    i, j, gain = i[good], j[good], gain[good]
    rank = np.lexsort((j, i, -gain))
    i, j = i[rank], j[rank]
    span = j - i
    short = span <= m // 2
    # Footprint: the edges a reversal touches, i..j, or the complementary arc j..i+m.
    f_start = np.where(short, i, j)
    f_len = np.where(short, span, m - span) + 1
    picked = _select(f_start, f_len, m, cap=m)
    if len(picked) == 0:
        return 0
    f_start, f_len = f_start[picked], f_len[picked]
    rot = int(f_start[0])
    ent = np.roll(tour.ent, -rot)
    ext = np.where(ent == tour.depot, ent, ent ^ 1)
    arc_start = (f_start - rot) % m + 1
    arc_len = f_len - 1
    total = int(arc_len.sum())
    offsets = np.repeat(np.cumsum(arc_len) - arc_len, arc_len)
    idx = np.repeat(arc_start, arc_len) + np.arange(total) - offsets
    key = np.arange(m)
    key[idx] = np.repeat(2 * arc_start + arc_len - 1, arc_len) - idx
    ent[idx] = ext[idx]
    new = np.empty_like(ent)
    new[key] = ent
    tour.ent = new
    return len(picked)


def _or_opt_round(tour: _Tour, near: np.ndarray, min_gain: float) -> int:
    """One batch of single-stroke moves into a gap beside a near endpoint; returns moves made."""
    m = len(tour.ent)
    depot = tour.depot
    a, b, lengths = tour.edge_lengths()
    pos_a, pos_b = tour.positions()
    pts = tour.points
    k = near.shape[1]
    src = np.repeat(np.arange(depot), k)
    dst = near[:depot].ravel()
    p = np.maximum(pos_a[src], pos_b[src])
    prev = (p - 1) % m
    nxt = (p + 1) % m
    removal = lengths[prev] + lengths[p] - np.hypot(*(a[nxt] - b[prev]).T)
    # Next to an exit at q: gap q, enter at src. Next to an entry at q: gap q-1, leave at src.
    after_exit = pos_b[dst] >= 0
    gap = np.where(after_exit, pos_b[dst], (pos_a[dst] - 1) % m)
    entry = np.where(after_exit, src, src ^ 1)
    cost = (
        np.hypot(*(pts[entry] - b[gap]).T)
        + np.hypot(*(a[(gap + 1) % m] - pts[entry ^ 1]).T)
        - lengths[gap]
    )
    gain = removal - cost
    valid = (gap != prev) & (gap != p) & ((dst >> 1) != (src >> 1))
    good = valid & (gain > min_gain)
    if not np.any(good):
        return 0
    p, gap, entry, gain = p[good], gap[good], entry[good], gain[good]
    rank = np.lexsort((gap, p, -gain))
    p, gap, entry = p[rank], gap[rank], entry[rank]
    occupied = bytearray(m)
    picked = []
    for c, (pp, gg) in enumerate(zip(p.tolist(), gap.tolist(), strict=True)):
        pv = pp - 1 if pp > 0 else m - 1
        if occupied[pv] or occupied[pp] or occupied[gg]:
            continue
        occupied[pv] = occupied[pp] = occupied[gg] = 1
        picked.append(c)
    sel = np.asarray(picked, dtype=np.int64)
    key = 2 * np.arange(m)
    key[p[sel]] = 2 * gap[sel] + 1
    ent = tour.ent.copy()
    ent[p[sel]] = entry[sel]
    tour.ent = ent[np.argsort(key, kind="stable")]
    return len(sel)


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
    _, near = cKDTree(points[: 2 * n]).query(points, k=k + 1)
    entries = _greedy(points, near)
    tour = _Tour(points, np.concatenate([[2 * n], entries]))
    travel_greedy = tour.travel()
    # Local search uses the neighbours other than the endpoint itself.
    own = near == np.arange(len(points))[:, None]
    cand = np.where(own, near[:, -1:], near)[:, :k]
    cand = np.where(cand >= 2 * n, 2 * n, cand)
    rounds = 0
    idle = 0
    while rounds < opts.passes and idle < 2:
        step = _two_opt_round if rounds % 2 == 0 else _or_opt_round
        moved = step(tour, cand, opts.min_gain_mm)
        rounds += 1
        idle = 0 if moved else idle + 1
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
