"""neighbour_pairs (compiled grid scan) against brute force and the KD-tree version it replaced.

The exact tests decide which pairs come out, so the set must equal, pair for pair, that of
every pair put through the brute-force form (numpy, all pairs), degenerate layouts and
pairs a rounding away from the reach or the parallel limit included.
"""

from __future__ import annotations

import math
import subprocess
import sys

import drjit as dr
import numpy as np
import pytest
from conftest import make_design
from scipy.spatial import cKDTree
from test_optimize_helpers import cross_of, make_layout

from scratchfab.optimize.loss import PARALLEL_LIMIT, neighbour_pairs, segment_distance_np
from scratchfab.optimize.optimizer import LayoutOptimizer, Settings


def brute_force(p0: np.ndarray, p1: np.ndarray, reach: float, angle_slack: float = 0.0) -> set:
    """Every pair (i < j) within the parallel limit and closer than ``reach``, over all pairs."""
    n = len(p0)
    if n < 2 or reach <= 0:
        return set()
    i, j = np.triu_indices(n, 1)
    d = p1 - p0
    length = np.linalg.norm(d, axis=1)
    cos = np.abs(np.sum(d[i] * d[j], axis=1)) / np.maximum(length[i] * length[j], 1e-300)
    limit = math.cos(min(math.pi / 2, PARALLEL_LIMIT + angle_slack))
    keep = (cos >= limit) & (segment_distance_np(p0, p1, i, j) < reach)
    return set(zip(i[keep].tolist(), j[keep].tolist(), strict=True))


def kd_tree_pairs(
    p0: np.ndarray, p1: np.ndarray, reach: float, angle_slack: float = 0.0, spacing: float = 16.0
) -> tuple[np.ndarray, np.ndarray]:
    """The version before the grid scan (KD-tree strips, numpy bounds), kept here to compare."""
    n = len(p0)
    if n < 2 or reach <= 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    d = p1 - p0
    length = np.linalg.norm(d, axis=1)
    count = np.maximum(1, np.ceil(length / max(spacing, reach))).astype(np.int64)
    owner = np.repeat(np.arange(n), count)
    first = np.cumsum(count) - count
    t = (np.arange(len(owner)) - first[owner] + 0.5) / count[owner]
    centre = p0[owner] + t[:, None] * d[owner]
    by_x = np.argsort(centre[:, 0], kind="stable")
    owner, centre = owner[by_x], centre[by_x]
    unit = (d / np.maximum(length, 1e-300)[:, None])[owner]
    half = (length / (2 * count))[owner]
    near = reach + 1e-6
    radius = 2 * float(half.max()) + near
    limit = math.cos(min(math.pi / 2, PARALLEL_LIMIT + angle_slack))
    found = [np.zeros(0, np.int64)]
    x = centre[:, 0]
    for start in range(0, len(owner), 512):
        end = min(start + 512, len(owner))
        last = int(np.searchsorted(x, x[end - 1] + radius, side="right"))
        tree = cKDTree(centre[start:end])
        inner = tree.query_pairs(radius, output_type="ndarray") + start
        candidates = [(inner[:, 0], inner[:, 1])]
        if last > end:
            outer = tree.sparse_distance_matrix(
                cKDTree(centre[end:last]), radius, output_type="ndarray"
            )
            candidates.append((outer["i"] + start, outer["j"] + end))
        for a, b in candidates:
            ua, ub = unit[a], unit[b]
            cos = np.abs(np.sum(ua * ub, axis=1))
            sin = np.abs(ua[:, 0] * ub[:, 1] - ua[:, 1] * ub[:, 0])
            dx, dy = (centre[b] - centre[a]).T
            ha, hb = half[a], half[b]
            ok = cos >= limit - 1e-9
            ok &= np.abs(ua[:, 0] * dy - ua[:, 1] * dx) - hb * sin < near
            ok &= np.abs(ub[:, 0] * dy - ub[:, 1] * dx) - ha * sin < near
            ok &= np.abs(ua[:, 0] * dx + ua[:, 1] * dy) - ha - hb * cos < near
            ok &= np.abs(ub[:, 0] * dx + ub[:, 1] * dy) - hb - ha * cos < near
            i, j = owner[a[ok]], owner[b[ok]]
            keep = i != j
            i, j = np.minimum(i[keep], j[keep]), np.maximum(i[keep], j[keep])
            cos = np.abs(np.sum(d[i] * d[j], axis=1)) / np.maximum(length[i] * length[j], 1e-300)
            keep = cos >= limit
            i, j = i[keep], j[keep]
            keep = segment_distance_np(p0, p1, i, j) < reach
            found.append(i[keep] * n + j[keep])
    keys = np.unique(np.concatenate(found))
    return keys // n, keys % n


def check(p0: np.ndarray, p1: np.ndarray, reach: float, slack: float = 0.0, **kw: int) -> set:
    """neighbour_pairs' pairs, checked sorted, unique and int64, equal to brute force."""
    i, j = neighbour_pairs(p0, p1, reach, slack, **kw)
    assert i.dtype == np.int64 and j.dtype == np.int64
    assert np.all(i < j)
    assert np.all(np.diff(i * max(len(p0), 1) + j) > 0)  # sorted by (i, j), no repeats
    got = set(zip(i.tolist(), j.tolist(), strict=True))
    assert got == brute_force(p0, p1, reach, slack)
    return got


def random_layout(rng: np.random.Generator, n: int, size: float, longest: float) -> tuple:
    c = rng.uniform(-size / 2, size / 2, (n, 2))
    a = rng.uniform(0, np.pi, n)
    h = rng.uniform(0, longest / 2, n)[:, None] * np.stack([np.cos(a), np.sin(a)], 1)
    return c - h, c + h


@pytest.mark.parametrize("n", [0, 1, 2])
def test_tiny_inputs(n):
    """No pair from fewer than two scratches; two parallel ones side by side make one."""
    p0 = np.array([[0.0, 0.0], [0.0, 0.3]])[:n]
    p1 = np.array([[5.0, 0.0], [5.0, 0.3]])[:n]
    got = check(p0, p1, 0.5)
    assert len(got) == (n == 2)
    assert len(check(p0, p1, 0.0)) == 0  # no reach, no pairs
    assert len(check(p0, p1, 0.3)) == 0  # 0.3 apart: not closer than 0.3


def test_degenerate_layouts(rng):
    """Points, repeats, collinear runs, crossings and parallel lines at the reach exactly."""
    reach = 0.5  # 0.5 and the offsets below are exact in binary
    p0, p1 = [], []
    # parallel, at the reach exactly (out), just inside (in), end to end on one line
    for k, y in enumerate([0.5, np.nextafter(0.5, 0.0), 0.25, 0.0]):
        p0 += [[10.0 * k, 0.0], [10.0 * k + 1.0, y]]
        p1 += [[10.0 * k + 4.0, 0.0], [10.0 * k + 5.0, y]]
    p0 += [[0.0, 20.0], [4.5, 20.0], [4.0, 20.0], [-3.0, 20.0]]  # collinear: gaps, overlap,
    p1 += [[4.0, 20.0], [8.0, 20.0], [4.0, 20.0], [-0.5, 20.0]]  # a point, touching at reach
    p0 += [[0.0, 40.0], [0.0, 40.0], [2.0, 38.0], [1.0, 40.0]]  # repeats, a crossing, a point
    p1 += [[5.0, 40.0], [5.0, 40.0], [3.0, 43.0], [1.0, 40.0]]  # on a scratch
    p0, p1 = np.array(p0), np.array(p1)
    got = check(p0, p1, reach)
    assert (0, 1) not in got and (2, 3) in got and (4, 5) in got and (6, 7) in got
    # scratches of zero length only: none is ever parallel to anything
    c = rng.uniform(0, 5, (40, 2))
    assert check(c, c.copy(), 1.0, 10.0) == set()
    assert check(c, c.copy(), 1e9) == set()
    # mixed with a few real scratches, every reach from tiny to all-encompassing
    q0, q1 = random_layout(rng, 120, 10.0, 4.0)
    q1[::7] = q0[::7]
    for reach in (1e-12, 0.05, 0.5, 3.0, 1e6, 1e300, np.inf):
        for slack in (0.0, 0.3, 10.0):
            check(q0, q1, reach, slack)
    assert len(check(q0, q1, 1e6, 10.0)) > len(check(q0, q1, 1e6)) > 1000


def test_pairs_a_rounding_away_from_the_reach(rng):
    """For random pairs, at a reach equal to their float64 distance they are out, one ulp above in.

    Any change of the float64 operations (their order, a fused multiply-add) moves some of
    these distances by an ulp.
    """
    for _ in range(150):
        p0 = rng.uniform(-30, 30, (2, 2))
        a = rng.uniform(0, 0.5) + np.array([0.0, rng.normal(0, 0.2)])
        p1 = p0 + rng.uniform(0.5, 8, (2, 1)) * np.stack([np.cos(a), np.sin(a)], 1)
        d = float(segment_distance_np(p0, p1, np.array([0]), np.array([1]))[0])
        if d == 0.0:
            continue
        assert len(check(p0, p1, d, 0.2)) == 0
        assert len(check(p0, p1, float(np.nextafter(d, np.inf)), 0.2)) == 1


def test_pairs_a_rounding_away_from_the_parallel_limit(rng):
    """Turned by the limit +- 1e-15 rad: the float64 cosine decides, as in brute force."""
    n = 400
    base = rng.uniform(0, 40, (n, 2))
    a = rng.uniform(0, np.pi, n)
    slack = 0.05
    turn = PARALLEL_LIMIT + slack + rng.choice([-1, 1], n) * rng.uniform(0, 3e-15, n)
    u = np.stack([np.cos(a), np.sin(a)], 1)
    v = np.stack([np.cos(a + turn), np.sin(a + turn)], 1)
    p0 = np.concatenate([base, base + 0.1 * u])
    p1 = np.concatenate([base + 3 * u, base + 0.1 * u + 3 * v])
    got = check(p0, p1, 0.2, slack)
    crossing = {(k, k + n) for k in range(n)}
    assert 0 < len(got & crossing) < n  # both sides of the limit occur


@pytest.mark.parametrize("slices", [1, 2, 5, 6, 7, 11])
def test_direction_slices_change_nothing(rng, monkeypatch, slices):
    """Pairs with one scratch on a slice boundary (0 = pi among them) and turned by the
    parallel limit, and random layouts: any number of slices gives brute force's pairs."""
    import scratchfab.optimize.loss as loss

    monkeypatch.setattr(loss, "NEIGHBOUR_DIRECTIONS", slices)
    scan = loss._compiled_scan()
    used = []

    def scan_and_note(*args: object) -> object:
        used.append(args[6])  # the slices it scans with
        return scan(*args)

    monkeypatch.setattr(loss, "_compiled_scan", lambda: scan_and_note)
    n = 300
    base = rng.uniform(0, 10, (n, 2))
    slack = 0.05
    turn = rng.choice([-1, 1], n) * (PARALLEL_LIMIT + slack + rng.uniform(-2e-15, 2e-15, n))
    # the first or the second (turned) of each pair on a boundary, give or take an ulp or 1e-7
    edges = np.arange(slices + 1) * np.pi / slices
    a = rng.choice(edges, n) - np.where(np.arange(n) % 2, turn, 0.0)
    a += rng.choice([0.0, -1e-15, 1e-15, -1e-7, 1e-7], n)
    u = np.stack([np.cos(a), np.sin(a)], 1)
    v = np.stack([np.cos(a + turn), np.sin(a + turn)], 1)
    p0 = np.concatenate([base, base + 0.1 * u])
    p1 = np.concatenate([base + 3 * u, base + 0.1 * u + 3 * v])
    got = check(p0, p1, 0.4, slack)
    assert set(used) == {slices}
    crossing = {(k, k + n) for k in range(n)}
    assert 0 < len(got & crossing) < n  # both sides of the limit occur
    # random directions and lengths, a few points among them, narrow and wide limits
    q0, q1 = random_layout(rng, 800, 30.0, 8.0)
    q1[::50] = q0[::50]
    for slack in (0.0, 0.5, 1.2):
        assert len(check(q0, q1, 1.0, slack)) > len(q0)


@pytest.mark.parametrize(
    ("n", "size", "longest", "reach", "slack", "spacing"),
    [
        (1500, 60.0, 12.0, 2.1, 0.07, 16.0),
        (2500, 150.0, 12.0, 0.6, 0.0, 16.0),
        (800, 30.0, 40.0, 1.0, 0.5, 3.0),  # long scratches, cut into pieces
        (600, 20.0, 6.0, 8.0, 0.07, 0.0),  # pieces as long as the reach
    ],
)
def test_same_pairs_as_the_kd_tree_version(rng, n, size, longest, reach, slack, spacing):
    """Random layouts of hundreds to thousands of scratches: the old and the new agree."""
    p0, p1 = random_layout(rng, n, size, longest)
    p1[:5] = p0[:5]
    i, j = neighbour_pairs(p0, p1, reach, slack, spacing=spacing)
    oi, oj = kd_tree_pairs(p0, p1, reach, slack, spacing=spacing)
    assert len(oi) > n / 10
    np.testing.assert_array_equal(i, oi)
    np.testing.assert_array_equal(j, oj)


def test_blocks_buffers_far_points_and_repeats_change_nothing(rng, monkeypatch):
    """Block sizes, a small pair buffer (copied out often, scans stopped early), a far
    outlier (a coarse grid) and a second call give the same pairs."""
    import scratchfab.optimize.loss as loss

    p0, p1 = random_layout(rng, 700, 25.0, 8.0)
    want = check(p0, p1, 0.8, 0.07)
    assert len(want) > 3 * len(p0)  # more than a buffer of 2 n pairs
    for strip_points in (1, 37, 100000):
        for buffer_pairs in (1, 1 << 20):
            monkeypatch.setattr(loss, "NEIGHBOUR_BUFFER_PAIRS", buffer_pairs)
            i, j = neighbour_pairs(p0, p1, 0.8, 0.07, strip_points=strip_points)
            assert np.all(np.diff(i * len(p0) + j) > 0)
            assert set(zip(i.tolist(), j.tolist(), strict=True)) == want
    far0 = np.concatenate([p0, [[1e7, -1e7]]])
    far1 = np.concatenate([p1, [[1e7 + 1.0, -1e7]]])
    i, j = neighbour_pairs(far0, far1, 0.8, 0.07)
    assert set(zip(i.tolist(), j.tolist(), strict=True)) == want
    again = neighbour_pairs(p0, p1, 0.8, 0.07)
    first = neighbour_pairs(p0, p1, 0.8, 0.07)
    narrow = neighbour_pairs(p0, p1, 0.8, 0.07, dtype=np.uint32)
    for x, y, z in zip(first, again, narrow, strict=True):
        np.testing.assert_array_equal(x, y)
        assert z.dtype == np.uint32
        np.testing.assert_array_equal(x, z)
    with pytest.raises(ValueError, match="int8 cannot hold"):
        neighbour_pairs(p0, p1, 0.8, 0.07, dtype=np.int8)


def test_refresh_on_one_thread_or_two(m):
    """A refresh finds brute force's merge candidates, on a second thread or not.

    With more than one Dr.Jit thread they are found beside the pixel pairs, on a thread of
    their own; the pixel pairs and the candidates must come out the same.
    """
    design = make_design(resolution=24, size_mm=30.0)
    targets, _ = cross_of(design)
    layout = make_layout(design, 400, seed=2)
    lr = {"cx": 0.05, "cy": 0.05, "theta": math.radians(1.0), "length": 0.05}
    before = dr.thread_count()
    found = []
    try:
        for threads in (1, 2):
            dr.set_thread_count(threads)
            opt = LayoutOptimizer(design, targets, layout, Settings(lr=lr), m)
            opt._refresh(opt.ends)
            first, second = (np.asarray(a, dtype=np.int64) for a in opt.neighbours)
            found.append(([(p.pixel_np, p.scratch_np) for p in opt.pairs], first, second))
    finally:
        dr.set_thread_count(before)
    (pairs_1, i1, j1), (pairs_2, i2, j2) = found
    for (pix_1, sc_1), (pix_2, sc_2) in zip(pairs_1, pairs_2, strict=True):
        np.testing.assert_array_equal(pix_1, pix_2)
        np.testing.assert_array_equal(sc_1, sc_2)
    np.testing.assert_array_equal(i1, i2)
    np.testing.assert_array_equal(j1, j2)
    e = opt.ends.astype(np.float64)
    reach = opt.tool_width + 2 * (opt.margin - float(np.max(opt.width)) / 2)
    want = brute_force(e[:, :2], e[:, 2:], reach, 16 * lr["theta"])
    assert set(zip(i1.tolist(), j1.tolist(), strict=True)) == want
    assert len(want) > 50


def test_numba_loads_on_first_use_only():
    """Importing the optimize stage loads neither numba nor scipy's KD-tree."""
    code = (
        "import sys, scratchfab.optimize.stage\n"
        "print(sorted(m for m in ('numba', 'scipy.spatial') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("offset", [-3e13, 1e14, 1e15])
def test_far_from_the_origin(rng, offset):
    """Layouts a long way from the origin: the bounds' slack grows past the rounding of
    the piece centres (ulps of the coordinates), so none of brute force's pairs is lost."""
    for reach, slack, longest, size in [(0.3, 0.3, 3.0, 10.0), (0.01, 0.05, 20.0, 1.0)]:
        p0, p1 = random_layout(rng, 300, size, longest)
        check(p0 + offset, p1 + offset, reach, slack)


def test_ends_not_finite(rng):
    """A scratch with a NaN or infinite end (or a length past float64) pairs with none, as
    in brute force; the others keep their pairs and their indices."""
    p0, p1 = random_layout(rng, 200, 15.0, 4.0)
    bad = [3, 50, 51, 120, 199]
    p0[3, 0], p1[50, 1], p0[51], p1[120, 0] = np.nan, np.inf, -np.inf, -np.inf
    p0[199], p1[199] = [-1e308, 0.0], [1e308, 0.0]  # finite ends, infinite length
    with np.errstate(invalid="ignore", over="ignore"):
        got = check(p0, p1, 1.0, 0.3)
        narrow = neighbour_pairs(p0, p1, 1.0, 0.3, dtype=np.uint32)
    assert not {k for pair in got for k in pair} & set(bad)
    ok = np.setdiff1d(np.arange(200), bad)
    i, j = neighbour_pairs(p0[ok], p1[ok], 1.0, 0.3)
    assert got == set(zip(ok[i].tolist(), ok[j].tolist(), strict=True))
    assert narrow[0].dtype == narrow[1].dtype == np.uint32
    assert set(zip(narrow[0].tolist(), narrow[1].tolist(), strict=True)) == got
    assert len(check(np.full((4, 2), np.nan), np.zeros((4, 2)), 1.0)) == 0


def test_concurrent_calls_on_threads(rng):
    """The scan runs without the GIL: calls on several threads at once give each its own
    pairs (no state shared between calls)."""
    from concurrent.futures import ThreadPoolExecutor

    layouts = [random_layout(rng, 1500, 30.0, 6.0) for _ in range(3)]
    want = [neighbour_pairs(a, b, 0.8, 0.07) for a, b in layouts]
    with ThreadPoolExecutor(4) as pool:
        got = list(
            pool.map(
                lambda k: neighbour_pairs(*layouts[k % 3], 0.8, 0.07, strip_points=61), range(12)
            )
        )
    for k, (i, j) in enumerate(got):
        np.testing.assert_array_equal(i, want[k % 3][0])
        np.testing.assert_array_equal(j, want[k % 3][1])


def test_buffer_renewed_before_a_scratch_that_may_not_fit(monkeypatch):
    """Scratches 1 to n - 1 side by side (each pairs with all after it) and scratch 0 beside
    the first ``near`` of them, on the smallest buffer (2 n pairs): scratch 2's n - 3 pairs
    come on a buffer with ``near`` + n - 2 used. Every scan call must be handed a buffer
    that holds its next scratch's pairs (or it stops at once, for ever), and the pairs must
    be brute force's.

    Over ``near`` = 1 .. n - 1 this finds any renewal rule "used + n - x > capacity" with
    x >= 4 (the exact bound before scratch i is n - 1 - i pairs).
    """
    import scratchfab.optimize.loss as loss

    scan = loss._compiled_scan()
    starts = []

    def scan_and_check(*args: object) -> tuple[int, int]:
        lo, used = args[19], args[23]
        got = scan(*args)
        starts.append(used)
        assert got[1] > lo, f"a scan from scratch {lo} with {used} of the buffer used stopped"
        return got

    monkeypatch.setattr(loss, "_compiled_scan", lambda: scan_and_check)
    monkeypatch.setattr(loss, "NEIGHBOUR_BUFFER_PAIRS", 1)
    reach = 1.0
    for n in (12, 41, 100):
        gap = 0.9 / (n - 2)  # lines 1 .. n - 1 within 0.9 of each other
        y = gap * np.arange(1, n, dtype=np.float64)
        for near in range(1, n):
            # scratch 0 below the lines, closer than the reach to the first ``near``
            y0 = gap * (near + 0.5) - reach
            ys = np.concatenate([[y0], y])
            p0 = np.stack([np.zeros(n), ys], 1)
            p1 = np.stack([np.full(n, 4.0), ys], 1)
            want = brute_force(p0, p1, reach)
            assert sum(a == 0 for a, _ in want) == near
            for strip_points in (1, 2, 100000):
                starts.clear()
                i, j = neighbour_pairs(p0, p1, reach, strip_points=strip_points)
                assert set(zip(i.tolist(), j.tolist(), strict=True)) == want
                assert np.all(np.diff(i * n + j) > 0)
                assert starts.count(0) >= 2  # renewed at least once
