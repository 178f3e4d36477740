"""Compiled local search for stroke tours: Lin-Kernighan chains of flips and Or-opt.

The tour is a cycle of M items held in one array: ``ent[p]`` is the endpoint id where
the item at position p is entered (2k: item k's first end, 2k+1: its second); it is
left at the other end, ``ent[p] ^ 1``. The start position is an item of zero length.
Every endpoint has exactly one travel edge: an item's entry is joined to the exit of
the item before it, its exit to the entry of the item after it. Moves (first
improvement, processed from a queue of items whose edges changed, "don't-look bits"):

- Flip chains (Lin-Kernighan): a flip at endpoints x and f removes their two travel
  edges and joins x to f and their old partners to each other, by reversing the
  stretch between them (which turns its strokes round); it keeps one tour only if x
  and f are both entries or both exits. A chain breaks an edge (x, t1) of the item,
  flips x to a near endpoint f whose distance is below the gain so far, then goes on
  from f's old partner, which the flip joined to t1: up to ``depth`` flips, the first
  over all ``K`` nearest endpoints (``near``) and the later ones to the neighbour with
  the best look-ahead. The chain is followed on virtual positions and only its best
  prefix is applied, if it shortens the tour. Depth 1 is 2-opt; depth 2 adds the
  sequential 3-opt moves.
- Or-opt: move a chain of 1 to 3 consecutive items into another gap, either way round.
- Perturbation ("kicks", iterated local search): swap two short neighbouring stretches
  (a local double bridge), search again from the changed joins, keep only improvements.

Reversals and moves go the shorter way round the cycle (reversing the complement of an
arc gives the same cycle). Work is capped at ``passes * M`` items taken from the queue.
When the queue runs dry, a fresh sweep over every item follows, until a sweep finds no
move or (on long tours) fewer than one per ``SETTLED_ITEMS_PER_MOVE`` items.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
from numba.core.caching import NullCache

from scratchfab.compiled import njit

# A sweep over the whole tour that finds fewer moves than one per this many items
# (besides the start item) ends the local search; on tours of up to this many strokes only
# a sweep that finds none does.
SETTLED_ITEMS_PER_MOVE = 1000


@njit(inline="always")
def _d(pts: np.ndarray, a: int, b: int) -> float:
    dx = pts[a, 0] - pts[b, 0]
    dy = pts[a, 1] - pts[b, 1]
    return math.sqrt(dx * dx + dy * dy)


@njit(inline="always")
def _wrap(i: int, m: int) -> int:
    """``i % m`` for ``-m <= i < 2 * m``, without a division (the hot loops' positions)."""
    if i < 0:
        return i + m
    if i >= m:
        return i - m
    return i


@njit(inline="always")
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


@njit()
def _reverse(ent: np.ndarray, pos: np.ndarray, first: int, last: int, log: np.ndarray) -> None:
    """Reverse the cyclic arc first..last (or its complement, whichever is shorter)."""
    m = ent.shape[0]
    length = (last - first) % m + 1
    if 2 * length > m:
        first, last = (last + 1) % m, (first - 1) % m
        length = m - length
    _note(log, first, length)
    for k in range((length + 1) // 2):
        a = _wrap(first + k, m)
        b = _wrap(last - k, m)
        ea = ent[a] ^ 1
        eb = ent[b] ^ 1
        ent[a] = eb
        ent[b] = ea
        pos[eb >> 1] = a
        pos[ea >> 1] = b


@njit()
def _move_chain(
    ent: np.ndarray,
    pos: np.ndarray,
    c0: int,
    s: int,
    g: int,
    flip: bool,
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
            buf[k] = buf[k] ^ 1
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


@njit(inline="always")
def _partner(ent: np.ndarray, pos: np.ndarray, e: int) -> int:
    """The endpoint joined to ``e`` by its travel edge."""
    m = ent.shape[0]
    q = pos[e >> 1]
    if ent[q] == e:
        return ent[_wrap(q - 1, m)] ^ 1
    return ent[_wrap(q + 1, m)]


@njit(inline="always")
def _place(
    ent: np.ndarray, pos: np.ndarray, e: int, first: np.ndarray, length: np.ndarray, n: int
) -> tuple[int, bool]:
    """Position of endpoint ``e`` and whether it is an entry, after ``n`` virtual flips."""
    m = ent.shape[0]
    q = pos[e >> 1]
    entry = ent[q] == e
    for k in range(n):
        o = _wrap(q - first[k], m)
        if o < length[k]:
            q = _wrap(first[k] + length[k] - 1 - o, m)
            entry = not entry
    return q, entry


@njit()
def _flip(ent: np.ndarray, pos: np.ndarray, x: int, f: int, log: np.ndarray) -> None:
    """Join x to f (both entries or both exits) and their old partners to each other."""
    m = ent.shape[0]
    qx = pos[x >> 1]
    qf = pos[f >> 1]
    first = qx if ent[qx] == x else _wrap(qx + 1, m)
    _reverse(ent, pos, first, _wrap(first + _wrap(qf - qx, m) - 1, m), log)


@njit()
def _chain(
    pts: np.ndarray,
    ent: np.ndarray,
    pos: np.ndarray,
    near: np.ndarray,
    x0: int,
    t1: int,
    f1: int,
    g0: float,
    depth: int,
    eps: float,
    chain: np.ndarray,
    scratch: np.ndarray,
) -> tuple[float, int]:
    """Follow a flip chain that breaks (x0, t1) and first joins x0 to f1, virtually.

    Returns the best gain found and the number of flips giving it (0: none improves);
    the flips are ``chain[k] = (x, f)``, to be applied in order with :func:`_flip`.
    ``scratch`` is (3, 2 * depth + 2) working space.
    """
    m = ent.shape[0]
    k_near = near.shape[1]
    first = scratch[0]
    length = scratch[1]
    # Endpoints whose travel edge the chain has changed: never the f of a later flip, so
    # every f's partner is still the one in the array.
    moved = scratch[2]
    moved[0] = x0
    moved[1] = t1
    n_moved = 2
    x = x0
    f = f1
    g = g0
    best = eps
    best_n = 0
    for n in range(depth):
        qx, ex = _place(ent, pos, x, first, length, n)
        if n == 0:
            qf, ef = _place(ent, pos, f, first, length, n)
            if ef != ex or qf == qx:
                break
        else:
            # The neighbour of x with the best look-ahead |f, partner(f)| - |x, f|, among
            # those on x's side of the virtual tour (the same orientation, not x itself).
            f = -1
            qf = 0
            look_best = -np.inf
            for kk in range(k_near):
                c = near[x, kk]
                dc = _d(pts, x, c)
                if dc >= g - eps:
                    break
                used = False
                for k in range(n_moved):
                    if moved[k] == c:
                        used = True
                        break
                if used:
                    continue
                qc, ec = _place(ent, pos, c, first, length, n)
                span = _wrap(qc - qx, m)
                if ec != ex or span == 0:
                    continue
                look = _d(pts, c, _partner(ent, pos, c)) - dc
                if look > look_best:
                    look_best = look
                    f = c
                    qf = qc
            if f < 0:
                break
        span = _wrap(qf - qx, m)
        # x's partner is t1 (the closing edge); f's partner b gets joined to t1.
        b = _partner(ent, pos, f)
        g += _d(pts, f, b) - _d(pts, x, f)
        first[n] = qx if ex else _wrap(qx + 1, m)
        length[n] = span
        chain[n, 0] = x
        chain[n, 1] = f
        moved[n_moved] = f
        moved[n_moved + 1] = b
        n_moved += 2
        total = g - _d(pts, t1, b)
        if total > best:
            best = total
            best_n = n + 1
        x = b
    return best, best_n


@njit()
def _search(
    pts: np.ndarray,
    ent: np.ndarray,
    pos: np.ndarray,
    near: np.ndarray,
    queue: np.ndarray,
    queued: np.ndarray,
    size: int,
    budget: int,
    eps: float,
    log: np.ndarray,
    depth: int,
) -> tuple[int, float, int]:
    """Local search from the ``size`` items queued in ``queue[:size]``.

    Takes at most ``budget`` items from the queue. Returns the improving moves, their
    total gain and the budget left. The positions it changes are recorded in ``log``
    (see :func:`_note`).
    """
    m = ent.shape[0]
    k_near = near.shape[1]
    head = 0
    buf = np.empty(3, dtype=np.int64)
    moves = 0
    total_gain = 0.0
    touched = np.empty(4 * depth + 8, dtype=np.int64)
    chain = np.empty((depth, 2), dtype=np.int64)
    scratch = np.empty((3, 2 * depth + 2), dtype=np.int64)
    while size > 0 and budget > 0:
        item = queue[head]
        head = _wrap(head + 1, m)
        size -= 1
        queued[item] = False
        budget -= 1
        improved = True
        while improved:
            improved = False
            n_touched = 0
            p = pos[item]
            # Flip chains from the edge out of p and the edge into p.
            for side in range(2):
                if improved:
                    break
                x0 = ent[p] ^ 1 if side == 0 else ent[p]
                t1 = ent[_wrap(p + 1, m)] if side == 0 else ent[_wrap(p - 1, m)] ^ 1
                g0 = _d(pts, x0, t1)
                for kk in range(k_near):
                    f1 = near[x0, kk]
                    if _d(pts, x0, f1) >= g0 - eps:
                        break
                    if f1 == t1:
                        continue
                    gain, n_flips = _chain(
                        pts,
                        ent,
                        pos,
                        near,
                        x0,
                        t1,
                        f1,
                        g0,
                        depth,
                        eps,
                        chain,
                        scratch,
                    )
                    if n_flips > 0:
                        total_gain += gain
                        for k in range(n_flips):
                            x = chain[k, 0]
                            f = chain[k, 1]
                            touched[n_touched] = x >> 1
                            touched[n_touched + 1] = f >> 1
                            touched[n_touched + 2] = _partner(ent, pos, x) >> 1
                            touched[n_touched + 3] = _partner(ent, pos, f) >> 1
                            n_touched += 4
                            _flip(ent, pos, x, f, log)
                        improved = True
                        break
            # Or-opt: chains of 1..3 items starting at p.
            if not improved:
                for s in range(1, 4):
                    if improved or m < s + 3:
                        break
                    c0 = p
                    c1 = _wrap(p + s - 1, m)
                    prev = _wrap(c0 - 1, m)
                    nxt = _wrap(c1 + 1, m)
                    a_s = ent[c0]
                    b_s = ent[c1] ^ 1
                    b_prev = ent[prev] ^ 1
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
                            is_entry = ent[q] == f
                            # f is the exit B(g) (f before the chain) or the entry A(g+1).
                            g = _wrap(q - 1, m) if is_entry else q
                            if _wrap(g - prev, m) <= s:
                                continue
                            # Joining x to an exit: x must be the chain's entry side.
                            flip = (end == 0) == is_entry
                            bg = ent[g] ^ 1
                            ag1 = ent[_wrap(g + 1, m)]
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
                                _move_chain(ent, pos, c0, s, g, flip, buf, log)
                                improved = True
                                break
            if improved:
                moves += 1
                for t in range(n_touched):
                    it = touched[t]
                    if not queued[it] and it != item:
                        queued[it] = True
                        queue[_wrap(head + size, m)] = it
                        size += 1
    while size > 0:
        queued[queue[head]] = False
        head = (head + 1) % m
        size -= 1
    return moves, total_gain, budget


@njit()
def improve(
    pts: np.ndarray,
    ent: np.ndarray,
    near: np.ndarray,
    passes: int,
    kicks: int,
    seed: int,
    eps: float,
    depth: int,
    settled: int,
) -> int:
    """Flip chains and Or-opt to a local optimum, then ``kicks`` perturbation trials.

    A trial swaps two short neighbouring stretches of the tour (a local double bridge),
    searches again from the four changed joins and keeps the result only if the tour got
    shorter. A trial is undone (or kept) through the positions it changed, not by copying
    the tour. Works on ``ent`` in place; returns the improving moves and trials kept.
    ``depth`` is the longest flip chain; ``seed`` (0 to 2**32 - 1) seeds the trials.
    The sweeps end at one that finds no move, or fewer than one per ``settled`` items
    besides the start item (``settled`` 0: only at one that finds none).
    """
    m = ent.shape[0]
    pos = np.empty(m, dtype=np.int64)
    for p in range(m):
        pos[ent[p] >> 1] = p
    queue = np.empty(m, dtype=np.int64)
    queued = np.zeros(m, dtype=np.bool_)  # _search leaves it all False
    budget = passes * m
    moves = 0
    no_log = np.zeros(2, dtype=np.int64)
    while budget > 0:
        # A sweep: every item, in tour order. A fresh sweep finds moves the queue missed
        # (a chain's later flips look past the item's own edges); on long tours each
        # costs M items for a dwindling tail.
        for p in range(m):
            queue[p] = ent[p] >> 1
            queued[queue[p]] = True
        found, _gain, budget = _search(
            pts, ent, pos, near, queue, queued, m, budget, eps, no_log, depth
        )
        moves += found
        if found == 0 or (settled > 0 and found * settled < m - 1):
            break
    if m < 8:
        return moves
    np.random.seed(seed)
    saved_ent = ent.copy()
    window = min(50, (m - 1) // 3)
    # Positions a trial changed, to undo (or keep) it without copying the whole tour.
    log = np.zeros(2 + 64 * window + 4096, dtype=np.int64)
    tmp = np.empty(2 * window + 2, dtype=np.int64)
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
            _d(pts, ent[a] ^ 1, ent[a1])
            + _d(pts, ent[b] ^ 1, ent[b1])
            + _d(pts, ent[c] ^ 1, ent[c1])
        )
        after = (
            _d(pts, ent[a] ^ 1, ent[b1])
            + _d(pts, ent[c] ^ 1, ent[a1])
            + _d(pts, ent[b] ^ 1, ent[c1])
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
        # Not a literal 0: typing the loop, numba would also compile _search for a
        # Literal[int](0) size, which is never run but adds ~1 s to a cold compile.
        size = np.int64(0)
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
        found, gain, _left = _search(
            pts, ent, pos, near, queue, queued, size, 50 * size, eps, log, depth
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


@njit()
def cut_region(inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The items of a region's small tour, as tour position ranges [starts, ends].

    ``inside`` marks, per tour position, the items in the region. Walking the tour from
    the first item inside that follows one outside, every item inside is a range of its
    own and every maximal run outside is one range.
    """
    m = inside.shape[0]
    head = -1
    for p in range(m):
        if inside[p] and not inside[(p - 1) % m]:
            head = p
            break
    if head < 0:
        raise ValueError("cut_region: the region must hold some but not all items")
    starts = np.empty(m, dtype=np.int64)
    ends = np.empty(m, dtype=np.int64)
    w = 0
    for k in range(m):
        p = (head + k) % m
        if inside[p] or inside[(p - 1) % m]:
            starts[w] = p
            ends[w] = p
            w += 1
        else:
            ends[w - 1] = p
    return starts[:w], ends[:w]


@njit()
def expand_region(
    ent: np.ndarray, starts: np.ndarray, ends: np.ndarray, sub_ent: np.ndarray
) -> np.ndarray:
    """The whole tour from a region's small tour.

    Each range in turn, in the small tour's order; reversed if entered at its end.
    """
    m = ent.shape[0]
    out = np.empty(m, dtype=np.int64)
    n = 0
    for e in sub_ent:
        first = starts[e >> 1]
        count = (ends[e >> 1] - first) % m + 1
        if e & 1:
            for k in range(count - 1, -1, -1):
                out[n] = ent[(first + k) % m] ^ 1
                n += 1
        else:
            for k in range(count):
                out[n] = ent[(first + k) % m]
                n += 1
    return out


@njit()
def greedy_steps(
    near: np.ndarray, used: np.ndarray, entries: np.ndarray, step: int, cur: int
) -> tuple[int, int]:
    """Greedy nearest-neighbour steps from endpoint ``cur``, in place.

    Step ``step`` onwards: enter the nearest endpoint in ``near[cur]`` whose stroke is
    not ``used`` yet (ids >= 2N, the start item's, are skipped), record it in
    ``entries[step]``, mark the stroke used and go on from its other end. Stops when
    all strokes are used or no near endpoint is free; returns (steps done, endpoint).
    """
    n = used.shape[0]
    while step < n:
        nxt = -1
        for kk in range(near.shape[1]):
            f = near[cur, kk]
            if f < 2 * n and not used[f >> 1]:
                nxt = f
                break
        if nxt < 0:
            break
        used[nxt >> 1] = True
        entries[step] = nxt
        step += 1
        cur = nxt ^ 1
    return step, cur


def compile_state(functions: Sequence[Any]) -> Literal["ready", "once", "each run", "unknown"]:
    """Whether numba compiles any of ``functions`` (compiled here) before it runs.

    Returns:
        "ready": each is compiled in this process already, or numba's cache holds code of
        it for its current source and numba version (read from the cache's index files,
        nothing compiled); "once": one compiles, then is cached; "each run": one
        compiles, and numba cannot cache it here; "unknown": numba's cache did not answer
        (its internals changed, or an index unreadable).
    """
    try:
        pending = [f for f in functions if not f.signatures]
        if any(isinstance(f._cache, NullCache) for f in pending):
            return "each run"
        cached = all(f._cache._cache_file._load_index() for f in pending)
    except Exception:  # NUMBA_DISABLE_JIT, numba's internals changed, an unreadable index
        return "unknown"
    return "ready" if cached else "once"
