"""The quick form's placement of three or more views: each tilts as the two-view ends do."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_views_see_the_whole_board_and_are_feasible

from scratchfab.design.feasibility import board_points, check_feasibility, half_vectors, tilt_deg
from scratchfab.design.quick import quick_design

DEMO = Path(__file__).resolve().parents[1] / "scratchfab" / "data" / "demo"


def _centre(design, view) -> np.ndarray:
    """The half-vector at the board's centre, from the resolved camera and light."""
    return half_vectors(design, view, np.zeros((1, 2)))[0]


@pytest.mark.parametrize("n", [3, 4, 5])
def test_every_view_tilts_as_the_two_view_ends_and_turns_in_equal_steps(n):
    """Centre tilts alike (a middle camera on the horizontal arc tilted 10.3 deg against
    14.9), half-vectors turned evenly from the diagonal (-1, 1) to (1, 1), and nowhere on
    the board a half-vector nearer the normal (the bare board's gloss) than two views have."""
    two = quick_design([DEMO / "sun.png", DEMO / "house.png"], (100.0, 60.0))
    design = quick_design([DEMO / "sun.png"] * n, (100.0, 60.0))
    ends = [_centre(two, v) for v in two.views]
    end_tilt = float(tilt_deg(ends[0]))
    assert [v.position_mm[1] for v in two.views] == pytest.approx([0.0, 0.0], abs=1e-9)
    h = np.array([_centre(design, v) for v in design.views])
    assert tilt_deg(h) == pytest.approx([end_tilt] * n, abs=0.01)
    turn = np.degrees(np.arctan2(h[:, 1], h[:, 0]))
    assert turn == pytest.approx(np.linspace(135.0, 45.0, n), abs=0.01)
    assert h[0] == pytest.approx(ends[0], abs=1e-6) and h[-1] == pytest.approx(ends[1], abs=1e-6)
    pts = board_points(design.board)
    least_two = min(tilt_deg(half_vectors(two, v, pts)).min() for v in two.views)
    assert (
        min(tilt_deg(half_vectors(design, v, pts)).min() for v in design.views) >= least_two - 1e-6
    )


@pytest.mark.parametrize("n", [4, 7])
def test_more_views_see_the_whole_board_and_stay_apart(n):
    """Every camera sees the whole board, and seven images pass the feasibility check
    (on the arc the middle ones were within a lobe of each other)."""
    design = quick_design([DEMO / "sun.png"] * n, (100.0, 60.0))
    assert_views_see_the_whole_board_and_are_feasible(design)
    report = check_feasibility(design)
    lobe = math.degrees(math.atan(design.board.roughness))
    assert min(p.separation_median_deg for p in report.pairs) > lobe
