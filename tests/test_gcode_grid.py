"""The G-code writer's grid: a value on the envelope's edge is written inside it, one beyond raises.

The writer rounds each coordinate to ``gcode.decimals``; a value on the edge may round
past it and is written as the nearest grid value inside. The toolpath stage moves a
stroke's end within half a written digit (at least 1e-6 mm) beyond the edge onto it;
anything further reaching the writer is a bug (the envelope check runs first), and a
silent clamp would move a cut, so it raises.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from scratchfab.export import gcode
from scratchfab.export.gcode import _Grid, gcode_lines
from scratchfab.machine.profile import load_profile, profile_from_mapping
from scratchfab.model.design import Board
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath import plan_toolpath

# On no grid of 0 to 6 decimals: the largest grid value inside is -10^-decimals.
HI = -4.3e-7
LO = -290.00000043


def edge_profile(decimals: int):
    table = load_profile("grbl-3018-diamond").to_table()
    table["envelope"].update(x_mm=[LO, HI], coordinates="work")
    table["start_mm"] = [-10.0, -10.0]
    table["tool"]["tolerance_mm"] = 0.5  # lets decimals = 0 through the profile's check
    table["gcode"]["decimals"] = decimals
    return profile_from_mapping(table, "<edge>")


@pytest.mark.parametrize("decimals", range(7))
def test_a_value_on_the_edge_or_within_the_slack_is_written_inside(decimals):
    grid = _Grid(edge_profile(decimals))
    unit = 10.0**-decimals
    slack = max(0.5 * unit, 1e-6)  # half a written digit, at least a scratch file's 1e-6
    inside_hi = math.floor(HI / unit) * unit  # the largest multiple of the unit <= HI
    inside_lo = math.ceil(LO / unit) * unit
    for value in (HI, HI + 0.999 * slack):
        word = grid.word("X", value)
        assert word[0] == "X" and float(word[1:]) == pytest.approx(inside_hi, abs=1e-12)
    for value in (LO, LO - 0.999 * slack):
        word = grid.word("X", value)
        assert float(word[1:]) == pytest.approx(inside_lo, abs=1e-12)
    # inside, a value is rounded to the nearest digit
    assert float(grid.word("X", -123.4567891)[1:]) == pytest.approx(
        round(-123.4567891, decimals), abs=1e-12
    )


@pytest.mark.parametrize("decimals", range(7))
def test_a_value_beyond_the_slack_raises_rather_than_moving(decimals):
    grid = _Grid(edge_profile(decimals))
    slack = max(0.5 * 10.0**-decimals, 1e-6)
    for value in (HI + 1.001 * slack, LO - 1.001 * slack, HI + 5.0, float("nan")):
        with pytest.raises(RuntimeError, match=r"internal error: G-code X .* beyond the envelope"):
            grid.word("X", value)
    with pytest.raises(RuntimeError, match=r"G-code Y"):
        grid.word("Y", 1.0)  # the bundled Y travel ends at 0


def test_a_stroke_past_the_edge_that_skipped_the_envelope_check_is_not_clamped(monkeypatch):
    """Were the check skipped, the writer would refuse the stroke, not move it onto the edge."""
    profile = load_profile("grbl-3018-diamond")
    rng = np.random.default_rng(3)
    p0 = rng.uniform(-15, 15, (12, 2))
    scratches = ScratchSet.from_arrays(p0, p0 + 2.0, 0.1, 0.01)
    tp = plan_toolpath(scratches, Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0), profile)
    hi_x = profile.envelope.x_mm[1]
    strokes = tp.strokes.copy()
    strokes[3, 1, 0] = hi_x + 0.01  # 0.01 mm past the edge: ten written digits
    moved = replace(tp, strokes=strokes)
    gcode_lines(tp, profile)  # the planned one writes
    monkeypatch.setattr(gcode, "check_envelope", lambda *args: None)
    with pytest.raises(RuntimeError, match="internal error"):
        gcode_lines(moved, profile)
