"""The offset advice's range: every offset_mm it names puts the whole board inside the envelope.

A range end is written rounded inward to the G-code's decimals: rounded to nearest, an
end could lie outside the range, farther than the toolpath stage keeps on the edge (half
a written digit), and the board placed there would be cut short. The reference is the
board's extent worked out here from its centre (origin "center", not turned).
"""

from __future__ import annotations

import re

import pytest

from scratchfab.machine.profile import load_profile, profile_from_mapping
from scratchfab.toolpath.plan import fit_advice

NUMBER = r"(-?\d+(?:\.\d+)?)"


def centred(decimals: int, x_mm: tuple[float, float] = (-300.0, 0.0)):
    table = load_profile("grbl-3018-diamond").to_table()
    table["gcode"]["decimals"] = decimals
    table["tool"]["tolerance_mm"] = 0.5
    table["envelope"]["x_mm"] = list(x_mm)
    table["board"].update(origin="center", rotation_deg=0, offset_mm=[50.0, 50.0])
    return profile_from_mapping(table, "<centred>")


@pytest.mark.parametrize(
    ("decimals", "board", "x_mm"),
    [
        (3, (123.4567, 77.77777), (-300.0, 0.0)),
        (4, (123.4567, 77.77777), (-300.0, 0.0)),
        (2, (123.4567, 77.77777), (-300.0, 0.0)),
        (3, (1500.12345, 40.0), (-2000.0, 0.0)),
        (3, (40.0, 40.0), (-300.0, 0.0)),
    ],
)
def test_each_end_of_the_range_fits_and_one_digit_past_it_does_not(decimals, board, x_mm):
    profile = centred(decimals, x_mm)
    advice = fit_advice(profile, board)
    found = re.search(rf"from X {NUMBER} to {NUMBER} and Y {NUMBER} to {NUMBER}", advice)
    assert found, advice
    ends = [float(v) for v in found.groups()]
    unit = 10.0**-decimals
    for text in found.groups():
        assert len(text.partition(".")[2]) <= decimals, text  # as the G-code writes numbers
    envelope = (x_mm, profile.envelope.y_mm)
    for axis in range(2):
        lo, hi = envelope[axis]
        half = board[axis] / 2
        first, last = ends[2 * axis], ends[2 * axis + 1]
        assert lo <= first - half and last + half <= hi, (axis, first, last)
        # tight: one written digit further, the board leaves the envelope
        assert first - unit - half < lo and last + unit + half > hi, (axis, first, last)


@pytest.mark.parametrize(
    ("board", "x_mm", "clear"),
    [((100.0, 100.0), (-300.0, 0.0), True), ((299.5, 40.0), (-300.0, 0.0), True)]
    + [((300.0, 40.0), (-300.0, 0.0), False)],
)
def test_the_offset_named_lies_in_the_range_and_the_text_says_why_not_at_its_end(
    board, x_mm, clear
):
    """Whole-millimetre range ends put the board on the envelope's edge: the offset named
    lies inside them, and the text says it keeps the board clear of the edges (where it
    does: a board as wide as the travel has one offset, on both edges)."""
    profile = centred(3, x_mm)
    advice = fit_advice(profile, board)
    found = re.search(
        rf"offset_mm = \[{NUMBER}, {NUMBER}\] \(the nearest to its \[50, 50\]"
        rf"( that keeps the board clear of the envelope's edges)?\).* from X {NUMBER} to "
        rf"{NUMBER} and Y {NUMBER} to {NUMBER}",
        advice,
    )
    assert found, advice
    x, y, said_clear, *ends = found.groups()
    offset = (float(x), float(y))
    envelope = (x_mm, profile.envelope.y_mm)
    placed_clear = []
    for axis in range(2):
        first, last = float(ends[2 * axis]), float(ends[2 * axis + 1])
        assert first <= offset[axis] <= last, advice
        lo, hi = envelope[axis]
        half = board[axis] / 2
        placed_clear.append(lo < offset[axis] - half and offset[axis] + half < hi)
    assert all(placed_clear) is clear is (said_clear is not None), advice
