"""side_by_side.png outlines the bare board's glint as verify's difference maps do.

References: the glint set computed here from each pixel centre's half-vector
(:func:`test_optimize_glint.reference_glint`), its outline as the pixels within two
steps (up, down, left, right) of a pixel outside it or off the picture, found by
shifting the picture here, and the exposure a least-squares fit outside the glint gives.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_optimize_glint import glint_design, reference_glint
from test_optimize_helpers import cross_of
from test_plots import is_color, pixels, srgb8

from scratchfab.backend import array_module
from scratchfab.design.feasibility import GLINT, design_glint_deg
from scratchfab.figures import OFF_BOARD_RGB
from scratchfab.optimize.glint import ViewGlint, view_glint
from scratchfab.optimize.plots import MIN_CELL_PX, save_side_by_side
from scratchfab.render.renderer import ViewRenderer

#: Brighter than any exposed pixel may be: the glint in the render.
GLINT_RADIANCE = 40.0


def outline_reference(region: np.ndarray, width: int = 2, diagonal: bool = False) -> np.ndarray:
    """Pixels of ``region`` with one outside it, or off the picture, within ``width`` steps.

    Steps go up, down, left and right; ``diagonal``: also diagonally (one step each).
    """
    h, w = region.shape
    edge = np.zeros_like(region)
    for i in range(h):
        for j in range(w):
            if not region[i, j]:
                continue
            for di in range(-width, width + 1):
                for dj in range(-width, width + 1):
                    if (max if diagonal else sum)((abs(di), abs(dj))) > width:
                        continue
                    y, x = i + di, j + dj
                    if not (0 <= y < h and 0 <= x < w) or not region[y, x]:
                        edge[i, j] = True
    return edge


def find(img: np.ndarray, cell: np.ndarray) -> list[tuple[int, int]]:
    """Top-left corners where ``cell`` (h, w, 3) appears in ``img`` exactly."""
    h, w = cell.shape[:2]
    return [
        (y, x)
        for y in range(img.shape[0] - h + 1)
        for x in range(img.shape[1] - w + 1)
        if np.array_equal(img[y, x], cell[0, 0]) and np.array_equal(img[y : y + h, x : x + w], cell)
    ]


@pytest.fixture(scope="module")
def glinting():
    """The 32 px two-view board whose left view glints in a corner; targets, glints."""
    design = glint_design()
    targets, _ = cross_of(design)
    limit = design_glint_deg(design)
    m = array_module("llvm")
    glints = {v.name: view_glint(ViewRenderer(design, v, m), limit) for v in design.views}
    return design, targets, glints


def test_both_cells_outline_the_glint_the_half_vectors_give_and_expose_outside_it(
    tmp_path, glinting
):
    design, targets, glints = glinting
    ref = reference_glint(design, "left")
    assert 10 < ref.sum() < 0.2 * ref.size
    np.testing.assert_array_equal(glints["left"].mask, ref)
    assert not glints["right"].mask.any()
    # The render: twice the target, the glint far brighter (it would set the exposure).
    target = {"left": targets["left"]}
    render = {"left": np.where(ref, GLINT_RADIANCE, 2.0 * np.nan_to_num(targets["left"]))}
    save_side_by_side(tmp_path / "sbs.png", target, render, glints)
    img = pixels(tmp_path / "sbs.png")

    t = targets["left"]
    factor = math.ceil(MIN_CELL_PX / t.shape[1])
    big = np.kron(ref, np.ones((factor, factor), dtype=int)).astype(bool)
    edge = outline_reference(big)
    off = np.kron(~np.isfinite(t), np.ones((factor, factor), dtype=int)).astype(bool)

    def cell(linear: np.ndarray) -> np.ndarray:
        grey = np.kron(srgb8(np.nan_to_num(linear)), np.ones((factor, factor)))
        rgb = np.repeat(grey[..., None], 3, axis=2).astype(np.int16)
        rgb[off] = OFF_BOARD_RGB
        rgb[edge] = GLINT
        return rgb

    # Outside the glint the exposure fit gives 1/2: the render cell shows the target there,
    # and white (clipped) inside the glint.
    (at_target,) = find(img, cell(t))
    (at_render,) = find(img, cell(np.where(ref, 1.0, t)))
    assert at_target[0] == at_render[0] and at_target[1] < at_render[1]
    # The outline drawn is exactly the reference's, on the glint's pixels' edge.
    y, x = at_target
    drawn = is_color(img[y : y + big.shape[0], x : x + big.shape[1]], GLINT)
    np.testing.assert_array_equal(drawn, edge)
    # In cells: those next to one outside it (a 2 px line reaches a diagonal's corner).
    cells = drawn.reshape(ref.shape[0], factor, ref.shape[1], factor).any(axis=(1, 3))
    np.testing.assert_array_equal(cells, outline_reference(ref, width=1, diagonal=True))
    # The caption's swatch explains it: the outline colour under the cells too.
    assert is_color(img[y + big.shape[0] :], GLINT).any()


def test_without_glint_the_picture_is_as_before(tmp_path, glinting):
    _, targets, glints = glinting
    renders = {k: 2.0 * np.nan_to_num(v) for k, v in targets.items()}
    save_side_by_side(tmp_path / "plain.png", targets, renders)
    right = {"right": targets["right"]}
    save_side_by_side(tmp_path / "none.png", right, renders, glints)
    save_side_by_side(tmp_path / "right.png", right, renders)
    empty = {"left": ViewGlint("left", np.zeros_like(glints["left"].mask), 0.0, 0.0)}
    save_side_by_side(tmp_path / "empty.png", targets, renders, empty)
    assert not is_color(pixels(tmp_path / "plain.png"), GLINT).any()
    np.testing.assert_array_equal(pixels(tmp_path / "none.png"), pixels(tmp_path / "right.png"))
    np.testing.assert_array_equal(pixels(tmp_path / "empty.png"), pixels(tmp_path / "plain.png"))


def test_a_glint_of_another_size_is_refused_naming_the_view(tmp_path, glinting):
    _, targets, glints = glinting
    wrong = {"left": ViewGlint("left", glints["left"].mask[:-1], 0.03, 0.8)}
    with pytest.raises(ValueError, match="view 'left': glint mask"):
        save_side_by_side(tmp_path / "x.png", targets, targets, wrong)
