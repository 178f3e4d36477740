"""Which pixel footprints each scratch can touch (pair finding for the renderer).

A pinhole camera maps the board plane to the image plane by a projective map that is a
bijection between each pixel's square and its footprint (SPEC section 2). So a pixel's
footprint meets a scratch's rectangle exactly when the pixel square meets the rectangle's
projection, a convex quadrilateral in the image. We rasterise that quadrilateral
conservatively: for each image row it overlaps, the exact column range of the
quadrilateral within the row's strip. The work is a few operations per (scratch, row)
plus one per pair, so it grows with the number of pairs, never with scratches x pixels.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from scratchfab.model.camera import Camera

#: Image-plane slack (pixels) added on every side, so rounding never drops a pair.
PIXEL_SLACK = 1e-3


@dataclass(frozen=True, eq=False)
class Pairs:
    """(pixel, scratch) pairs of one view, scratch-major.

    Attributes:
        pixel: Dr.Jit UInt32 flat pixel indices j * W + i.
        scratch: Dr.Jit UInt32 scratch indices.
        pixel_np: The same pixel indices in numpy uint32 (read-only).
        scratch_np: The same scratch indices in numpy uint32 (read-only).
    """

    pixel: Any
    scratch: Any
    pixel_np: np.ndarray
    scratch_np: np.ndarray

    def __len__(self) -> int:
        return len(self.pixel_np)


def scratch_rectangles(
    p0: np.ndarray, p1: np.ndarray, half_width: np.ndarray | float, margin_mm: float = 0.0
) -> np.ndarray:
    """Corners (N, 4, 2) of the scratch rectangles |x| <= w, 0 <= y <= L grown by a margin.

    Args:
        p0: (N, 2) start points in mm.
        p1: (N, 2) end points in mm.
        half_width: (N,) or scalar half widths w in mm.
        margin_mm: Growth on every side (across and beyond both ends).
    """
    p0 = np.asarray(p0, dtype=np.float64).reshape(-1, 2)
    p1 = np.asarray(p1, dtype=np.float64).reshape(-1, 2)
    d = p1 - p0
    length = np.linalg.norm(d, axis=1, keepdims=True)
    along = d / np.where(length > 0, length, 1.0)
    across = np.stack([-along[:, 1], along[:, 0]], axis=1)
    a = (np.broadcast_to(np.asarray(half_width, dtype=np.float64), (len(p0),)) + margin_mm)[:, None]
    start = p0 - margin_mm * along
    end = p1 + margin_mm * along
    return np.stack([start - a * across, end - a * across, end + a * across, start + a * across], 1)


def raster_pairs(
    camera: Camera, corners: np.ndarray, pixel_ok: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Every (pixel, scratch) pair whose footprint may meet the quadrilateral of the scratch.

    numpy projects the corners and finds each scratch's rows; compiled scans (numba,
    loaded on first use) find each row's columns and count the pixels with ``pixel_ok``
    among them (:func:`_count_pairs`), then write the pairs into arrays of that size
    (:func:`_write_pairs`).

    Args:
        camera: The view's camera.
        corners: (N, 4, 2) board-plane quadrilaterals (e.g. :func:`scratch_rectangles`).
        pixel_ok: (H * W,) bool, pixels that can carry a pair at all (valid footprint
            with some area on the board); others are dropped.

    Returns:
        (pixel, scratch) uint32 arrays, scratch-major; in each scratch by row, then
        column.
    """
    W, H = camera.width, camera.height
    corners = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
    n = len(corners)
    if n == 0:
        return np.zeros(0, np.uint32), np.zeros(0, np.uint32)
    if n - 1 > np.iinfo(np.uint32).max or H * W - 1 > np.iinfo(np.uint32).max:
        raise ValueError(f"uint32 cannot index {n} scratches or {H} x {W} pixels")
    pts = np.concatenate([corners, np.zeros((n, 4, 1))], axis=2)
    st, front = camera.project(pts)
    # A corner behind the camera (never for a camera looking at the board): the whole
    # image, which stays correct, only slower.
    whole = ~np.all(front, axis=1) | ~np.all(np.isfinite(st), axis=(1, 2))
    t_min = np.where(whole, 0.0, st[:, :, 1].min(axis=1) - PIXEL_SLACK)
    t_max = np.where(whole, H - 1.0, st[:, :, 1].max(axis=1) + PIXEL_SLACK)
    j0 = np.clip(np.floor(t_min), 0, H).astype(np.int64)
    j1 = np.clip(np.floor(t_max), -1, H - 1).astype(np.int64)
    rows = np.zeros(n + 1, np.int64)
    np.cumsum(np.maximum(0, j1 - j0 + 1), out=rows[1:])
    ok = np.ascontiguousarray(pixel_ok, dtype=np.bool_).reshape(H * W)
    # ok pixels of row j before column i: before[j * (W + 1) + i]
    before = np.zeros((H, W + 1), np.int32)
    np.cumsum(ok.reshape(H, W), axis=1, dtype=np.int32, out=before[:, 1:])
    count_pairs, write_pairs = _compiled()
    span = np.empty((int(rows[-1]), 2), np.int32)
    first = np.zeros(n + 1, np.int64)
    st = np.ascontiguousarray(st)  # one compiled signature
    count_pairs(st, whole, j0, rows, W, before.reshape(-1), span, first[1:])
    np.cumsum(first, out=first)
    pixel = np.empty(int(first[-1]), np.uint32)
    scratch = np.empty(int(first[-1]), np.uint32)
    write_pairs(j0, rows, W, ok, span, first, pixel, scratch)
    return pixel, scratch


@functools.cache
def _compiled() -> tuple[Any, Any]:
    """:func:`_count_pairs` and :func:`_write_pairs` compiled (numba is loaded on first use)."""
    from scratchfab.compiled import njit

    return njit(_count_pairs, nogil=True), njit(_write_pairs, nogil=True)


def _count_pairs(
    st: np.ndarray,
    whole: np.ndarray,
    j0: np.ndarray,
    rows: np.ndarray,
    width: int,
    before: np.ndarray,
    span: np.ndarray,
    kept: np.ndarray,
) -> None:
    """Each scratch's column span in each of its rows, and its pairs (compiled by numba).

    Scratch k covers image rows ``j0[k]`` on, items ``rows[k]`` to ``rows[k + 1]`` - 1;
    ``st`` (N, 4, 2) are its projected corners, ``whole`` whether it takes every pixel.
    Writes each item's first and last column into ``span`` (last < first: none) and
    the number of its pixels that ``before`` (per row, the ok pixels left of a column,
    rows W + 1 long) counts into ``kept[k]``.

    The span of a convex quadrilateral within the strip [row, row + 1] (grown by the
    slack) is the extent of the parts of its edges in the strip; the float64 operations
    are those of the numpy form this replaced, in the same order, its NaN-propagating
    minimum and maximum included (tests/test_raster_pairs.py keeps it to compare).
    """

    def least(a: float, b: float) -> float:
        return a if (a != a or a < b) else b

    def most(a: float, b: float) -> float:
        return a if (a != a or a > b) else b

    slack = PIXEL_SLACK
    for k in range(len(j0)):
        total = 0
        for r in range(rows[k], rows[k + 1]):
            j = j0[k] + (r - rows[k])
            i0 = 0
            i1 = width - 1
            if not whole[k]:
                lo = float(j) - slack
                hi = float(j) + 1.0 + slack
                s_min = math.inf
                s_max = -math.inf
                for e in range(4):
                    f = (e + 1) % 4
                    sa, ta, sb, tb = st[k, e, 0], st[k, e, 1], st[k, f, 0], st[k, f, 1]
                    dt = tb - ta
                    if abs(dt) < 1e-12:  # along the strip: all of it or none
                        if not (ta >= lo and ta <= hi):
                            continue
                        u_lo = 0.0
                        u_hi = 1.0
                    else:
                        u1 = (lo - ta) / dt
                        u2 = (hi - ta) / dt
                        u_lo = most(0.0, least(u1, u2))
                        u_hi = least(1.0, most(u1, u2))
                        if not u_lo <= u_hi:
                            continue
                    s1 = sa + u_lo * (sb - sa)
                    s2 = sa + u_hi * (sb - sa)
                    s_min = least(s_min, least(s1, s2))
                    s_max = most(s_max, most(s1, s2))
                s_min = s_min - slack
                s_max = s_max + slack
                if s_min <= s_max:
                    # clipped to whole columns first: floor keeps the integer bounds
                    i0 = math.floor(min(max(s_min, 0.0), float(width)))
                    i1 = math.floor(min(max(s_max, -1.0), width - 1.0))
                else:
                    i1 = -1
            span[r, 0] = i0
            span[r, 1] = i1
            if i1 >= i0:
                row = j * (width + 1)
                total += before[row + i1 + 1] - before[row + i0]
        kept[k] = total


def _write_pairs(
    j0: np.ndarray,
    rows: np.ndarray,
    width: int,
    ok: np.ndarray,
    span: np.ndarray,
    first: np.ndarray,
    pixel: np.ndarray,
    scratch: np.ndarray,
) -> None:
    """The ok pixels of every span, from ``first[k]`` on for scratch k (compiled by numba)."""
    for k in range(len(j0)):
        m = first[k]
        for r in range(rows[k], rows[k + 1]):
            base = (j0[k] + (r - rows[k])) * width
            for p in range(base + span[r, 0], base + span[r, 1] + 1):
                if ok[p]:
                    pixel[m] = p
                    scratch[m] = k
                    m += 1
        if m != first[k + 1]:
            raise RuntimeError("raster_pairs: a scratch's pairs differ from its count")
