"""Stroke ordering: minimise pen-up travel from and back to the machine's start position.

The strokes and the start position form one closed tour: start -> stroke -> ... -> stroke
-> start. Each stroke may be cut in either direction. The tour is built in three steps:

1. Greedy nearest neighbour from the start position, with reversal allowed: from the
   current tool position go to the nearest endpoint of any stroke not yet cut, cut the
   stroke to its other end, repeat. A k-d tree (scipy ``cKDTree``) of all endpoints gives
   each endpoint's ``neighbours`` nearest endpoints once; a second tree of the endpoints
   still free answers the rare lookups whose near neighbours are all used.
2. Local search (:mod:`scratchfab.toolpath.local_search`, compiled with numba):
   Lin-Kernighan chains of up to ``depth`` flips (a flip reverses a stretch of the tour,
   which also turns its strokes round; one flip is 2-opt) and Or-opt (moving a chain of
   1-3 strokes into another gap, either way round), over neighbour lists, until no move
   improves (on long tours: until a sweep finds under one move per 1000 strokes) or the
   work cap ``passes * N`` is spent.
3. Iterated local search: perturbation trials ("kicks") that keep only improvements.
   Up to ``window`` strokes they run on the whole tour after step 2. Longer tours are
   cut into regions of at most about ``window`` strokes (an equal-count grid, then the
   grid shifted by half a cell); each region's strokes, with every stretch of the tour
   outside it standing in as one stroke, form a small tour of their own, searched
   (step 2) and perturbed there, so that a reversal costs at most the region's size
   instead of N. Step 2 on the whole tour then follows, for what crosses regions.

The start position is an item of zero length in the tour (both its endpoints at the
start), so every endpoint has exactly one travel edge.

The result is never worse than the input order (it is returned instead if it is shorter).
"""

from __future__ import annotations

import math
import reprlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

# scratchfab.toolpath.local_search (numba, ~0.2-0.7 s to import) and scipy (~0.2 s) are
# imported where they are used: OrderOptions, which the toolpath command needs for its
# help, and tour_travel, which the exporters need, are plain numpy.


@dataclass(frozen=True)
class OrderOptions:
    """Tuning of :func:`order_strokes`.

    Attributes:
        neighbours: Candidate endpoints considered per endpoint (greedy and local search).
        passes: Cap on local-search work, in visits of every stroke; 0 = greedy only.
        kicks_per_stroke: Perturbation trials after the local optimum, per stroke.
        kicks: Perturbation trials in all (overrides ``kicks_per_stroke``).
        max_kicks: Cap on the trials from ``kicks_per_stroke`` (keeps 100k strokes
            well under 10 s; it governs from 2400 strokes on).
        seed: Seed of the perturbations (the result is deterministic for a seed).
        min_gain_mm: Moves that save less than this are ignored (rounding noise).
        window: Tours of more than this many strokes get their perturbation trials in
            regions of at most about this many strokes, so each trial stays cheap.
        depth: Longest Lin-Kernighan flip chain (1: 2-opt, 2: adds sequential 3-opt).
    """

    neighbours: int = 10
    passes: int = 50
    kicks_per_stroke: float = 25.0
    kicks: int | None = None
    max_kicks: int = 60_000
    seed: int = 0
    min_gain_mm: float = 1e-9
    window: int = 1000
    depth: int = 8

    def __post_init__(self) -> None:
        checks = {
            "neighbours >= 1": self.neighbours >= 1,
            "passes >= 0": self.passes >= 0,
            "kicks_per_stroke >= 0": self.kicks_per_stroke >= 0,
            "kicks >= 0 or None": self.kicks is None or self.kicks >= 0,
            "max_kicks >= 0": self.max_kicks >= 0,
            "0 <= seed < 2**32": 0 <= self.seed < 2**32,
            "window >= 1": self.window >= 1,
            "depth >= 1": self.depth >= 1,
        }
        broken = [rule for rule, ok in checks.items() if not ok]
        if broken:
            raise ValueError(f"OrderOptions: need {', '.join(broken)}")


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


@dataclass(frozen=True)
class OrderProgress:
    """One progress report of :func:`order_strokes` (and of the planning around it).

    Attributes:
        phase: The phase just finished: ``"greedy"``, ``"regions"`` (the perturbation
            trials region by region, on tours of more than ``window`` strokes) or
            ``"local search"``; ``""`` for a message.
        step: Phases finished.
        total: Phases this ordering runs (1 with ``passes`` 0, else 2, or 3 with
            regions; 0 where not yet known, in a message said before ordering).
        travel_mm: Pen-up travel of the tour after the phase (NaN for a message). The
            last phase's is the ordering's own: where the input order is shorter
            (:attr:`OrderResult.kept_input`) the result keeps that and its
            ``travel_mm``, which is then less than this.
        elapsed_s: Seconds since the ordering began.
        message: A status line instead of a phase ("" for phases).
    """

    phase: str
    step: int
    total: int
    travel_mm: float
    elapsed_s: float
    message: str = ""

    @classmethod
    def note(
        cls, message: str, step: int = 0, total: int = 0, elapsed_s: float = 0.0
    ) -> OrderProgress:
        """A status line, said after ``step`` of ``total`` phases."""
        return cls("", step, total, math.nan, elapsed_s, message)


#: A ``progress`` callback of :func:`order_strokes` and :func:`~scratchfab.toolpath.plan_toolpath`.
OrderProgressCallback = Callable[[OrderProgress], None]


def order_phases(n: int, options: OrderOptions) -> tuple[str, ...]:
    """The phases :func:`order_strokes` runs on ``n`` strokes (none below two strokes)."""
    if n < 2:
        return ()
    if options.passes == 0:
        return ("greedy",)
    return (
        ("greedy", "local search") if n <= options.window else ("greedy", "regions", "local search")
    )


def compile_note(options: OrderOptions) -> str | None:
    """The line to say before ordering with ``options`` when numba compiles first, else None.

    The compiled steps that ordering runs (greedy, and the local search unless
    ``passes`` is 0) compile once after installing or upgrading, in about 10 s, and are
    then cached (:func:`~scratchfab.toolpath.local_search.compile_state`).
    """
    from scratchfab.toolpath.local_search import compile_state, greedy_steps, improve

    state = compile_state([greedy_steps, *([improve] if options.passes > 0 else [])])
    if state == "once":
        return "compiling the ordering code once (about 10 s) ..."
    if state == "each run":
        return "compiling the ordering code (about 10 s; numba cannot cache it here) ..."
    return None


def _floats(value: Any, name: str) -> np.ndarray:
    """``value`` as a float64 array; a ValueError naming ``name`` when it holds no numbers."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected numbers in mm, got {reprlib.repr(value)}") from None


def tour_travel(p0: np.ndarray, p1: np.ndarray, start: np.ndarray) -> float:
    """Pen-up travel of cutting p0[k] -> p1[k] in index order, from ``start`` and back to it."""
    if len(p0) == 0:
        return 0.0
    stops = np.vstack([start[None, :], p1])
    goes = np.vstack([p0, start[None, :]])
    return float(np.hypot(*(goes - stops).T).sum())


def _tour_travel(points: np.ndarray, ent: np.ndarray) -> float:
    """Length of the tour's travel edges, exit of each item to the entry of the next."""
    return float(np.hypot(*(points[np.roll(ent, -1)] - points[ent ^ 1]).T).sum())


def _stroke_order(ent: np.ndarray, start_item: int) -> tuple[np.ndarray, np.ndarray]:
    """Strokes in cut order after the start item, and whether each is cut p1 -> p0."""
    after = np.roll(ent, -int(np.flatnonzero((ent >> 1) == start_item)[0]))[1:]
    return after >> 1, (after & 1).astype(bool)


def _greedy(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Entry endpoints in greedy nearest-neighbour order from the start (the last item)."""
    from scipy.spatial import cKDTree

    from scratchfab.toolpath.local_search import greedy_steps

    n = (len(points) - 2) // 2
    near = np.ascontiguousarray(neighbours, dtype=np.int64)
    used = np.zeros(n, dtype=np.bool_)
    entries = np.empty(n, dtype=np.int64)
    free_tree: cKDTree | None = None
    free_ids = np.empty(0, dtype=np.int64)
    step = 0
    cur = 2 * n + 1
    while True:
        # Compiled steps while a near neighbour is free; here only when all are used.
        step, cur = greedy_steps(near, used, entries, step, cur)
        if step == n:
            return entries
        nxt = -1
        while nxt < 0:
            if free_tree is None:
                free_ids = np.flatnonzero(np.repeat(~used, 2))
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
            if nxt < 0:
                free_tree = None
        used[nxt >> 1] = True
        entries[step] = nxt
        step += 1
        cur = nxt ^ 1


def _candidates(near: np.ndarray, k: int) -> np.ndarray:
    """Each point's ``k`` nearest endpoints other than itself, from a k+1 query."""
    own = near == np.arange(len(near))[:, None]
    cand = np.take_along_axis(near, np.argsort(own, axis=1, kind="stable"), axis=1)[:, :k]
    return np.ascontiguousarray(cand, dtype=np.int64)


def _improve_region(
    points: np.ndarray,
    ent: np.ndarray,
    inside: np.ndarray,
    kicks: int,
    seed: int,
    opts: OrderOptions,
) -> tuple[np.ndarray, int]:
    """Perturbation trials on the strokes at the tour positions marked ``inside``.

    The tour is cut into runs inside and outside the region. Each outside run becomes
    one stand-in stroke from its first entry to its last exit, whose own length does
    not count; the region's strokes and the stand-ins form a small tour. Any tour of
    them is a tour of everything (a stand-in cut backwards is its run reversed), at the
    small tour's length plus a constant, so the small tour can be searched freely and
    expanded back, and its reversals cost at most its size. Returns the new tour and
    the improving moves and trials kept.
    """
    from scipy.spatial import cKDTree

    from scratchfab.toolpath.local_search import (
        SETTLED_ITEMS_PER_MOVE,
        cut_region,
        expand_region,
        improve,
    )

    starts, ends = cut_region(inside)
    w = len(starts)
    sub = np.empty((2 * w, 2))
    sub[0::2] = points[ent[starts]]
    sub[1::2] = points[ent[ends] ^ 1]
    k = min(opts.neighbours, 2 * w - 1)
    _, near = cKDTree(sub).query(sub, k=k + 1)
    sub_ent = np.arange(0, 2 * w, 2, dtype=np.int64)
    moves = improve(
        sub,
        sub_ent,
        _candidates(near, k),
        opts.passes,
        kicks,
        seed,
        opts.min_gain_mm,
        opts.depth,
        SETTLED_ITEMS_PER_MOVE,
    )
    return expand_region(ent, starts, ends, sub_ent), moves


def _improve_regions(
    points: np.ndarray, ent: np.ndarray, kicks: int, opts: OrderOptions
) -> tuple[np.ndarray, int]:
    """Spread ``kicks`` perturbation trials over regions of about ``opts.window`` strokes.

    Regions are the cells of an equal-count grid over the stroke midpoints; a second
    round shifts the grid by half a cell so that the cells' borders get searched too.
    Returns the new tour and the improving moves and trials kept.
    """
    n = (len(points) - 2) // 2
    mid = 0.5 * (points[0 : 2 * n : 2] + points[1 : 2 * n : 2])
    cols = max(1, int(np.ceil(np.sqrt(n / max(opts.window, 8)))))
    moves = 0
    for r in range(2):
        edges = (np.arange(1, cols + r) - 0.5 * r) / cols
        col = np.searchsorted(np.quantile(mid[:, 0], edges), mid[:, 0])
        cell = np.full(n + 1, -1)  # per item; the start (item n) is in none
        for c in range(cols + r):
            in_col = col == c
            if in_col.any():
                row = np.searchsorted(np.quantile(mid[in_col, 1], edges), mid[in_col, 1])
                cell[:n][in_col] = c * (cols + r) + row
        for c in np.unique(cell[:n]).tolist():
            inside = cell[ent >> 1] == c
            share = kicks * int(inside.sum()) // (2 * n)
            seed = (opts.seed * 1_000_003 + r * 65_537 + c) % 2**32
            ent, got = _improve_region(points, ent, inside, share, seed, opts)
            moves += got
    return ent, moves


def order_strokes(
    p0: np.ndarray,
    p1: np.ndarray,
    start: tuple[float, float] | np.ndarray,
    options: OrderOptions | None = None,
    progress: OrderProgressCallback | None = None,
) -> OrderResult:
    """Order strokes to minimise pen-up travel from ``start`` and back (see module docstring).

    Args:
        p0: (N, 2) stroke start points in mm.
        p1: (N, 2) stroke end points in mm.
        start: The machine's start position (x, y) in mm.
        options: Tuning; defaults to :class:`OrderOptions`.
        progress: Called after each phase (:func:`order_phases`), and first with the
            :func:`compile_note` where numba compiles before ordering. The result is the
            same with it or without.

    Returns:
        The order, per-stroke reversal and travel figures.

    Raises:
        ValueError: ``p0`` and ``p1`` are not both (N, 2) (a (2, N) array among them) or
            hold a point that is not finite, or ``start`` is not one finite (x, y).
    """
    from scipy.spatial import cKDTree

    began = time.perf_counter()
    opts = options or OrderOptions()
    p0, p1, origin = (_floats(v, name) for v, name in ((p0, "p0"), (p1, "p1"), (start, "start")))
    if p0.ndim != 2 or p0.shape[1:] != (2,) or p1.shape != p0.shape:
        raise ValueError(f"p0 and p1: expected both (N, 2), got shapes {p0.shape} and {p1.shape}")
    bad = np.flatnonzero(~np.isfinite(np.hstack([p0, p1])).all(axis=1))
    if len(bad):
        k = int(bad[0])
        raise ValueError(
            f"p0 and p1: stroke {k} is not finite ({p0[k].tolist()} -> {p1[k].tolist()})"
            + (f", nor are {len(bad) - 1} more" if len(bad) > 1 else "")
        )
    if origin.shape != (2,) or not np.isfinite(origin).all():
        raise ValueError(f"start: expected one finite (x, y) in mm, got {reprlib.repr(start)}")
    n = len(p0)
    travel_input = tour_travel(p0, p1, origin)
    identity = np.arange(n)
    no_flip = np.zeros(n, dtype=bool)
    if n < 2:
        return OrderResult(identity, no_flip, travel_input, travel_input, travel_input, 0, True)
    phases = order_phases(n, opts)

    def report(phase: str, ent: np.ndarray) -> None:
        """Tell ``progress`` that ``phase`` finished with the tour ``ent``."""
        if progress is not None:
            step = phases.index(phase) + 1
            elapsed = time.perf_counter() - began
            progress(OrderProgress(phase, step, len(phases), _tour_travel(points, ent), elapsed))

    if progress is not None and (note := compile_note(opts)) is not None:
        progress(OrderProgress.note(note, 0, len(phases), time.perf_counter() - began))
    points = np.empty((2 * n + 2, 2))
    points[0 : 2 * n : 2] = p0
    points[1 : 2 * n : 2] = p1
    points[2 * n :] = origin
    k = min(opts.neighbours, 2 * n + 1)
    _, near = cKDTree(points).query(points, k=k + 1, workers=-1)
    ent = np.concatenate([[2 * n], _greedy(points, near)]).astype(np.int64)
    travel_greedy = _tour_travel(points, ent)
    report("greedy", ent)
    moves = 0
    if opts.passes > 0:
        from scratchfab.toolpath.local_search import SETTLED_ITEMS_PER_MOVE, improve

        kicks = opts.kicks
        if kicks is None:
            kicks = min(int(opts.kicks_per_stroke * n), opts.max_kicks)
        whole = "regions" not in phases
        if not whole:
            ent, moves = _improve_regions(points, ent, kicks, opts)
            report("regions", ent)
        moves += improve(
            points,
            ent,
            _candidates(near, k),
            opts.passes,
            kicks if whole else 0,
            opts.seed,
            opts.min_gain_mm,
            opts.depth,
            SETTLED_ITEMS_PER_MOVE,
        )
        report("local search", ent)
    order, reverse = _stroke_order(ent, n)
    travel = tour_travel(
        np.where(reverse[:, None], p1[order], p0[order]),
        np.where(reverse[:, None], p0[order], p1[order]),
        origin,
    )
    if travel_input <= travel:
        return OrderResult(
            identity, no_flip, travel_input, travel_input, travel_greedy, moves, True
        )
    return OrderResult(order, reverse, travel, travel_input, travel_greedy, moves, False)
