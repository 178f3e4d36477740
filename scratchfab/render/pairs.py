"""Which pixel footprints each scratch can touch (pair finding for the renderer).

A pinhole camera maps the board plane to the image plane by a projective map that is a
bijection between each pixel's square and its footprint (SPEC section 2). So a pixel's
footprint meets a scratch's rectangle exactly when the pixel square meets the rectangle's
projection, a convex quadrilateral in the image. We rasterise that quadrilateral
conservatively: for each image row it overlaps, the exact column range of the
quadrilateral within the row's strip. The work is one small vectorised step per (scratch,
row) plus one per pair, so it grows with the number of pairs, never with
scratches x pixels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from scratchfab.model.camera import Camera

#: Image-plane slack (pixels) added on every side, so rounding never drops a pair.
PIXEL_SLACK = 1e-3

#: Scratches rasterised per vectorised step (bounds the temporary memory).
CHUNK = 16384


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


def _row_spans(q: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column extent (s_min, s_max) of convex quads q (R, 4, 2) within strips [row, row + 1]."""
    lo = rows - PIXEL_SLACK
    hi = rows + 1 + PIXEL_SLACK
    s_min = np.full(len(rows), np.inf)
    s_max = np.full(len(rows), -np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for e in range(4):
            sa, ta = q[:, e, 0], q[:, e, 1]
            sb, tb = q[:, (e + 1) % 4, 0], q[:, (e + 1) % 4, 1]
            dt = tb - ta
            flat = np.abs(dt) < 1e-12
            u1 = (lo - ta) / np.where(flat, 1.0, dt)
            u2 = (hi - ta) / np.where(flat, 1.0, dt)
            ulo = np.maximum(0.0, np.minimum(u1, u2))
            uhi = np.minimum(1.0, np.maximum(u1, u2))
            ulo = np.where(flat, 0.0, ulo)
            uhi = np.where(flat, 1.0, uhi)
            ok = np.where(flat, (ta >= lo) & (ta <= hi), ulo <= uhi)
            s1 = sa + ulo * (sb - sa)
            s2 = sa + uhi * (sb - sa)
            s_min = np.where(ok, np.minimum(s_min, np.minimum(s1, s2)), s_min)
            s_max = np.where(ok, np.maximum(s_max, np.maximum(s1, s2)), s_max)
    return s_min, s_max


def _runs(base: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``base[k] + 0 .. base[k] + count[k] - 1`` for every k, laid end to end.

    In int32 (half the memory traffic of int64) unless the offsets need more.
    """
    starts = np.cumsum(count) - count
    offset = base - starts
    total = int(count.sum())
    small = total < 2**31 and (len(offset) == 0 or int(np.abs(offset).max()) < 2**31 - total)
    dtype = np.int32 if small else np.int64
    return np.repeat(offset.astype(dtype), count) + np.arange(total, dtype=dtype)


def raster_pairs(
    camera: Camera, corners: np.ndarray, pixel_ok: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Every (pixel, scratch) pair whose footprint may meet the quadrilateral of the scratch.

    Args:
        camera: The view's camera.
        corners: (N, 4, 2) board-plane quadrilaterals (e.g. :func:`scratch_rectangles`).
        pixel_ok: (H * W,) bool, pixels that can carry a pair at all (valid footprint
            with some area on the board); others are dropped.

    Returns:
        (pixel, scratch) uint32 arrays, scratch-major.
    """
    W, H = camera.width, camera.height
    pix_out: list[np.ndarray] = []
    sid_out: list[np.ndarray] = []
    for start in range(0, len(corners), CHUNK):
        quad = corners[start : start + CHUNK]
        n = len(quad)
        pts = np.concatenate([quad, np.zeros((n, 4, 1))], axis=2)
        st, front = camera.project(pts)
        # A corner behind the camera (never for a camera looking at the board): fall
        # back to the whole image, which stays correct, only slower.
        whole = ~np.all(front, axis=1) | ~np.all(np.isfinite(st), axis=(1, 2))
        st = np.where(whole[:, None, None], 0.0, st)
        t_min = np.where(whole, 0.0, st[:, :, 1].min(axis=1) - PIXEL_SLACK)
        t_max = np.where(whole, H - 1.0, st[:, :, 1].max(axis=1) + PIXEL_SLACK)
        j0 = np.clip(np.floor(t_min), 0, H).astype(np.int64)
        j1 = np.clip(np.floor(t_max), -1, H - 1).astype(np.int64)
        row_count = np.maximum(0, j1 - j0 + 1)
        owner = np.repeat(np.arange(n, dtype=np.int32), row_count)
        rows = _runs(j0, row_count)
        s_min, s_max = _row_spans(st[owner], rows.astype(np.float64))
        s_min = np.where(whole[owner], 0.0, s_min - PIXEL_SLACK)
        s_max = np.where(whole[owner], W - 1.0, s_max + PIXEL_SLACK)
        empty = ~(s_min <= s_max)
        i0 = np.clip(np.floor(np.where(empty, 0.0, s_min)), 0, W).astype(np.int64)
        i1 = np.clip(np.floor(np.where(empty, -1.0, s_max)), -1, W - 1).astype(np.int64)
        col_count = np.maximum(0, i1 - i0 + 1)
        # each (scratch, row) item's columns i0 .. i1 as flat pixels rows * W + i
        pixel = _runs(rows.astype(np.int64) * W + i0, col_count)
        keep = pixel_ok[pixel]
        scratch = np.repeat((owner + start).astype(np.uint32), col_count)
        pix_out.append(pixel[keep].astype(np.uint32))
        sid_out.append(scratch[keep])
    if not pix_out:
        return np.zeros(0, np.uint32), np.zeros(0, np.uint32)
    return np.concatenate(pix_out), np.concatenate(sid_out)
