"""``optimize/side_by_side.png`` of large views: each cell shrunk to at most MAX_CELL_PX.

References: block means computed pixel by pixel in plain Python, and pictures built as
whole blocks of a small picture (whose block means are that picture).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_plots import is_color, pixels, srgb8

from scratchfab.figures import OFF_BOARD_RGB
from scratchfab.optimize.plots import MAX_CELL_PX, block_means, save_side_by_side


def _reference_block_means(values: np.ndarray, k: int) -> np.ndarray:
    """Block by block: the finite pixels' mean where they are more than half the block."""
    h, w = values.shape
    out = np.full((math.ceil(h / k), math.ceil(w / k)), np.nan)
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            block = values[i * k : (i + 1) * k, j * k : (j + 1) * k]
            finite = block[np.isfinite(block)]
            if 2 * finite.size > block.size:
                out[i, j] = finite.mean()
    return out


@pytest.mark.parametrize(("shape", "k"), [((7, 11), 3), ((8, 8), 2), ((5, 9), 4), ((6, 4), 1)])
def test_block_means_are_the_blocks_finite_means_where_most_are_on_the_board(shape, k):
    rng = np.random.default_rng(3)
    values = rng.random(shape)
    values[rng.random(shape) < 0.35] = np.nan
    np.testing.assert_allclose(
        block_means(values, k), _reference_block_means(values, k), rtol=1e-12
    )


def _cell_positions(img: np.ndarray, cell: np.ndarray) -> list[tuple[int, int]]:
    """Top-left corners where the RGB ``cell`` appears in ``img`` exactly."""
    h, w = cell.shape[:2]
    ys, xs = np.nonzero(is_color(img, cell[0, 0]))
    return [
        (int(y), int(x))
        for y, x in zip(ys, xs, strict=True)
        if np.array_equal(img[y : y + h, x : x + w], cell)
    ]


def test_a_large_view_is_shown_as_its_block_means_within_the_cap(tmp_path):
    """A 1200 x 700 view is shown at 1/3: each cell is the small picture whose 3 x 3
    blocks (the last column of blocks one pixel wide) make the view."""
    k = 3
    rng = np.random.default_rng(0)
    small = rng.random((400, 234))
    small[:40, :60] = np.nan  # off the board, in whole blocks
    target = np.kron(small, np.ones((k, k)))[:, :700]
    assert target.shape == (1200, 700) and math.ceil(1200 / MAX_CELL_PX) == k
    render = np.where(np.isfinite(target), 2.0 * target, 0.3)  # exposed by 1/2: the target
    path = tmp_path / "sbs.png"
    save_side_by_side(path, {"v": target}, {"v": render})
    img = pixels(path)
    grey = srgb8(np.nan_to_num(small)).astype(np.int16)
    cell = np.repeat(grey[..., None], 3, axis=2)
    cell[np.isnan(small)] = OFF_BOARD_RGB
    found = _cell_positions(img, cell)
    assert len(found) == 2 and found[0][0] == found[1][0]  # target | render, one row
    assert img.shape[0] < 400 + 120 and img.shape[1] < 2 * 234 + 120


def test_a_long_narrow_view_is_not_enlarged_past_the_cap(tmp_path):
    """A 2000 x 40 view shrinks to 500 x 10; enlarging it to MIN_CELL_PX wide would make it
    8000 px tall, so it stays within MAX_CELL_PX."""
    target = np.linspace(0.0, 1.0, 2000)[:, None] * np.ones((1, 40))
    path = tmp_path / "sbs.png"
    save_side_by_side(path, {"v": target}, {"v": target})
    height = pixels(path).shape[0]
    assert MAX_CELL_PX // 2 < height < MAX_CELL_PX + 120


def test_a_glint_is_outlined_on_the_blocks_it_touches(tmp_path):
    """One glinting pixel of a 1030 x 1030 view (shown at 1/3) marks its block."""
    from scratchfab.optimize.glint import GLINT_RGB, ViewGlint

    target = np.full((1030, 1030), 0.25)
    mask = np.zeros(target.shape, dtype=bool)
    mask[301, 905] = True  # block (100, 301)
    glint = ViewGlint("v", mask, board_share=1e-6, light_share=0.0)
    path = tmp_path / "sbs.png"
    save_side_by_side(path, {"v": target}, {"v": target}, {"v": glint})
    img = pixels(path)
    cell = np.repeat(np.full((344, 344), srgb8(np.array(0.25)))[..., None], 3, axis=2)
    cell[100, 301] = GLINT_RGB
    assert len(_cell_positions(img, cell.astype(np.int16))) == 2
