"""`stream` reads the header comments of whatever G-code file it is given.

The partial-board check once read the job's toolpath.json only, so a copy of a partial
board's `export/board.gcode` streamed from elsewhere went to the machine unasked, even under
--yes. The header's `PARTIAL BOARD` comments travel with the file; a foreign file without
them streams as before. Every header comment fits GRBL's 79 characters, however large the
counts, and still reads back.
"""

from __future__ import annotations

import shutil

import pytest
from stream_helpers import PARTIAL_BOARD_CASES
from test_stream import SIM, read_record, write_job
from test_stream_cli_input import _gcode_received, _stream
from test_stream_restart import _partial_job

from scratchfab.export.gcode import gcode_lines, read_header
from scratchfab.machine.profile import load_profile
from scratchfab.toolpath.plan import Toolpath, partial_text


@pytest.mark.parametrize(
    ("outside", "clipped"), [(3, 1), (0, 2), (123_456_789, 987_654_321_098), (99_999_999, 0)]
)
def test_the_partial_board_comments_fit_a_line_and_read_back(tmp_path, outside, clipped):
    layout, stats = _partial_job(tmp_path, outside=outside, clipped=clipped)
    lines = gcode_lines(Toolpath.load(layout.toolpath_json))
    limit = load_profile("grbl-3018-diamond").gcode.max_line_length
    assert limit == 79
    assert all(len(line) <= limit for line in lines)
    assert sum(line.startswith("(PARTIAL BOARD") for line in lines) == 2
    assert read_header(lines).partial == partial_text(stats)


def test_a_header_too_narrow_for_the_counts_still_says_partial(tmp_path):
    """A machine with short lines: the counts that do not fit are left out, not cut (a cut
    count would misstate the loss), and the bare comment still marks the board partial."""
    from dataclasses import replace

    layout, _ = _partial_job(tmp_path, outside=123_456_789, clipped=987_654_321)
    tp = Toolpath.load(layout.toolpath_json)
    profile = tp.profile
    narrow = replace(profile, gcode=replace(profile.gcode, max_line_length=40))
    lines = gcode_lines(tp, narrow)
    partial = [line for line in lines if line.startswith("(PARTIAL BOARD")]
    assert partial == ["(PARTIAL BOARD)", "(PARTIAL BOARD: 987654321 clipped)"]
    said = read_header(lines).partial
    assert said is not None and "PARTIAL BOARD" in said


def test_an_earlier_exports_single_partial_comment_reads_back():
    stats = {"outside_count": 4, "input_count": 30, "clipped_count": 2}
    earlier = [
        "G21 G90 G17 G94",
        "(PARTIAL BOARD: 4 of 30 scratches outside the envelope, 2 clipped)",
        "G0 Z5",
    ]
    assert read_header(earlier).partial == partial_text(stats)
    assert read_header(["G21 G90", "(no header here)", "G0 Z5"]).partial is None


@pytest.mark.parametrize(("real", "flags", "answers", "refusal"), PARTIAL_BOARD_CASES)
def test_a_copy_of_a_partial_board_gcode_is_said_and_on_a_machine_asked_about(
    tmp_path, monkeypatch, real, flags, answers, refusal
):
    layout, stats = _partial_job(tmp_path / "made", outside=3, clipped=1)
    copy = tmp_path / "elsewhere" / "board-copy.gcode"
    copy.parent.mkdir()
    shutil.copy(layout.export_file("gcode"), copy)
    shutil.rmtree(layout.root)  # nothing of the job is left to read
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: not real)
    rec = tmp_path / "rec.jsonl"
    code, out, err = _stream([str(copy), "--port", f"{SIM}&record={rec}", *flags], answers)
    assert "Traceback" not in err
    lost = f"{partial_text(stats)} (the header of {copy} says so)"
    assert f"warning: a partial board: {lost}" in err
    assert ("Cut a partial board? " + lost in err) == (real and not flags)
    if refusal is not None:
        assert code == 2 and refusal in err
        assert not rec.exists()  # asked before connecting
    else:
        assert code == 0, err
        assert "done:" in out and _gcode_received(read_record(rec))


def test_a_foreign_gcode_without_our_header_streams_as_before(tmp_path, monkeypatch):
    job = tmp_path / "foreign.gcode"
    write_job(job, 3)
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    rec = tmp_path / "rec.jsonl"
    code, out, err = _stream([str(job), "--port", f"{SIM}&record={rec}", "--yes"], "")
    assert code == 0, err
    assert "partial board" not in err and "done:" in out
    assert _gcode_received(read_record(rec))
