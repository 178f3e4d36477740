"""The objective: per-view image error with closed-form exposure, plus layout penalties.

Image term, per view k over its pixels M_k (finite target: on the board, and not where
the bare board glints, :mod:`scratchfab.optimize.glint`):

    s_k = sum(R T) / sum(R^2)                  (the exposure of SPEC section 7)
    E_k = sum((g(s_k R) - g(T))^2) / sum(g(T)^2)

with g the identity (``space = "linear"``) or the sRGB encoding (``"perceptual"``). In
linear space s_k minimises E_k, so by the envelope theorem dE_k/dR is the same whether
or not s_k is differentiated: it is detached, which saves a reduction in the adjoint.
In perceptual space s_k (still the linear optimum) does not minimise E_k, so it is
differentiated: the gradient is that of E_k itself.
Dividing by the target's energy makes the views weigh alike whatever their brightness.

Linear against perceptual, measured (``benchmarks/bench_optimize.py --spaces
linear,perceptual``, demo, 150 iterations from the design stage's layout, checked with
the tests' brute-force renderer): linear reached PSNR 21.1 / 27.5 dB, rho 0.973 / 0.994
and crosstalk 0.021 / 0.016 (sun / house); perceptual 18.4 / 22.8 dB, rho 0.949 / 0.982,
crosstalk 0.026 / 0.034. The quality measures of SPEC section 7 are linear and the
perceptual error spends scratches on dark-tone detail the measures do not reward, so
``linear`` is the default.

Merge penalty: two scratches closer than the tool width are cut as one wider groove
where they overlap, side by side or crossing at a small angle a (each then lies within
the width of the other over about 2 width / sin a of its length, however far apart
their ends are). For candidate pairs (i, j) (:func:`neighbour_pairs`: within
PARALLEL_LIMIT of parallel and closer than the reach, or crossing) the penalty is the
mean over both orders of

    integral along scratch i of relu(1 - q / width)^2 dl     (mm)

with q the distance of the point from scratch j's line, over the points of i that
project onto j: the length of i within the tool width of j, weighted by how close. q
is linear along i, so the integral is a difference quotient of an antiderivative of
the weight, in closed form, written so that nothing cancels as the pair nears parallel
(:func:`_hat_mean`). It is continuous; its gradient jumps only where the overlap's
limit passes from one end to another (an end of i past the perpendicular at an end of
j), as a distance's does. Side by side at distance d over a shared length L it is
L (1 - d / width)^2; crossing at angle a away from the ends, (2 width / 3) / sin a (at
the parallel limit 1.16 width: a small step when a pair leaves the candidates).

It replaced ``cos^16(angle) * relu(1 - d_ij / width)^2``, d_ij the least of the four
endpoint-to-segment distances, which did not see crossings. Measured
(``benchmarks/bench_quality.py``, demo, 3 layout seeds, 300 steps): at merge_weight 0.02
against that form's 0.05, the length cut twice by pairs within 10 degrees of parallel
fell 54 % (2766 to 1276 mm) and mean PSNR rose 0.8 dB (28.7 to 29.5; Mitsuba's, 1024
spp, 26.4 to 26.6). Weighing this form by cos^16 of the angle as well cost about 0.1 dB
at the same length cut twice.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Literal

import drjit as dr
import numpy as np

from scratchfab.backend import array_module, jit_array

Space = Literal["linear", "perceptual"]
SPACES: tuple[str, ...] = ("linear", "perceptual")

#: The merge penalty's form, kept in checkpoints: a run made under another form (the
#: earlier one weighed the nearest scratch ends by ``cos^16`` of the angle) does not resume.
MERGE_PENALTY = "length cut twice"
#: Pairs more than this far from parallel are never merge candidates (radians).
PARALLEL_LIMIT = math.radians(35.0)
#: Longest piece :func:`neighbour_pairs` cuts a scratch into (longer than the 12 mm default
#: maximum length, so scratches stay whole, while a few long ones cannot widen every query).
NEIGHBOUR_SPACING_MM = 16.0
#: Scratches per call of :func:`neighbour_pairs`' compiled scan.
NEIGHBOUR_STRIP_POINTS = 4096
#: Grid cells of :func:`neighbour_pairs`, relative to the longest half piece plus the
#: reach (a piece looks this far and its own half length around itself).
NEIGHBOUR_CELL = 0.35
#: Direction slices of :func:`neighbour_pairs` (equal slices of [0, pi)): a piece looks
#: only into those the parallel limit lets it pair with.
NEIGHBOUR_DIRECTIONS = 6
#: Pairs :func:`neighbour_pairs` buffers before it starts a fresh buffer (at least 2 per
#: scratch).
NEIGHBOUR_BUFFER_PAIRS = 1 << 20
#: Slack (mm) of :func:`neighbour_pairs`' bounds, far above float64 rounding on a board
#: (past about 70 km from the origin it grows with the coordinates).
NEIGHBOUR_SLACK_MM = 1e-6


def srgb_encode(x: Any) -> Any:
    """The sRGB transfer function (IEC 61966-2-1) on Dr.Jit arrays, x >= 0."""
    lin = x * 12.92
    curve = 1.055 * dr.power(dr.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055
    return dr.select(x <= 0.0031308, lin, curve)


def view_error(render: Any, target: Any, mask: Any, space: Space) -> tuple[Any, Any]:
    """(E_k, s_k) for one view as Dr.Jit scalars (size-1 arrays, not evaluated).

    Args:
        render: R_k (H * W,) Float.
        target: T_k (H * W,) Float, 0 where ``mask`` is.
        mask: (H * W,) Float, 1 on the pixels the error counts (on the board, no glint),
            0 elsewhere.
        space: ``"linear"`` or ``"perceptual"``.
    """
    r = render * mask
    rt = dr.sum(r * target, mode="symbolic")
    rr = dr.sum(r * r, mode="symbolic")
    s = rt / dr.select(rr > 0, rr, 1.0)  # scale-free: a dim render's rr may be below 1e-30
    if space == "linear":
        s = dr.detach(s)
        diff = s * r - target
        norm = dr.sum(target * target, mode="symbolic")
    else:
        enc_t = srgb_encode(target)
        diff = (srgb_encode(s * dr.maximum(r, 0.0)) - enc_t) * mask
        norm = dr.sum(enc_t * enc_t * mask, mode="symbolic")
    err = dr.sum(diff * diff, mode="symbolic") / dr.maximum(norm, 1e-30)
    return err, s


def merge_penalty(
    Float: type,
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    first: Any,
    second: Any,
    tool_width: float,
) -> Any:
    """Sum of the merge penalty over candidate pairs (mm, Dr.Jit scalar, not evaluated)."""
    terms = pair_overlaps(Float, p0x, p0y, p1x, p1y, first, second, tool_width)
    return dr.sum(terms, mode="symbolic")


def pair_overlaps(
    Float: type,
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    first: Any,
    second: Any,
    tool_width: float,
) -> Any:
    """The merge penalty of each candidate pair (mm, Dr.Jit array, not evaluated).

    The mean over both orders of the length of one scratch within the tool width of the
    other, weighted by relu(1 - q / width)^2 (the module's docstring).
    """
    ax: Any = dr.gather(Float, p0x, first)
    ay: Any = dr.gather(Float, p0y, first)
    bx: Any = dr.gather(Float, p1x, first)
    by: Any = dr.gather(Float, p1y, first)
    cx: Any = dr.gather(Float, p0x, second)
    cy: Any = dr.gather(Float, p0y, second)
    ex: Any = dr.gather(Float, p1x, second)
    ey: Any = dr.gather(Float, p1y, second)
    ux, uy = bx - ax, by - ay
    vx, vy = ex - cx, ey - cy
    lu = dr.sqrt(dr.maximum(ux * ux + uy * uy, 1e-20))
    lv = dr.sqrt(dr.maximum(vx * vx + vy * vy, 1e-20))
    both = _overlap(ax, ay, ux, uy, lu, cx, cy, vx, vy, lv, tool_width)
    both = both + _overlap(cx, cy, vx, vy, lv, ax, ay, ux, uy, lu, tool_width)
    return 0.5 * both


def length_cut_twice(
    p0: np.ndarray, p1: np.ndarray, tool_width: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The merge penalty of a finished layout, pair by pair, as the optimizer counts it.

    The candidates are :func:`neighbour_pairs` closer than the tool width (those the
    final loss takes), each weighed by :func:`pair_overlaps` in float64 on the LLVM
    backend; their sum is the length the machine cuts twice, weighted by how close.

    Args:
        p0: (n, 2) scratch starts (mm).
        p1: (n, 2) scratch ends (mm).
        tool_width: The tool's width (mm).

    Returns:
        (i, j, mm): the candidate pairs (i < j) and each one's weighted length cut twice.
    """
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    i, j = neighbour_pairs(p0, p1, tool_width, dtype=np.uint32)
    if len(i) == 0:
        return i, j, np.zeros(0)
    m = array_module("llvm")
    F, U = m.Float64, m.UInt32
    ax, ay, bx, by = (jit_array(F, c) for c in (p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1]))
    first, second = jit_array(U, i, np.uint32), jit_array(U, j, np.uint32)
    with dr.suspend_grad():
        terms = pair_overlaps(F, ax, ay, bx, by, first, second, tool_width)
        return i, j, np.array(terms, dtype=np.float64)


def _overlap(
    ax: Any, ay: Any, ux: Any, uy: Any, lu: Any,
    cx: Any, cy: Any, vx: Any, vy: Any, lv: Any, width: float,
) -> Any:  # fmt: skip
    """Length of segments a + t u weighted by closeness to the segments c + s v (mm).

    The integral over t in [0, 1] of ``|u| * relu(1 - |q| / width)^2``, with q the signed
    distance of a + t u from the line of c + s v, over the points that project onto
    the segment c + s v itself (none onto a segment of no length, below 1e-10 mm).
    """
    nx, ny = -vy / lv, vx / lv
    wx, wy = ax - cx, ay - cy
    q0 = nx * wx + ny * wy
    dq = nx * ux + ny * uy
    # where the point projects onto c + s v: s lv = p0 + t dp, within [0, lv]
    p0 = (vx * wx + vy * wy) / lv
    dp = (vx * ux + vy * uy) / lv
    dp = dr.select(dr.abs(dp) > 1e-12, dp, 1e-12)
    t_a = -p0 / dp
    t_b = (lv - p0) / dp
    lo = dr.maximum(dr.minimum(t_a, t_b), 0.0)
    hi = dr.maximum(dr.minimum(dr.maximum(t_a, t_b), 1.0), lo)
    # lv is clamped at 1e-10: a shorter segment's normal (n) would be too short
    hi = dr.select(vx * vx + vy * vy > 1e-20, hi, lo)
    return (hi - lo) * lu * _hat_mean(q0 + lo * dq, q0 + hi * dq, width)


def _hat_mean(qa: Any, qb: Any, width: float) -> Any:
    """The mean of relu(1 - |q| / width)^2 over q in [qa, qb] (either order), in closed form.

    It is the difference quotient of the antiderivative F(q) = sign(q) (m / 3)
    (1 + r + r^2), m = min(|q|, width), r = 1 - m / width, written so that nothing
    cancels as qa and qb meet (a pair near parallel), in float32 too: across the line
    (opposite signs) (|F(qa)| + |F(qb)|) / (|qa| + |qb|); on one side the fraction of
    [qa, qb] within the width times (ra^2 + ra rb + rb^2) / 3, that fraction 1 when
    both are within it.
    """
    aa, ab = dr.abs(qa), dr.abs(qb)
    ma, mb = dr.minimum(aa, width), dr.minimum(ab, width)
    ra, rb = 1.0 - ma / width, 1.0 - mb / width
    opposite = qa * qb < 0.0
    fa = ma * (1.0 + ra + ra * ra)
    fb = mb * (1.0 + rb + rb * rb)
    across = (fa + fb) / dr.select(opposite, 3.0 * (aa + ab), 1.0)
    differ = ab != aa
    within = (mb - ma) / dr.select(differ, ab - aa, 1.0)
    within = dr.select((aa <= width) & (ab <= width), 1.0, dr.select(differ, within, 0.0))
    side = within * (ra * ra + ra * rb + rb * rb) / 3.0
    return dr.select(opposite, across, side)


def segment_distance_np(p0: np.ndarray, p1: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Distance between segments i and j (numpy; 0 when they cross)."""

    def point_seg(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = b - a
        ll = np.maximum(np.sum(d * d, axis=1), 1e-300)
        t = np.clip(np.sum((p - a) * d, axis=1) / ll, 0.0, 1.0)
        return np.linalg.norm(p - a - t[:, None] * d, axis=1)

    a, b, c, e = p0[i], p1[i], p0[j], p1[j]
    d = np.minimum.reduce(
        [point_seg(a, c, e), point_seg(b, c, e), point_seg(c, a, b), point_seg(e, a, b)]
    )

    def orient(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        return np.sign(
            (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])
        )

    cross = (orient(a, b, c) * orient(a, b, e) < 0) & (orient(c, e, a) * orient(c, e, b) < 0)
    return np.where(cross, 0.0, d)


def neighbour_pairs(
    p0: np.ndarray,
    p1: np.ndarray,
    reach: float,
    angle_slack: float = 0.0,
    spacing: float = NEIGHBOUR_SPACING_MM,
    strip_points: int = NEIGHBOUR_STRIP_POINTS,
    dtype: Any = np.int64,
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i < j) of scratches closer than ``reach`` and within the parallel limit.

    Each scratch is cut into equal pieces at most ``max(spacing, reach)`` long (most
    scratches stay whole). Two scratches closer than ``reach`` have two pieces, one of
    each, whose centres are closer than their half lengths plus ``reach``, so a look
    around each piece of scratch i, over the cells of a uniform grid of the piece
    centres, for the pieces of scratches j > i is complete. Each cell is split by the
    direction of the pieces (NEIGHBOUR_DIRECTIONS slices of [0, pi)), and a piece looks
    only into the slices within the parallel limit of its own direction (widened by
    1e-6 rad, far above the rounding of the angles). The piece pairs it finds are first
    thinned by bounds that never drop a close pair: the angle between them, and the
    separating-axis bound (projections onto either piece's direction and normal are
    no longer than the distance). The scratch pairs left then meet the exact tests,
    the float64 operations of the brute-force form (:func:`segment_distance_np`) in the
    same order: the parallel limit PARALLEL_LIMIT + ``angle_slack`` (weights below 0.05
    past it) and the segment distance. The scan is compiled (numba, loaded on first
    use), ``strip_points`` scratches a call; it finds the pairs in (i, j) order into
    buffers of NEIGHBOUR_BUFFER_PAIRS, so memory follows the pairs found.

    Returns:
        (i, j), sorted by (i, j), of integer type ``dtype`` (which must hold n - 1).
    """
    n = len(p0)
    if n < 2 or reach <= 0:
        return np.zeros(0, dtype), np.zeros(0, dtype)
    if n - 1 > np.iinfo(dtype).max:
        raise ValueError(f"{np.dtype(dtype)} cannot hold the indices of {n} scratches")
    p0 = np.asarray(p0, dtype=np.float64)
    p1 = np.asarray(p1, dtype=np.float64)
    d = p1 - p0
    length = np.linalg.norm(d, axis=1)
    finite = np.isfinite(p0).all(axis=1) & np.isfinite(p1).all(axis=1) & np.isfinite(length)
    if not finite.all():
        # NaN fails the exact tests (as in numpy): such a scratch pairs with none, and
        # the others are scanned under their own indices
        keep = np.flatnonzero(finite)
        i, j = neighbour_pairs(p0[keep], p1[keep], reach, angle_slack, spacing, strip_points)
        return keep[i].astype(dtype), keep[j].astype(dtype)
    count = np.maximum(1, np.ceil(length / max(spacing, reach))).astype(np.int64)
    owner = np.repeat(np.arange(n), count)
    first = np.cumsum(count) - count
    t = (np.arange(len(owner)) - first[owner] + 0.5) / count[owner]
    centre = p0[owner] + t[:, None] * d[owner]
    unit = d / np.maximum(length, 1e-300)[:, None]
    half = (length / (2 * count))[owner]
    # the bounds get a little slack, the exact tests none; far from the origin, more
    # than the rounding of the piece centres (a few ulps of the coordinates)
    near = reach + max(NEIGHBOUR_SLACK_MM, 64 * np.finfo(np.float64).eps * _largest(p0, p1))
    limit = math.cos(min(math.pi / 2, PARALLEL_LIMIT + angle_slack))
    longest = float(half.max())
    grid = _grid(centre, NEIGHBOUR_CELL * (longest + near))
    cells = grid.nx * grid.ny
    # no more direction slices than keep the cell table within 8 entries a piece
    slices = max(1, min(NEIGHBOUR_DIRECTIONS, (8 * len(owner) + 64) // cells))
    # direction in [0, pi] (the ends are finite here)
    angle = np.mod(np.arctan2(unit[:, 1], unit[:, 0]), math.pi)
    direction = np.clip(np.nan_to_num(angle * (slices / math.pi)), 0, slices - 1).astype(np.int64)
    key = direction[owner] * cells + grid.cell
    order = np.argsort(key, kind="stable")
    where = np.empty_like(order)
    where[order] = np.arange(len(order))
    start = np.searchsorted(key[order], np.arange(slices * cells + 1)).astype(np.int64)
    # one row a scratch (ends, length) and a piece (centre, direction, half length, and
    # its scratch's row, for the exact tests beside the bounds)
    ends = np.stack([*p0.T, *p1.T, length], axis=1)
    pieces = np.concatenate(
        [centre[order], unit[owner[order]], half[order, None], ends[owner[order]]], axis=1
    )
    scan = _compiled_scan()
    # of the pairs (i, j), j goes to a buffer (int32 while the indices fit) and ``pairs``
    # counts each i's; a fresh buffer follows whenever one may not hold the next
    # scratch's pairs (fewer than n)
    capacity = max(2 * n, NEIGHBOUR_BUFFER_PAIRS)
    index = np.int32 if n < 2**31 else np.int64
    buffer = np.empty(capacity, index)
    found = [np.zeros(0, index)]
    pairs = np.zeros(n, np.int64)
    step = max(1, int(strip_points))
    lo = used = 0
    while lo < n:
        used, lo = scan(
            pieces, owner[order], angle, start, grid.nx, grid.ny, slices, grid.x0, grid.y0,
            grid.size, longest, where, first, count, ends, near, limit - 1e-9, limit, reach,
            lo, min(n, lo + step), pairs, buffer, used,
        )  # fmt: skip
        if used + n > capacity or lo == n:
            found.append(buffer[:used])
            buffer = np.empty(capacity, index) if lo < n else buffer
            used = 0
    return (
        np.repeat(np.arange(n, dtype=dtype), pairs),
        np.concatenate(found, dtype=dtype, casting="unsafe"),
    )


def _largest(p0: np.ndarray, p1: np.ndarray) -> float:
    """The largest absolute coordinate of the ends."""
    return float(max(np.abs(p0).max(), np.abs(p1).max()))


@dataclass(frozen=True)
class _Grid:
    """Uniform square cells over points: each point's cell ``cx + nx * cy`` and the grid."""

    cell: np.ndarray
    nx: int
    ny: int
    x0: float
    y0: float
    size: float


def _grid(points: np.ndarray, size: float) -> _Grid:
    """Cells about ``size`` wide over ``points``, at most about 4 per point."""
    x0, y0 = (float(v) for v in points.min(axis=0))
    wx, wy = (float(v) for v in points.max(axis=0) - points.min(axis=0))
    most = 4 * len(points) + 16
    if not size < 1e100:  # an infinite reach: one cell
        size = max(wx, wy, 1.0)
    size = max(size, wx / most, wy / most, math.sqrt(wx * wy / most), 1e-300)
    nx = min(int(wx / size), most) + 1
    ny = min(int(wy / size), most) + 1
    cx = np.minimum(((points[:, 0] - x0) / size).astype(np.int64), nx - 1)
    cy = np.minimum(((points[:, 1] - y0) / size).astype(np.int64), ny - 1)
    return _Grid(cx + nx * cy, nx, ny, x0, y0, size)


@functools.cache
def _compiled_scan() -> Any:
    """:func:`_scan_pairs` compiled (numba is imported here: it takes a while to load)."""
    from scratchfab.compiled import njit

    return njit(_scan_pairs, nogil=True)


def _scan_pairs(
    pieces: np.ndarray,
    owner: np.ndarray,
    angle: np.ndarray,
    start: np.ndarray,
    nx: int,
    ny: int,
    slices: int,
    x0: float,
    y0: float,
    size: float,
    longest: float,
    where: np.ndarray,
    first: np.ndarray,
    count: np.ndarray,
    ends: np.ndarray,
    near: float,
    bound_limit: float,
    limit: float,
    reach: float,
    lo: int,
    hi: int,
    pairs: np.ndarray,
    out: np.ndarray,
    used: int,
) -> tuple[int, int]:
    """:func:`neighbour_pairs` of scratches ``lo`` to ``hi`` - 1 (compiled by numba).

    ``ends`` rows are the scratches' endpoints (x0, y0, x1, y1) and length; ``pieces``
    rows the pieces' centre (x, y), unit direction (x, y), half length and their
    scratch's ``ends`` row. ``pieces`` and ``owner`` are sorted by direction slice, then
    grid cell; ``start`` holds the first piece of each (slice, cell) and ``where`` each
    piece's place in that order. ``angle`` is each scratch's direction in [0, pi]. NaN
    fails every test, as in numpy. Of each pair (i, j) found, j goes to ``out`` from
    ``used`` on, in (i, j) order, and ``pairs[i]`` counts them; it stops before a
    scratch whose pairs may not fit.

    Returns:
        The entries of ``out`` used now, and the scratch it stopped before.
    """

    def cells(lo_x: float, hi_x: float, origin: float, total: int) -> tuple[int, int]:
        # clamped before the conversion to int; NaN (inf - inf) takes every cell
        a = (lo_x - origin) / size
        b = (hi_x - origin) / size
        first_cell = 0 if not a >= 0.0 else total - 1 if a >= total - 1 else int(a)
        last_cell = total - 1 if not b < total - 1 else -1 if b < 0.0 else int(b)
        return first_cell, last_cell

    def band_span(
        cx: float, cy: float, ex: float, ey: float, fx: float, fy: float, y_lo: float, y_hi: float
    ) -> tuple[float, float]:
        # x extent of the parallelogram c +- e +- f within y_lo <= y <= y_hi
        xs = (cx - ex - fx, cx + ex - fx, cx + ex + fx, cx - ex + fx)
        ys = (cy - ey - fy, cy + ey - fy, cy + ey + fy, cy - ey + fy)
        left = math.inf
        right = -math.inf
        for e in range(4):
            sx, sy = xs[e], ys[e]
            tx, ty = xs[(e + 1) % 4], ys[(e + 1) % 4]
            if sy == ty:
                if y_lo <= sy <= y_hi:
                    left = min(left, sx, tx)
                    right = max(right, sx, tx)
                continue
            u1 = (y_lo - sy) / (ty - sy)
            u2 = (y_hi - sy) / (ty - sy)
            u_lo = max(0.0, min(u1, u2))
            u_hi = min(1.0, max(u1, u2))
            if u_lo <= u_hi:
                x1 = sx + u_lo * (tx - sx)
                x2 = sx + u_hi * (tx - sx)
                left = min(left, x1, x2)
                right = max(right, x1, x2)
        return left, right

    def point_segment_squared(
        qx: float, qy: float, sx: float, sy: float, ex: float, ey: float
    ) -> float:
        dx = ex - sx
        dy = ey - sy
        ll = dx * dx + dy * dy
        if ll < 1e-300:
            ll = 1e-300
        wx = qx - sx
        wy = qy - sy
        t = (wx * dx + wy * dy) / ll
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
        rx = wx - t * dx
        ry = wy - t * dy
        return rx * rx + ry * ry

    def sort_below_n(
        a: np.ndarray, b: np.ndarray, counts: np.ndarray, k: int, digits: int
    ) -> np.ndarray:
        # a[:k] (0 <= a < n) sorted: insertion when short, else radix sort by bytes
        if k <= 64:
            for t in range(1, k):
                v = a[t]
                s = t
                while s > 0 and a[s - 1] > v:
                    a[s] = a[s - 1]
                    s -= 1
                a[s] = v
            return a[:k]
        for d in range(digits):
            shift = 8 * d
            counts[:] = 0
            for t in range(k):
                counts[((a[t] >> shift) & 255) + 1] += 1
            for c in range(256):
                counts[c + 1] += counts[c]
            for t in range(k):
                c = (a[t] >> shift) & 255
                b[counts[c]] = a[t]
                counts[c] += 1
            a, b = b, a
        return a[:k]

    def lesser(a: float, b: float) -> float:
        return a if (a != a or a < b) else b

    def sides(qx: float, qy: float, rx: float, ry: float, sx: float, sy: float) -> float:
        return (rx - qx) * (sy - qy) - (ry - qy) * (sx - qx)

    def opposite(a: float, b: float) -> bool:
        return (a > 0.0 and b < 0.0) or (a < 0.0 and b > 0.0)

    def exact(i: int, b: int) -> bool:
        # the parallel limit and the segment distance of scratch i and piece b's scratch
        iax, iay, ibx, iby, ilen = ends[i, 0], ends[i, 1], ends[i, 2], ends[i, 3], ends[i, 4]
        jax, jay, jbx, jby = pieces[b, 5], pieces[b, 6], pieces[b, 7], pieces[b, 8]
        jlen = pieces[b, 9]
        den = ilen * jlen
        if den < 1e-300:
            den = 1e-300
        if not abs((ibx - iax) * (jbx - jax) + (iby - iay) * (jby - jay)) / den >= limit:
            return False
        # squared distances: their least has the least root (sqrt is monotone and
        # correctly rounded), so one root decides as the four of numpy's
        close = lesser(
            lesser(
                point_segment_squared(iax, iay, jax, jay, jbx, jby),
                point_segment_squared(ibx, iby, jax, jay, jbx, jby),
            ),
            lesser(
                point_segment_squared(jax, jay, iax, iay, ibx, iby),
                point_segment_squared(jbx, jby, iax, iay, ibx, iby),
            ),
        )
        return math.sqrt(close) < reach or (
            opposite(sides(iax, iay, ibx, iby, jax, jay), sides(iax, iay, ibx, iby, jbx, jby))
            and opposite(sides(jax, jay, jbx, jby, iax, iay), sides(jax, jay, jbx, jby, ibx, iby))
        )

    n = len(first)
    seen = np.full(n, -1, out.dtype)
    found = np.empty(n, np.int64)
    spare = np.empty(n, np.int64)
    counts = np.empty(257, np.int64)
    digits = 1
    while (n - 1) >> (8 * digits):
        digits += 1
    m = used
    # the largest sine between pieces that pass the angle bound
    sin_max = math.sqrt(1.0 - bound_limit * bound_limit) if 0.0 < bound_limit < 1.0 else 1.0
    # the angles (slices) a piece passing the angle bound can have, around a piece's own
    reach_angle = (math.acos(bound_limit) + 1e-6) * (slices / math.pi)
    some_slices = 0.0 < bound_limit < 1.0 and 2.0 * reach_angle + 1.0 < slices
    cells_total = nx * ny
    pad = near - reach
    for i in range(lo, hi):
        k = 0
        for q in range(first[i], first[i] + count[i]):
            a = where[q]
            xa, ya, ha = pieces[a, 0], pieces[a, 1], pieces[a, 4]
            uxa, uya = pieces[a, 2], pieces[a, 3]
            s0, s1 = 0, slices - 1
            if abs(uxa * uxa + uya * uya - 1.0) < 1e-9:
                if some_slices:
                    s0 = int(math.floor(angle[i] * (slices / math.pi) - reach_angle))
                    s1 = int(math.floor(angle[i] * (slices / math.pi) + reach_angle))
                # the separating-axis bounds at their widest: along a, and across it
                along = ha + longest + near + pad
                across = near + longest * sin_max + pad
                ex, ey, fx, fy = along * uxa, along * uya, -across * uya, across * uxa
            else:  # a point: centres closer than the half lengths plus the reach
                r = ha + longest + near + pad
                ex, ey, fx, fy = r, 0.0, 0.0, r
            extent = abs(ey) + abs(fy)
            # a reach beyond any board (even infinite): every cell, no overflowing corners
            everywhere = not abs(ex) + abs(fx) + extent < 1e100
            cy0, cy1 = (0, ny - 1) if everywhere else cells(ya - extent, ya + extent, y0, ny)
            for cy in range(cy0, cy1 + 1):
                if everywhere:
                    cx0, cx1 = 0, nx - 1
                else:
                    band_lo = y0 + cy * size - pad
                    band_hi = y0 + (cy + 1) * size + pad if cy < ny - 1 else math.inf
                    left, right = band_span(xa, ya, ex, ey, fx, fy, band_lo, band_hi)
                    if not left <= right:
                        continue
                    cx0, cx1 = cells(left, right, x0, nx)
                for sl in range(s0, s1 + 1):
                    # slices wrap round at 0 = pi (s0 > -slices, s1 < 2 slices)
                    wrapped = sl + slices if sl < 0 else sl - slices if sl >= slices else sl
                    row = wrapped * cells_total + nx * cy
                    for c in range(row + cx0, row + cx1 + 1):
                        # a cell's pieces come in scratch order: the last ones are of j > i
                        for b in range(start[c + 1] - 1, start[c] - 1, -1):
                            j = owner[b]
                            if j <= i:
                                break
                            uxb, uyb, hb = pieces[b, 2], pieces[b, 3], pieces[b, 4]
                            cos = abs(uxa * uxb + uya * uyb)
                            if not cos >= bound_limit:
                                continue
                            dx = pieces[b, 0] - xa
                            dy = pieces[b, 1] - ya
                            sin = abs(uxa * uyb - uya * uxb)
                            if (
                                abs(uxa * dy - uya * dx) - hb * sin < near
                                and abs(uxb * dy - uyb * dx) - ha * sin < near
                                and abs(uxa * dx + uya * dy) - ha - hb * cos < near
                                and abs(uxb * dx + uyb * dy) - hb - ha * cos < near
                                and seen[j] != i
                            ):
                                seen[j] = i
                                if exact(i, b):
                                    found[k] = j
                                    k += 1
        if k == 0:
            continue
        if m + k > len(out):
            return m, i  # the next call looks around scratch i again
        out[m : m + k] = sort_below_n(found, spare, counts, k, digits)
        pairs[i] = k
        m += k
    return m, hi
