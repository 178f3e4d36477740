"""Scratches planned in memory that lie off the board are counted as such, not as outside
the machine's envelope.

A scratch file is checked against the board when read; a ScratchSet given to
:func:`plan_toolpath` from Python is not, and its scratches are clipped to the board. One
with no part on the board is left out as off the board: the envelope has no part in it,
and the partial-board text (said by toolpath and export, written into the G-code) names
only what the envelope cuts short.
"""

from __future__ import annotations

import numpy as np

from scratchfab.machine.profile import load_profile, profile_from_mapping
from scratchfab.model.design import Board
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath import plan_toolpath
from scratchfab.toolpath.plan import partial_text
from scratchfab.toolpath.stage import summary


def _planned(right_edge: float | None = None):
    """Five scratches on the 3018's 40 mm board, its envelope's right edge at ``right_edge``.

    The bundled profile puts the board's lower-left corner at (-220, -150): board (x, y)
    lies at machine (x - 200, y - 130).
    """
    table = load_profile("grbl-3018-diamond").to_table()
    if right_edge is not None:
        table["envelope"]["x_mm"] = [-300.0, right_edge]
        table["start_mm"] = [right_edge - 5.0, -5.0]
    rows = [
        [-10.0, 0.0, -5.0, 0.0],  # on the board, inside the envelope: cut
        [5.0, 5.0, 10.0, 5.0],  # on the board, machine x -195..-190
        [-30.0, 0.0, -25.0, 0.0],  # off the board's left edge, inside the envelope
        [-10.0, 10.0, 10.0, 10.0],  # on the board, machine x -210..-190
        [25.0, 0.0, 28.0, 0.0],  # off the board's right edge, machine x -175..-172
    ]
    data = np.array(rows)
    scratches = ScratchSet.from_arrays(data[:, :2], data[:, 2:], 0.1, 0.01)
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    return plan_toolpath(scratches, board, profile_from_mapping(table, "<t>"))


def _segments(tp) -> list[list[float]]:
    """The strokes as sorted (x0, y0, x1, y1) rows, each from its smaller end."""
    return sorted(sorted(map(tuple, s.tolist())) for s in tp.strokes)


def test_scratches_off_a_board_inside_the_envelope_are_not_called_outside_it():
    tp = _planned()
    stats = tp.stats
    assert stats["off_board_count"] == 2, stats
    assert (stats["outside_count"], stats["clipped_count"]) == (0, 0), stats
    assert partial_text(stats) is None
    assert stats["count"] == len(tp) == 3
    assert _segments(tp) == [
        [(-210.0, -130.0), (-205.0, -130.0)],
        [(-210.0, -120.0), (-190.0, -120.0)],
        [(-195.0, -125.0), (-190.0, -125.0)],
    ]
    said = summary(tp)
    assert "2 off the board" in said and "0 outside" in said, said


def test_the_envelope_and_the_board_each_count_their_own():
    """The envelope's right edge through the board's middle (machine x = -200)."""
    tp = _planned(right_edge=-200.0)
    stats = tp.stats
    assert stats["off_board_count"] == 2, stats
    assert (stats["outside_count"], stats["clipped_count"]) == (1, 1), stats
    text = partial_text(stats)
    assert text is not None and text.startswith("1 of 5 scratches lie outside"), text
    assert _segments(tp) == [
        [(-210.0, -130.0), (-205.0, -130.0)],
        [(-210.0, -120.0), (-200.0, -120.0)],
    ]
    dropped = stats["off_board_count"] + stats["outside_count"] + stats["short_count"]
    assert stats["count"] == stats["input_count"] - dropped - stats["merged_count"]
