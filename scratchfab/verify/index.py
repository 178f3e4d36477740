"""A uniform grid over the board listing the scratches that may cover each cell.

The Mitsuba plugin looks a shading point up in this grid inside its kernel: the
point's cell gives a slice ``items[starts[c]:starts[c + 1]]`` of scratch ids, which a
bounded loop then tests exactly. Cells list every scratch whose rectangle
(|x| <= w across, 0 <= y <= L along, SPEC section 3) meets the cell grown by a small
pad, so float32 rounding of a point's cell in the kernel cannot lose a scratch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Cells are grown by this fraction of their size in the overlap test.
PAD_FRACTION = 1e-3
#: Upper bound on the number of cells.
MAX_CELLS = 1 << 22
#: Candidate (scratch, cell) pairs tested at a time while building the grid.
BATCH_CELLS = 1 << 20


@dataclass(frozen=True, eq=False)
class GridIndex:
    """Flattened cell lists of a board grid.

    Attributes:
        origin: (x, y) of the grid's lower-left corner in mm.
        cell: Cell size in mm.
        nx: Cells along x.
        ny: Cells along y.
        starts: (nx * ny + 1,) uint32 offsets into ``items``; cell c = iy * nx + ix.
        items: (M,) uint32 scratch ids.
    """

    origin: tuple[float, float]
    cell: float
    nx: int
    ny: int
    starts: np.ndarray
    items: np.ndarray

    @property
    def max_count(self) -> int:
        """The longest cell list."""
        return int(np.max(np.diff(self.starts))) if self.nx * self.ny else 0

    def cell_of(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Flat cell index of board points (clamped to the grid)."""
        ix = np.clip(np.floor((np.asarray(x) - self.origin[0]) / self.cell), 0, self.nx - 1)
        iy = np.clip(np.floor((np.asarray(y) - self.origin[1]) / self.cell), 0, self.ny - 1)
        return (iy * self.nx + ix).astype(np.int64)

    def candidates(self, x: float, y: float) -> np.ndarray:
        """Scratch ids listed in the cell of point (x, y)."""
        c = int(self.cell_of(np.asarray(x), np.asarray(y)))
        return self.items[self.starts[c] : self.starts[c + 1]]


def default_cell(
    p0: np.ndarray, p1: np.ndarray, half_width: np.ndarray, extent: tuple[float, float]
) -> float:
    """A cell size giving short lists: about 8 cells per scratch, never below 4 widths."""
    area = 4.0 * extent[0] * extent[1]
    n = max(len(p0), 1)
    cell = math.sqrt(area / (8.0 * n))
    if len(half_width):
        cell = max(cell, 4.0 * float(np.max(half_width)))
    return max(cell, math.sqrt(area / MAX_CELLS))


def build_grid(
    p0: np.ndarray,
    p1: np.ndarray,
    half_width: np.ndarray,
    extent: tuple[float, float],
    cell: float | None = None,
) -> GridIndex:
    """Index scratch rectangles on the board |x| <= extent[0], |y| <= extent[1].

    Args:
        p0: (N, 2) scratch starts in mm.
        p1: (N, 2) scratch ends in mm.
        half_width: (N,) half widths w in mm.
        extent: Board half width and half height in mm.
        cell: Cell size in mm; :func:`default_cell` when None.

    Returns:
        The grid; a scratch is listed in every cell its rectangle meets (separating
        axis test against the padded cell).
    """
    p0 = np.asarray(p0, dtype=np.float64).reshape(-1, 2)
    p1 = np.asarray(p1, dtype=np.float64).reshape(-1, 2)
    w = np.asarray(half_width, dtype=np.float64).reshape(-1)
    if cell is None:
        cell = default_cell(p0, p1, w, extent)
    nx = max(1, math.ceil(2 * extent[0] / cell))
    ny = max(1, math.ceil(2 * extent[1] / cell))
    origin = (-extent[0], -extent[1])
    pad = PAD_FRACTION * cell
    half_c = 0.5 * cell + pad

    seg = p1 - p0
    length = np.linalg.norm(seg, axis=1)
    along = seg / np.maximum(length, 1e-300)[:, None]
    across = np.stack([-along[:, 1], along[:, 0]], axis=1)
    centre = 0.5 * (p0 + p1)
    # Half extents of each rectangle's axis-aligned bounding box.
    bx = 0.5 * length * np.abs(along[:, 0]) + w * np.abs(across[:, 0])
    by = 0.5 * length * np.abs(along[:, 1]) + w * np.abs(across[:, 1])
    ix0 = np.clip(np.floor((centre[:, 0] - bx - pad - origin[0]) / cell), 0, nx - 1).astype(int)
    ix1 = np.clip(np.floor((centre[:, 0] + bx + pad - origin[0]) / cell), 0, nx - 1).astype(int)
    iy0 = np.clip(np.floor((centre[:, 1] - by - pad - origin[1]) / cell), 0, ny - 1).astype(int)
    iy1 = np.clip(np.floor((centre[:, 1] + by + pad - origin[1]) / cell), 0, ny - 1).astype(int)
    spans_x = ix1 - ix0 + 1
    counts = spans_x * (iy1 - iy0 + 1)
    # Candidate cells in batches of scratches: a long diagonal scratch's box holds
    # thousands of cells, and all of them at once would take gigabytes.
    begin = np.cumsum(counts) - counts  # each scratch's first candidate, counted over all
    flats, idss = [], []
    first = 0
    while first < len(p0):
        last = max(first + 1, int(np.searchsorted(begin, begin[first] + BATCH_CELLS, "right")))
        sid = np.repeat(np.arange(first, last), counts[first:last])
        local = np.arange(len(sid)) - np.repeat(
            begin[first:last] - begin[first], counts[first:last]
        )
        cx = ix0[sid] + local % spans_x[sid]
        cy = iy0[sid] + local // spans_x[sid]
        # Separating axes: the cell's x and y (bounding boxes above, recheck per cell) and
        # the rectangle's along/across axes.
        lo_x = origin[0] + cx * cell - pad
        lo_y = origin[1] + cy * cell - pad
        dx = lo_x + half_c - centre[sid, 0]
        dy = lo_y + half_c - centre[sid, 1]
        keep = (np.abs(dx) <= half_c + bx[sid]) & (np.abs(dy) <= half_c + by[sid])
        for axis, half_rect in ((along, 0.5 * length), (across, w)):
            ax = axis[sid]
            reach = half_c * (np.abs(ax[:, 0]) + np.abs(ax[:, 1])) + half_rect[sid]
            keep &= np.abs(dx * ax[:, 0] + dy * ax[:, 1]) <= reach
        flats.append((cy * nx + cx)[keep])
        idss.append(sid[keep])
        first = last
    flat = np.concatenate(flats) if flats else np.zeros(0, np.int64)
    ids = np.concatenate(idss) if idss else np.zeros(0, np.int64)
    order = np.lexsort((ids, flat))
    flat = flat[order]
    ids = ids[order]
    starts = np.zeros(nx * ny + 1, dtype=np.uint32)
    starts[1:] = np.cumsum(np.bincount(flat, minlength=nx * ny))
    return GridIndex(origin, float(cell), nx, ny, starts, ids.astype(np.uint32))
