"""Compiled local search for stroke tours: 2-opt and Or-opt with neighbour lists.

The tour is a cycle of M = N + 1 items (N strokes and the depot, the start position)
held in one array: ``ent[p]`` is the endpoint id where the item at position p is
entered (2k: stroke k's p0, 2k+1: its p1, 2N: the depot); it is left at the other end
(``ent ^ 1``; the depot at itself). Edge p joins the exit B(p) of position p to the
entry A(p+1) of the next. Moves (first improvement, processed from a queue of items
whose edges changed, "don't-look bits"):

- 2-opt: replace edges i and j by (B(i), B(j)) and (A(i+1), A(j+1)), i.e. reverse the
  positions i+1..j, which also turns each stroke in them round. Candidates join an
  endpoint to one of its ``K`` nearest endpoints (``near``); the search along a
  neighbour list stops once the new edge is no shorter than the edge it replaces.
- Or-opt: move a chain of 1 to 3 consecutive items into another gap, either way round.
- Perturbation ("kicks", iterated local search): swap two short neighbouring stretches
  (a local double bridge), search again from the changed joins, keep only improvements.

Reversals and moves go the shorter way round the cycle (reversing the complement of an
arc gives the same cycle). Work is capped at ``passes * M`` items taken from the queue.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _exit(e: int, depot: int) -> int:
    return e if e == depot else e ^ 1


@numba.njit(cache=True, inline="always")
def _d(pts: np.ndarray, a: int, b: int) -> float:
    dx = pts[a, 0] - pts[b, 0]
    dy = pts[a, 1] - pts[b, 1]
    return math.sqrt(dx * dx + dy * dy)


@numba.njit(cache=True, inline="always")
def _note(log: np.ndarray, first: int, count: int) -> None:
    """Record that ``count`` positions from ``first`` on (cyclic) are about to change.

    ``log[0]`` counts the positions held in ``log[2:]`` (taken modulo the tour length
    when read); ``log[1]`` becomes 1 once they overflow, and a full copy is needed.
    """
    n = log[0]
    if n + count > log.shape[0] - 2:
        log[1] = 1
        return
    for k in range(count):
        log[2 + n + k] = first + k
    log[0] = n + count


@numba.njit(cache=True)
def _reverse(
    ent: np.ndarray, pos: np.ndarray, first: int, last: int, depot: int, log: np.ndarray
) -> None:
    """Reverse the cyclic arc first..last (or its complement, whichever is shorter)."""
    m = ent.shape[0]
    length = (last - first) % m + 1
    if 2 * length > m:
        first, last = (last + 1) % m, (first - 1) % m
        length = m - length
    _note(log, first, length)
    for k in range((length + 1) // 2):
        a = (first + k) % m
        b = (last - k) % m
        ea = _exit(ent[a], depot)
        eb = _exit(ent[b], depot)
        ent[a] = eb
        ent[b] = ea
        pos[eb >> 1] = a
        pos[ea >> 1] = b


@numba.njit(cache=True)
def _move_chain(
    ent: np.ndarray,
    pos: np.ndarray,
    c0: int,
    s: int,
    g: int,
    flip: bool,
    depot: int,
    buf: np.ndarray,
    log: np.ndarray,
) -> None:
    """Move the s items at c0.. into the gap after position g (turned round if ``flip``)."""
    m = ent.shape[0]
    c1 = (c0 + s - 1) % m
    for k in range(s):
        buf[k] = ent[(c0 + k) % m]
    if flip:
        for k in range(s // 2):
            t = buf[k]
            buf[k] = buf[s - 1 - k]
            buf[s - 1 - k] = t
        for k in range(s):
            buf[k] = _exit(buf[k], depot)
    n_after = (g - c1) % m  # items from c1+1 to g: the chain moves forward past them
    n_before = (c0 - 1 - g) % m  # items from g+1 to c0-1: or they move forward past it
    if n_after <= n_before:
        _note(log, c0, n_after + s)
        for k in range(n_after):
            src = (c1 + 1 + k) % m
            dst = (c0 + k) % m
            ent[dst] = ent[src]
            pos[ent[dst] >> 1] = dst
        base = (c0 + n_after) % m
    else:
        _note(log, g + 1, n_before + s)
        for k in range(n_before - 1, -1, -1):
            src = (g + 1 + k) % m
            dst = (g + 1 + s + k) % m
            ent[dst] = ent[src]
            pos[ent[dst] >> 1] = dst
        base = (g + 1) % m
    for k in range(s):
        p = (base + k) % m
        ent[p] = buf[k]
        pos[buf[k] >> 1] = p


@numba.njit(cache=True)
def _search(
    pts: np.ndarray,
    ent: np.ndarray,
    pos: np.ndarray,
    near: np.ndarray,
    queue: np.ndarray,
    queued: np.ndarray,
    size: int,
    budget: int,
    max_reverse: int,
    eps: float,
    log: np.ndarray,
) -> tuple[int, float]:
    """Local search from the ``size`` items queued in ``queue[:size]``; (moves, gain).

    The positions it changes are recorded in ``log`` (see :func:`_note`).
    """
    m = ent.shape[0]
    depot = pts.shape[0] - 1
    k_near = near.shape[1]
    head = 0
    buf = np.empty(3, dtype=np.int64)
    moves = 0
    total_gain = 0.0
    touched = np.empty(8, dtype=np.int64)
    while size > 0 and budget > 0:
        item = queue[head]
        head = (head + 1) % m
        size -= 1
        queued[item] = False
        budget -= 1
        improved = True
        while improved:
            improved = False
            n_touched = 0
            p = pos[item]
            # 2-opt on the edge out of p (joins exits) and the edge into p (joins entries).
            for side in range(2):
                if improved:
                    break
                i = p if side == 0 else (p - 1) % m
                bi = _exit(ent[i], depot)
                ai1 = ent[(i + 1) % m]
                li = _d(pts, bi, ai1)
                x = bi if side == 0 else ai1
                for kk in range(k_near):
                    f = near[x, kk]
                    d1 = _d(pts, x, f)
                    if d1 >= li - eps:
                        break
                    q = pos[f >> 1]
                    is_entry = ent[q] == f
                    if f != depot and (is_entry == (side == 0)):
                        continue
                    j = q if side == 0 else (q - 1) % m
                    if j == i:
                        continue
                    span = (j - i) % m
                    if min(span, m - span) > max_reverse:
                        continue
                    bj = _exit(ent[j], depot)
                    aj1 = ent[(j + 1) % m]
                    gain = li + _d(pts, bj, aj1) - _d(pts, bi, bj) - _d(pts, ai1, aj1)
                    if gain > eps:
                        total_gain += gain
                        touched[0] = ent[i] >> 1
                        touched[1] = ai1 >> 1
                        touched[2] = ent[j] >> 1
                        touched[3] = aj1 >> 1
                        n_touched = 4
                        _reverse(ent, pos, (i + 1) % m, j, depot, log)
                        improved = True
                        break
            # Or-opt: chains of 1..3 items starting at p.
            if not improved:
                for s in range(1, 4):
                    if improved or m < s + 3:
                        break
                    c0 = p
                    c1 = (p + s - 1) % m
                    prev = (c0 - 1) % m
                    nxt = (c1 + 1) % m
                    a_s = ent[c0]
                    b_s = _exit(ent[c1], depot)
                    b_prev = _exit(ent[prev], depot)
                    a_next = ent[nxt]
                    removal = _d(pts, b_prev, a_s) + _d(pts, b_s, a_next) - _d(pts, b_prev, a_next)
                    if removal <= eps:
                        continue
                    for end in range(2):
                        if improved:
                            break
                        x = a_s if end == 0 else b_s
                        for kk in range(k_near):
                            f = near[x, kk]
                            d1 = _d(pts, x, f)
                            if d1 >= removal - eps:
                                break
                            q = pos[f >> 1]
                            is_entry = ent[q] == f and f != depot
                            # f is the exit B(g) (f before the chain) or the entry A(g+1).
                            g = (q - 1) % m if is_entry else q
                            if (g - prev) % m <= s:
                                continue
                            # Joining x to an exit: x must be the chain's entry side.
                            flip = (end == 0) == is_entry
                            bg = _exit(ent[g], depot)
                            ag1 = ent[(g + 1) % m]
                            if flip:
                                add = _d(pts, bg, b_s) + _d(pts, a_s, ag1)
                            else:
                                add = _d(pts, bg, a_s) + _d(pts, b_s, ag1)
                            add -= _d(pts, bg, ag1)
                            if removal - add > eps:
                                total_gain += removal - add
                                touched[0] = ent[prev] >> 1
                                touched[1] = a_next >> 1
                                touched[2] = ent[g] >> 1
                                touched[3] = ag1 >> 1
                                touched[4] = a_s >> 1
                                touched[5] = ent[c1] >> 1
                                n_touched = 6
                                _move_chain(ent, pos, c0, s, g, flip, depot, buf, log)
                                improved = True
                                break
            if improved:
                moves += 1
                for t in range(n_touched):
                    it = touched[t]
                    if not queued[it] and it != item:
                        queued[it] = True
                        queue[(head + size) % m] = it
                        size += 1
    while size > 0:
        queued[queue[head]] = False
        head = (head + 1) % m
        size -= 1
    return moves, total_gain


@numba.njit(cache=True)
def _tour_length(pts: np.ndarray, ent: np.ndarray) -> float:
    m = ent.shape[0]
    depot = pts.shape[0] - 1
    total = 0.0
    for p in range(m):
        total += _d(pts, _exit(ent[p], depot), ent[(p + 1) % m])
    return total


@numba.njit(cache=True)
def improve(
    pts: np.ndarray,
    ent: np.ndarray,
    near: np.ndarray,
    passes: int,
    kicks: int,
    seed: int,
    max_reverse: int,
    eps: float,
) -> int:
    """2-opt and Or-opt to a local optimum, then ``kicks`` perturbation trials.

    A trial swaps two short neighbouring stretches of the tour (a local double bridge),
    searches again from the four changed joins and keeps the result only if the tour got
    shorter. A trial is undone (or kept) through the positions it changed, not by copying
    the tour. Works on ``ent`` in place; returns the improving moves and trials kept.
    """
    m = ent.shape[0]
    pos = np.empty(m, dtype=np.int64)
    for p in range(m):
        pos[ent[p] >> 1] = p
    queue = np.empty(m, dtype=np.int64)
    queued = np.ones(m, dtype=np.bool_)
    for p in range(m):
        queue[p] = ent[p] >> 1
    budget = passes * m
    moves = 0
    no_log = np.zeros(2, dtype=np.int64)
    for _ in range(passes):
        found, _gain = _search(
            pts, ent, pos, near, queue, queued, m, budget, max_reverse, eps, no_log
        )
        moves += found
        if found == 0:
            break
        for p in range(m):
            queue[p] = ent[p] >> 1
            queued[queue[p]] = True
    for p in range(m):
        queued[p] = False
    if m < 8:
        return moves
    np.random.seed(seed)
    saved_ent = ent.copy()
    window = min(50, (m - 1) // 3)
    # Positions a trial changed, to undo (or keep) it without copying the whole tour.
    log = np.zeros(2 + 64 * window + 4096, dtype=np.int64)
    tmp = np.empty(2 * window + 2, dtype=np.int64)
    depot = pts.shape[0] - 1
    for _ in range(kicks):
        a = np.random.randint(0, m)
        l1 = np.random.randint(1, window + 1)
        l2 = np.random.randint(1, window + 1)
        b = (a + l1) % m
        c = (b + l2) % m
        # Tour ... A(a) | S1 = a+1..b | S2 = b+1..c | c+1 ...  ->  ... a | S2 | S1 | c+1 ...
        a1 = (a + 1) % m
        b1 = (b + 1) % m
        c1 = (c + 1) % m
        before = (
            _d(pts, _exit(ent[a], depot), ent[a1])
            + _d(pts, _exit(ent[b], depot), ent[b1])
            + _d(pts, _exit(ent[c], depot), ent[c1])
        )
        after = (
            _d(pts, _exit(ent[a], depot), ent[b1])
            + _d(pts, _exit(ent[c], depot), ent[a1])
            + _d(pts, _exit(ent[b], depot), ent[c1])
        )
        log[0] = 0
        log[1] = 0
        _note(log, a1, l1 + l2)
        n = 0
        for k in range(l2):
            tmp[n] = ent[(b1 + k) % m]
            n += 1
        for k in range(l1):
            tmp[n] = ent[(a1 + k) % m]
            n += 1
        for k in range(n):
            p = (a1 + k) % m
            ent[p] = tmp[k]
            pos[tmp[k] >> 1] = p
        size = 0
        for it in (
            ent[a] >> 1,
            ent[a1] >> 1,
            ent[(a1 + l2 - 1) % m] >> 1,
            ent[(a1 + l2) % m] >> 1,
            ent[c] >> 1,
            ent[c1] >> 1,
        ):
            if not queued[it]:
                queued[it] = True
                queue[size] = it
                size += 1
        found, gain = _search(
            pts, ent, pos, near, queue, queued, size, 50 * size, max_reverse, eps, log
        )
        keep = after - before - gain < -eps
        if keep:
            moves += found + 1
        if log[1] != 0:
            if keep:
                saved_ent[:] = ent
            else:
                ent[:] = saved_ent
                for p in range(m):
                    pos[ent[p] >> 1] = p
        elif keep:
            for k in range(log[0]):
                p = log[2 + k] % m
                saved_ent[p] = ent[p]
        else:
            for k in range(log[0]):
                p = log[2 + k] % m
                ent[p] = saved_ent[p]
                pos[ent[p] >> 1] = p
    return moves
