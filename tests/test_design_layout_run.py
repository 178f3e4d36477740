"""The chunked bright-run walk of the layout against a brute-force walk, one step at a time."""

from __future__ import annotations

import numpy as np
import pytest

from scratchfab.design.layout import _bright_run
from scratchfab.model.design import Board


def _reference_run(
    grid: np.ndarray, board: Board, centre: np.ndarray, direction: np.ndarray, limit: np.ndarray
) -> np.ndarray:
    """Walk each centre in half-cell steps, one point at a time, until dark or past its limit."""
    rows, cols = grid.shape
    hw, hh = board.half_extent
    step = 0.5 * min(board.width_mm / cols, board.height_mm / rows)

    def cell(p: np.ndarray) -> float:
        c = min(max(int((p[0] + hw) / board.width_mm * cols), 0), cols - 1)
        r = min(max(int((hh - p[1]) / board.height_mm * rows), 0), rows - 1)
        return float(grid[r, c])

    out = np.empty(len(centre))
    for i, (p, d, lim) in enumerate(zip(centre, direction, limit, strict=True)):
        start, run, k = cell(p), 0.0, 1
        while run < lim:
            s = k * step
            if cell(p + s * d) < 0.5 * start:
                break
            run, k = s, k + 1
        out[i] = min(run, lim)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("dark", [0.003, 0.05, 0.3])
def test_the_chunked_walk_matches_a_step_by_step_walk(seed: int, dark: float) -> None:
    rng = np.random.default_rng(seed)
    rows, cols = rng.integers(5, 90, size=2)
    # dark specks, sparse (most centres far from any: the walk skips them) to dense, so
    # runs end anywhere from the first step to past the limit
    grid = (rng.random((rows, cols)) < dark).astype(float)
    grid = 1.0 - grid * rng.uniform(0.5, 1.0)
    board = Board(width_mm=float(rng.uniform(10, 80)), height_mm=float(rng.uniform(10, 80)))
    n = 500
    hw, hh = board.half_extent
    centre = rng.uniform(-1, 1, (n, 2)) * [hw, hh]
    angle = rng.uniform(0, 2 * np.pi, n)
    direction = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    limit = rng.uniform(0.0, rng.uniform(0.05, 0.6) * max(hw, hh), n)
    limit[:5] = 0.0
    got = _bright_run(grid, board, centre, direction, limit)
    want = _reference_run(grid, board, centre, direction, limit)
    assert np.all(got <= limit)
    assert np.array_equal(got, want)
    # the walk ends at a dark cell for some centres and at the limit for others
    assert 0 < np.count_nonzero(got < limit) < n
