"""The objective: per-view image error with closed-form exposure, plus layout penalties.

Image term, per view k over its board pixels M_k (finite target):

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

Merge penalty: two nearly parallel scratches closer than the tool width merge into one
wider groove when cut. For candidate pairs (i, j) (:func:`neighbour_pairs`) the penalty
is ``par(i, j) * relu(1 - d_ij / width)^2`` with ``par = cos^16`` of the angle between
them (1 when parallel, 0.1 at 30 degrees) and d_ij the distance between the two
segments (the least of the four endpoint-to-segment distances, exact for segments that
do not cross).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import drjit as dr
import numpy as np
from scipy.spatial import cKDTree

Space = Literal["linear", "perceptual"]
SPACES: tuple[str, ...] = ("linear", "perceptual")

#: Pairs more than this far from parallel are never merge candidates (radians).
PARALLEL_LIMIT = math.radians(35.0)
#: Longest piece :func:`neighbour_pairs` cuts a scratch into (longer than the 12 mm default
#: maximum length, so scratches stay whole, while a few long ones cannot widen every query).
NEIGHBOUR_SPACING_MM = 16.0
#: Pieces per strip of :func:`neighbour_pairs`' KD-tree queries (bounds its memory).
NEIGHBOUR_STRIP_POINTS = 512
#: Piece pairs :func:`neighbour_pairs` tests at once (temporaries stay in cache).
NEIGHBOUR_CHUNK = 1 << 16
#: Slack (mm) of :func:`neighbour_pairs`' bounds, far above float64 rounding.
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
        target: T_k (H * W,) Float, 0 off the board.
        mask: (H * W,) Float, 1 on the board and 0 off it.
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
    """Sum of the merge penalty over candidate pairs (Dr.Jit scalar, not evaluated)."""
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
    cos = (ux * vx + uy * vy) * dr.rsqrt(
        dr.maximum((ux * ux + uy * uy) * (vx * vx + vy * vy), 1e-20)
    )
    par = dr.power(dr.square(cos), 8)
    d = dr.minimum(
        dr.minimum(_point_segment(ax, ay, cx, cy, vx, vy), _point_segment(bx, by, cx, cy, vx, vy)),
        dr.minimum(_point_segment(cx, cy, ax, ay, ux, uy), _point_segment(ex, ey, ax, ay, ux, uy)),
    )
    close = dr.maximum(1.0 - d / tool_width, 0.0)
    return dr.sum(par * close * close, mode="symbolic")


def _point_segment(px: Any, py: Any, ax: Any, ay: Any, dx: Any, dy: Any) -> Any:
    """Distance from points p to segments a + t d, t in [0, 1]."""
    ll = dr.maximum(dx * dx + dy * dy, 1e-20)
    t = dr.clip(((px - ax) * dx + (py - ay) * dy) / ll, 0.0, 1.0)
    qx = px - ax - t * dx
    qy = py - ay - t * dy
    return dr.sqrt(dr.maximum(qx * qx + qy * qy, 1e-20))


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
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i < j) of scratches closer than ``reach`` and within the parallel limit.

    Each scratch is cut into equal pieces at most ``max(spacing, reach)`` long (most
    scratches stay whole). Two scratches closer than ``reach`` have two pieces, one of
    each, whose centres are closer than their half lengths plus ``reach``, so a KD-tree
    query over the piece centres at that radius is complete. The piece pairs it finds
    are first thinned by bounds that never drop a close pair: the angle between them,
    and the separating-axis bound (projections onto either piece's direction and
    normal are no longer than the distance). The pairs left then meet the exact tests:
    the parallel limit PARALLEL_LIMIT + ``angle_slack`` (weights below 0.05 past it)
    and the segment distance. The query runs strip by strip across x, ``strip_points``
    pieces each against those up to the query radius to their right, and the bounds
    run on chunks of the pairs found, so memory follows the strip, not the board.

    Returns:
        (i, j), sorted by (i, j).
    """
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
    unit = d / np.maximum(length, 1e-300)[:, None]
    pieces = _Pieces(
        centre[:, 0].copy(),
        centre[:, 1].copy(),
        unit[owner, 0].copy(),
        unit[owner, 1].copy(),
        (length / (2 * count))[owner],
    )
    # the bounds get a little slack, the exact tests below none
    near = reach + NEIGHBOUR_SLACK_MM
    radius = 2 * float(pieces.half.max()) + near
    limit = math.cos(min(math.pi / 2, PARALLEL_LIMIT + angle_slack))
    found = [np.zeros(0, np.int64)]
    x = pieces.x
    for start in range(0, len(owner), strip_points):
        end = min(start + strip_points, len(owner))
        last = int(np.searchsorted(x, x[end - 1] + radius, side="right"))
        tree = cKDTree(centre[start:end])
        inner = tree.query_pairs(radius, output_type="ndarray") + start
        candidates = [(inner[:, 0], inner[:, 1])]
        if last > end:
            outer = tree.sparse_distance_matrix(
                cKDTree(centre[end:last]), radius, output_type="ndarray"
            )
            candidates.append((outer["i"] + start, outer["j"] + end))
        for a_all, b_all in candidates:
            for c in range(0, len(a_all), NEIGHBOUR_CHUNK):
                a, b = a_all[c : c + NEIGHBOUR_CHUNK], b_all[c : c + NEIGHBOUR_CHUNK]
                sel = _may_touch(pieces, a, b, near, limit - 1e-9)
                i, j = owner[a[sel]], owner[b[sel]]
                keep = i != j
                i, j = np.minimum(i[keep], j[keep]), np.maximum(i[keep], j[keep])
                cos = np.abs(np.sum(d[i] * d[j], axis=1)) / np.maximum(
                    length[i] * length[j], 1e-300
                )
                keep = cos >= limit
                i, j = i[keep], j[keep]
                keep = segment_distance_np(p0, p1, i, j) < reach
                found.append(i[keep] * n + j[keep])
    keys = _sorted_unique(np.concatenate(found))
    return keys // n, keys % n


@dataclass(frozen=True)
class _Pieces:
    """Pieces of scratches for :func:`neighbour_pairs`: centres, unit directions, half lengths."""

    x: np.ndarray
    y: np.ndarray
    ux: np.ndarray
    uy: np.ndarray
    half: np.ndarray


def _may_touch(p: _Pieces, a: np.ndarray, b: np.ndarray, near: float, limit: float) -> np.ndarray:
    """Indices k of the piece pairs (a[k], b[k]) that no bound shows apart.

    Kept: |cos| of their angle at least ``limit``, and no separating-axis lower bound
    on their distance (along or across either piece) at ``near`` or more.
    """
    cos = np.abs(p.ux[a] * p.ux[b] + p.uy[a] * p.uy[b])
    keep = np.flatnonzero(cos >= limit)
    a, b, cos = a[keep], b[keep], cos[keep]
    uxa, uya, uxb, uyb = p.ux[a], p.uy[a], p.ux[b], p.uy[b]
    dx = p.x[b] - p.x[a]
    dy = p.y[b] - p.y[a]
    ha, hb = p.half[a], p.half[b]
    sin = np.abs(uxa * uyb - uya * uxb)
    ok = np.abs(uxa * dy - uya * dx) - hb * sin < near
    ok &= np.abs(uxb * dy - uyb * dx) - ha * sin < near
    ok &= np.abs(uxa * dx + uya * dy) - ha - hb * cos < near
    ok &= np.abs(uxb * dx + uyb * dy) - hb - ha * cos < near
    return keep[ok]


def _sorted_unique(keys: np.ndarray) -> np.ndarray:
    """The distinct values of ``keys``, sorted (sorting beats numpy's hash-based unique here)."""
    keys = np.sort(keys)
    return keys[np.concatenate(([True], keys[1:] != keys[:-1]))] if len(keys) else keys
