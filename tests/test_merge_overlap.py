"""The merge penalty: the length two scratches cut twice, crossings at small angles included."""

from __future__ import annotations

import math

import drjit as dr
import numpy as np
import pytest

from scratchfab.optimize.loss import (
    PARALLEL_LIMIT,
    length_cut_twice,
    merge_penalty,
    neighbour_pairs,
)


def penalty(m, p0: np.ndarray, p1: np.ndarray, i, j, width: float) -> float:
    """merge_penalty of the pairs (i, j) as a float."""
    return with_gradient(m.Float64, m.UInt32, p0, p1, i, j, width)[0]


def with_gradient(F, U, p0: np.ndarray, p1: np.ndarray, i, j, width: float):
    """merge_penalty of the pairs (i, j) in float type F, and its gradient (4, n) by AD."""
    ends = [F(p0[:, 0]), F(p0[:, 1]), F(p1[:, 0]), F(p1[:, 1])]
    for a in ends:
        dr.enable_grad(a)
    total = merge_penalty(F, *ends, U(i), U(j), width)
    dr.backward(total)
    return float(total[0]), np.array([np.array(dr.grad(a), dtype=np.float64) for a in ends])


def quadrature(p0: np.ndarray, p1: np.ndarray, i, j, width: float, n: int = 200_000) -> float:
    """The penalty's definition by the midpoint rule: each scratch sampled at n points.

    Per pair, the mean over both orders of: along scratch a, the length weighted by
    relu(1 - q / width)^2, q the distance of the point from scratch b's line, over the
    points that project onto scratch b.
    """
    t = (np.arange(n) + 0.5) / n
    total = 0.0
    for k, m_ in zip(i, j, strict=True):
        for a, b in ((k, m_), (m_, k)):
            e, f = p1[a] - p0[a], p1[b] - p0[b]
            lf = np.linalg.norm(f)
            rel = p0[a] + t[:, None] * e - p0[b]
            along = rel @ f / lf
            across = np.abs(rel @ np.array([-f[1], f[0]])) / lf
            weight = np.maximum(1 - across / width, 0) ** 2 * ((along >= 0) & (along <= lf))
            total += 0.5 * weight.mean() * np.linalg.norm(e)
    return total


def test_the_penalty_matches_its_definition(m, rng) -> None:
    """Random near-parallel pairs (some reversed, some crossing) against the quadrature."""
    n = 24
    c = rng.uniform(-0.6, 0.6, (n, 2))
    ang = rng.uniform(-0.5, 0.5, n) + np.where(rng.uniform(size=n) < 0.3, math.pi, 0.0)
    half = np.stack([np.cos(ang), np.sin(ang)], 1) * rng.uniform(0.3, 2, n)[:, None]
    p0, p1 = c - half, c + half
    i, j = np.triu_indices(n, 1)
    width = 0.4
    ref = quadrature(p0, p1, i, j, width)
    assert ref > 1.0
    assert penalty(m, p0, p1, i, j, width) == pytest.approx(ref, rel=1e-6)


@pytest.mark.parametrize("degrees", [2.0, 5.0, 10.0, 20.0, 30.0])
def test_a_small_angle_crossing_costs_its_doubly_cut_length(m, degrees: float) -> None:
    """Long scratches crossing at angle a far from their ends: (2 w / 3) / sin a.

    The closeness weight relu(1 - |x| sin a / w)^2 integrates over x to (2 w / 3) / sin a
    (each scratch's length within w of the other is 2 w / sin a), whatever the ends do.
    """
    a, width = math.radians(degrees), 0.1
    p0 = np.array([[-30.0, 0.0], [-30.0 * math.cos(a), -30.0 * math.sin(a)]])
    p1 = -p0
    expected = (2 * width / 3) / math.sin(a)
    assert penalty(m, p0, p1, [0], [1], width) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("gap", [0.0, 0.03, 0.07, 0.1, 0.15])
def test_side_by_side_scratches_cost_their_shared_length(m, gap: float) -> None:
    """Parallel scratches ``gap`` apart sharing 3 of their 5 mm: 3 (1 - gap / w)^2."""
    p0 = np.array([[0.0, 0.0], [2.0, gap]])
    p1 = np.array([[5.0, 0.0], [7.0, gap]])
    expected = 3.0 * max(1 - gap / 0.1, 0.0) ** 2
    assert penalty(m, p0, p1, [0], [1], 0.1) == pytest.approx(expected, rel=1e-9, abs=1e-12)
    # reversing either scratch changes nothing
    back0, back1 = np.array([p0[0], p1[1]]), np.array([p1[0], p0[1]])
    assert penalty(m, back0, back1, [0], [1], 0.1) == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_the_gradient_matches_central_differences(m, rng) -> None:
    """d(penalty)/d(endpoints) of close pairs, crossing and side by side, numerically."""
    n = 12
    c = rng.uniform(-0.15, 0.15, (n, 2))
    ang = rng.uniform(-0.4, 0.4, n)
    half = np.stack([np.cos(ang), np.sin(ang)], 1) * rng.uniform(0.5, 1.5, n)[:, None]
    p0, p1 = c - half, c + half
    i, j = np.triu_indices(n, 1)
    width = 0.2
    F, U = m.Float64, m.UInt32
    arrays = [F(p0[:, 0]), F(p0[:, 1]), F(p1[:, 0]), F(p1[:, 1])]
    for a in arrays:
        dr.enable_grad(a)
    total = merge_penalty(F, *arrays, U(i), U(j), width)
    dr.backward(total)
    grad = [np.array(dr.grad(a), dtype=np.float64) for a in arrays]
    values = [p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1]]

    def at(changed: list[np.ndarray]) -> float:
        with dr.suspend_grad():
            return float(merge_penalty(F, *(F(v) for v in changed), U(i), U(j), width)[0])

    h = 1e-6
    scale = max(float(np.abs(g).max()) for g in grad)
    checked = 0
    for c_ in range(4):
        for k in range(n):
            plus = [v.copy() for v in values]
            minus = [v.copy() for v in values]
            plus[c_][k] += h
            minus[c_][k] -= h
            fd = (at(plus) - at(minus)) / (2 * h)
            if abs(fd) > 1e-3 * scale:
                checked += 1
                assert grad[c_][k] == pytest.approx(fd, rel=1e-5, abs=1e-7 * scale), (c_, k)
    assert checked >= 30


def test_small_angle_crossings_are_merge_candidates() -> None:
    """Crossing pairs within the parallel limit are candidates however far their ends are."""
    angles = [2.0, 5.0, 10.0, 20.0, 30.0, 34.0, 36.0, 50.0]
    p0, p1 = [], []
    for k, degrees in enumerate(angles):
        a = math.radians(degrees)
        centre = np.array([0.0, 40.0 * k])
        for turn in (0.0, a):
            d = 6.0 * np.array([math.cos(turn), math.sin(turn)])
            p0.append(centre - d)
            p1.append(centre + d)
    i, j = neighbour_pairs(np.array(p0), np.array(p1), reach=0.1)
    found = set(zip(i.tolist(), j.tolist(), strict=True))
    within = {(2 * k, 2 * k + 1) for k, d in enumerate(angles) if d < math.degrees(PARALLEL_LIMIT)}
    assert found == within


def near_parallel_pairs(rng, n: int, width: float, offset: np.ndarray):
    """n pairs side by side within ``width``, turned 1e-8 to 1e-2 width over their length.

    Their ends' distances from the other's line then differ by 1e-8 to 1e-2 width,
    where a difference quotient of the weight's antiderivative would cancel.
    """
    c = rng.uniform(-1, 1, (n, 2))
    ang = rng.uniform(0, math.pi, n)
    d = np.stack([np.cos(ang), np.sin(ang)], 1)
    length = rng.uniform(2, 6, n)
    turn = rng.choice([-1, 1], n) * 10 ** rng.uniform(-8, -2, n) * width / length
    turned = np.stack([np.cos(ang + turn), np.sin(ang + turn)], 1)
    side = rng.uniform(0.1, 0.9, n) * width * rng.choice([-1, 1], n)
    c2 = c + side[:, None] * np.stack([-d[:, 1], d[:, 0]], 1) + rng.uniform(-1, 1, (n, 1)) * d
    half, half2 = d * length[:, None] / 2, turned * length[:, None] / 2
    p0 = np.concatenate([c - half, c2 - half2]) + offset
    p1 = np.concatenate([c + half, c2 + half2]) + offset
    return p0, p1, np.arange(n), np.arange(n) + n


@pytest.mark.parametrize("offset", [(0.0, 0.0), (450.0, 310.0)])
def test_near_parallel_pairs_keep_their_precision_in_float32(m, rng, offset) -> None:
    """Float32 value and gradient agree with float64's, on a board at the origin or off it.

    A 300 mm board centred at (450, 310) rounds its float32 ends by up to 3e-5 mm, which
    bounds the agreement; the float64 values meet the quadrature.
    """
    width = 0.1
    p0, p1, i, j = near_parallel_pairs(rng, 200, width, np.array(offset))
    value, grad = with_gradient(m.Float64, m.UInt32, p0, p1, i, j, width)
    assert value == pytest.approx(quadrature(p0, p1, i, j, width), rel=1e-6)
    value32, grad32 = with_gradient(m.Float32, m.UInt32, p0, p1, i, j, width)
    assert value32 == pytest.approx(value, rel=1e-3)
    assert np.abs(grad32 - grad).max() < 1e-2 * np.abs(grad).max()


@pytest.mark.parametrize("float_type", ["Float32", "Float64"])
@pytest.mark.parametrize(
    "ends",
    [
        ([[0, 0], [0, 0]], [[5, 0], [5, 0]]),  # identical
        ([[0, 0], [5, 0]], [[5, 0], [0, 0]]),  # identical, one reversed
        ([[0, 0], [2, 0]], [[5, 0], [7, 0]]),  # collinear, overlapping
        ([[0, 0], [5, 0]], [[5, 0], [9, 0]]),  # collinear, end to end
        ([[0, 0], [2, 0]], [[5, 0], [6, 0.5]]),  # T-junction: an end of one on the other
        ([[0, 0], [2, 0.1]], [[5, 0], [7, 0.1]]),  # side by side at the width
        ([[0, 0], [2, 0.03]], [[5, 0], [2 + 3e-7, 5.03]]),  # nearly perpendicular
    ],
)
def test_degenerate_pairs_cost_their_definition(m, float_type: str, ends) -> None:
    """Pairs at the closed form's edge cases: the quadrature's value, a finite gradient."""
    p0, p1 = np.array(ends[0], float), np.array(ends[1], float)
    value, grad = with_gradient(getattr(m, float_type), m.UInt32, p0, p1, [0], [1], 0.1)
    tol = 1e-6 if float_type == "Float32" else 1e-9
    assert value == pytest.approx(quadrature(p0, p1, [0], [1], 0.1), rel=1e-4, abs=tol)
    assert np.isfinite(grad).all()


@pytest.mark.parametrize("float_type", ["Float32", "Float64"])
@pytest.mark.parametrize("length", [0.0, 1e-12])
def test_a_scratch_of_no_length_overlaps_nothing(m, float_type: str, length: float) -> None:
    """A point on or beside a scratch (either order) shares none of its length."""
    p0 = np.array([[0.0, 0.0], [2.0, 0.02], [0.0, 1.0]])
    p1 = np.array([[5.0, 0.0], [2.0 + length, 0.02], [5.0, 1.0]])
    for i, j in (([0, 2], [1, 1]), ([1, 1], [0, 2])):
        value, grad = with_gradient(getattr(m, float_type), m.UInt32, p0, p1, i, j, 0.1)
        assert abs(value) < 1e-9
        assert np.isfinite(grad).all()


def hand_made_layout() -> tuple[np.ndarray, np.ndarray]:
    """Groups of scratches 30 mm apart, each a case of the measure (width 0.1 mm).

    Side by side 0.03 mm apart over 3 mm; crossing at 20 and 34 degrees (counted) and
    40 degrees (not); parallel 0.12 mm apart (too far); end to end on one line; three
    side by side within the width (three pairs); a crossing at 5 degrees near an end.
    """
    groups = [
        [((0, 0), (5, 0)), ((2, 0.03), (7, 0.03))],
        [((-6, 0), (6, 0)), ((-6 * math.cos(0.349), -6 * math.sin(0.349)),
                             (6 * math.cos(0.349), 6 * math.sin(0.349)))],
        [((-6, 0), (6, 0)), ((-6 * math.cos(0.593), -6 * math.sin(0.593)),
                             (6 * math.cos(0.593), 6 * math.sin(0.593)))],
        [((-6, 0), (6, 0)), ((-6 * math.cos(0.698), -6 * math.sin(0.698)),
                             (6 * math.cos(0.698), 6 * math.sin(0.698)))],
        [((0, 0), (8, 0)), ((1, 0.12), (9, 0.12))],
        [((0, 0), (4, 0)), ((4, 0), (9, 0))],
        [((0, 0), (6, 0.01)), ((1, 0.04), (7, 0.05)), ((-1, 0.08), (4, 0.07))],
        [((0, 0), (10, 0)), ((9.5, -0.02), (9.5 + 6 * math.cos(0.087), 6 * math.sin(0.087)))],
    ]  # fmt: skip
    p0, p1 = [], []
    for g, group in enumerate(groups):
        for a, b in group:
            p0.append(np.add(a, (30.0 * g, 0.0)))
            p1.append(np.add(b, (30.0 * g, 0.0)))
    return np.array(p0, dtype=np.float64), np.array(p1, dtype=np.float64)


def sampled_length_cut_twice(p0: np.ndarray, p1: np.ndarray, width: float, n: int = 100_000):
    """Brute force over every pair within the parallel limit: points along each scratch.

    Per pair, half the sum over both orders of: the points of scratch a within the width
    of scratch b's line and projecting onto b, each counting its share of a's length
    weighted by relu(1 - q / width)^2.
    """
    t = (np.arange(n) + 0.5) / n
    out = {}
    for a in range(len(p0)):
        for b in range(a + 1, len(p0)):
            e, f = p1[a] - p0[a], p1[b] - p0[b]
            cos = abs(e @ f) / (np.linalg.norm(e) * np.linalg.norm(f))
            if math.acos(min(cos, 1.0)) > PARALLEL_LIMIT:
                continue
            total = 0.0
            for x, y in ((a, b), (b, a)):
                u, v = p1[x] - p0[x], p1[y] - p0[y]
                lv = np.linalg.norm(v)
                rel = p0[x] + t[:, None] * u - p0[y]
                along = rel @ v / lv
                q = np.abs(rel @ np.array([-v[1], v[0]])) / lv
                on = (along >= 0) & (along <= lv) & (q < width)
                total += 0.5 * np.sum((1 - q[on] / width) ** 2) / n * np.linalg.norm(u)
            if total > 0:
                out[(a, b)] = total
    return out


def test_length_cut_twice_matches_sampling_of_hand_made_pairs() -> None:
    """length_cut_twice of a layout: the same pairs and lengths as brute-force sampling.

    The closed forms check the sampling: side by side 3 (1 - 0.3)^2 mm, crossing at a
    far from the ends (2 w / 3) / sin a.
    """
    width = 0.1
    p0, p1 = hand_made_layout()
    i, j, mm = length_cut_twice(p0, p1, width)
    got = {(int(a), int(b)): float(v) for a, b, v in zip(i, j, mm, strict=True) if v > 0}
    want = sampled_length_cut_twice(p0, p1, width)
    assert got.keys() == want.keys()
    for key, value in want.items():
        assert got[key] == pytest.approx(value, rel=1e-3, abs=1e-6), key
    assert want[(0, 1)] == pytest.approx(3 * 0.7**2, rel=1e-3)
    for pair, a in (((2, 3), 0.349), ((4, 5), 0.593)):
        assert want[pair] == pytest.approx((2 * width / 3) / math.sin(a), rel=1e-3)
    assert {(6, 7), (8, 9), (10, 11)}.isdisjoint(want)  # 40 degrees, too far, end to end
    assert {(12, 13), (12, 14), (13, 14), (15, 16)} <= want.keys()
    assert float(mm.sum()) == pytest.approx(sum(want.values()), rel=1e-3)


def test_length_cut_twice_of_no_pairs() -> None:
    """Scratches far apart: no pair and nothing cut twice."""
    p0 = np.array([[0.0, 0.0], [0.0, 5.0]])
    i, j, mm = length_cut_twice(p0, p0 + [4.0, 0.0], 0.1)
    assert len(i) == len(j) == len(mm) == 0
