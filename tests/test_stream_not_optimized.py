"""`stream` says when the G-code cuts the design's initial layout (NOT OPTIMIZED).

Toolpath warned and export's header says `NOT OPTIMIZED`, but stream said nothing: a
person streaming a copy under --yes learnt nothing of it. A note line before anything is
asked or sent; the stream is not refused (the initial layout may be meant).
"""

from __future__ import annotations

import shutil

from conftest import cli_said
from test_stream import SIM, read_record, write_job
from test_stream_cli_input import _gcode_received, _stream
from test_toolpath_unoptimized import BUNDLED, job  # noqa: F401  (the fixture)

from scratchfab.model.job import JobLayout

NOTE = "this G-code cuts the design's initial layout (not optimized)"


def test_an_unoptimized_gcode_is_noted_and_streamed(job, tmp_path, monkeypatch, capsys):  # noqa: F811
    argv = ["toolpath", str(job), "--machine", BUNDLED, "--passes", "0"]
    code, said = cli_said(argv, capsys)
    assert code == 0, said
    code, said = cli_said(["export", str(job), "-f", "gcode"], capsys)
    assert code == 0, said
    copy = tmp_path / "elsewhere" / "board.gcode"  # the header travels with the file
    copy.parent.mkdir()
    shutil.copy(JobLayout(job).export_file("gcode"), copy)
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    rec = tmp_path / "rec.jsonl"
    code, out, err = _stream([str(copy), "--port", f"{SIM}&record={rec}", "--yes"], "")
    assert code == 0, err
    notes = [line for line in err.splitlines() if NOTE in line]
    assert notes == [f"note: {copy}: {NOTE}"], err
    assert err.index(NOTE) < err.index("connected:")  # before anything is sent
    assert "done:" in out and _gcode_received(read_record(rec))


def test_a_gcode_without_the_mark_gets_no_note(tmp_path):
    gcode = tmp_path / "foreign.gcode"
    write_job(gcode, 2)
    code, out, err = _stream([str(gcode), "--port", SIM, "--yes"], "")
    assert code == 0, err
    assert "not optimized" not in err and "done:" in out
