"""The feasibility map draws a line around where the bare board outshines the layout's grooves.

Reference: the half-vectors computed here from the light, the camera and the grid's
cell centres, and the shoulder limit the check reports; the line's cells are the region's
cells next to one outside it (or at the map's edge), as a 2 px line inside them runs.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_design_glint import _maker_design
from test_plots_glint import outline_reference

from scratchfab import figures
from scratchfab.design import feasibility as fz
from scratchfab.design.feasibility import check_feasibility, map_figure
from scratchfab.design.targets import board_image

GRID = 48


def reference_tilt(design, name: str) -> np.ndarray:
    """Half-vector tilt (deg) at the centres of the map's GRID x GRID cells, row 0 at +y."""
    view = next(v for v in design.views if v.name == name)
    w, h = design.board.width_mm, design.board.height_mm
    x = -w / 2 + (np.arange(GRID) + 0.5) * w / GRID
    y = h / 2 - (np.arange(GRID) + 0.5) * h / GRID
    p = np.stack([*np.meshgrid(x, y), np.zeros((GRID, GRID))], axis=-1)
    h_sum = np.zeros_like(p)
    for source in (design.light.position_mm, view.position_mm):
        d = np.asarray(source, dtype=np.float64) - p
        h_sum += d / np.linalg.norm(d, axis=-1, keepdims=True)
    return np.degrees(np.arccos(h_sum[..., 2] / np.linalg.norm(h_sum, axis=-1)))


@pytest.fixture(scope="module")
def maker():
    design = _maker_design()
    boards = {v.name: board_image(design.target_path(v), design.board) for v in design.views}
    return design, check_feasibility(design, grid=GRID, boards=boards)


def test_the_line_runs_around_the_tilts_below_the_shoulder_limit(maker):
    design, report = maker
    shoulder = report.shoulder_deg
    assert shoulder is not None and shoulder > report.glint_deg + 3.0
    fig = map_figure(report, "sun")
    img = np.asarray(fig.image.convert("RGB"))
    x0, y0, x1, y1 = fig.map_box
    c = fig.cell
    assert c >= 4
    drawn = np.all(img[y0 : y1 + 1, x0 : x1 + 1] == fz.SHOULDER, axis=-1)
    cells = drawn.reshape(GRID, c, GRID, c).any(axis=(1, 3))
    tilt = reference_tilt(design, "sun")
    below = tilt < shoulder
    band = below & (tilt >= report.glint_deg)
    assert band.sum() > 20 and (~below).sum() > 20
    want = outline_reference(below, width=1, diagonal=True)
    sure = np.abs(tilt - shoulder) > 1e-6  # no cell this close to the limit to be unsure
    assert sure.all()
    np.testing.assert_array_equal(cells, want)
    # The key and the tilt bar: the line's colour, the bar's lined stretch from 0 to the limit.
    lx0, ly0, lx1, ly1 = fig.legend_box
    assert np.any(np.all(img[ly0 : ly1 + 1, lx0 : lx1 + 1] == fz.SHOULDER, axis=-1))
    bx0, by0, bx1, by1 = fig.bar_box
    cols = np.flatnonzero(np.all(img[by0 : by1 + 1, bx0 : bx1 + 1] == fz.SHOULDER, axis=-1).any(0))
    span = bx1 - bx0 + 1
    assert cols[0] == 0
    assert abs((cols[-1] + 1) / span * fig.bar_deg - shoulder) <= fig.bar_deg / span
    assert "shoulder_limit_deg" in report.to_json()["maps"]


def test_the_line_reads_apart_from_the_light_blues_in_grey_and_colour_blindness():
    line = np.array([fz.SHOULDER], dtype=float)
    for background in (fz.REACH_LIGHT, fz.GLINT):
        around = np.array([background], dtype=float)
        assert figures.lightness(around / 255)[0] - figures.lightness(line / 255)[0] > 20
        for kind in ("protanopia", "deuteranopia"):
            gap = (
                figures.lightness(figures.simulate_cvd(around, kind))[0]
                - figures.lightness(figures.simulate_cvd(line, kind))[0]
            )
            assert gap > 20


def test_no_targets_no_line(maker):
    design, _ = maker
    plain = check_feasibility(design, grid=GRID)
    assert plain.shoulder_deg is None
    img = np.asarray(map_figure(plain, "sun").image.convert("RGB"))
    assert not np.any(np.all(img == fz.SHOULDER, axis=-1))
