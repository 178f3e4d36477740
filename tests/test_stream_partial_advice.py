"""The partial-board refusal under --yes names every step that changes what is streamed.

`stream` streams JOB/export/board.gcode but reads the partial-board figures from
JOB/toolpath/toolpath.json: a toolpath planned again without an export leaves the old
partial G-code in place, and the check then finds nothing to say. The advice must name
the export too; followed whole (toolpath and export), the stream goes ahead unasked.
"""

from __future__ import annotations

import shutil

from test_stream import SIM, read_record
from test_stream_cli_input import _gcode_received, _stream
from test_stream_restart import _partial_job

from scratchfab.cli import main


def test_the_partial_board_refusal_says_to_export_again_and_following_it_streams(
    tmp_path, monkeypatch
):
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    layout, _ = _partial_job(tmp_path, outside=3, clipped=1)
    code, _, err = _stream([str(layout.root), "--port", SIM, "--yes"], "")
    assert code == 2
    refusal = err.rstrip().splitlines()[-1]
    assert refusal.startswith("error: refusing to cut a partial board with --yes: ")
    assert "plan the toolpath and export again" in refusal
    # the advice followed: a whole board's toolpath and the G-code exported from it
    shutil.rmtree(layout.root)
    layout, _ = _partial_job(tmp_path, outside=0, clipped=0)
    rec = tmp_path / "rec.jsonl"
    code, out, err = _stream([str(layout.root), "--port", f"{SIM}&record={rec}", "--yes"], "")
    assert code == 0, err
    assert "partial board" not in err and "done:" in out
    assert _gcode_received(read_record(rec))


def test_a_gcode_exported_from_an_earlier_plan_is_named_and_refused_under_yes(
    tmp_path, monkeypatch
):
    """Toolpath planned again (another seed: another order) without an export: the G-code's
    header still names the earlier strokes. On a machine under --yes the stream is refused
    with the export to run; run, it streams unasked. The emulator is only warned of."""
    from conftest import write_pipeline

    from scratchfab.export.gcode import read_header
    from scratchfab.pipeline.config import load_pipeline
    from scratchfab.pipeline.runner import run_pipeline
    from scratchfab.toolpath import Toolpath

    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    run_pipeline(load_pipeline(path), job, until="export", say=lambda _: None)
    gcode = job / "export" / "board.gcode"
    planned = Toolpath.load(job / "toolpath" / "toolpath.json")
    assert read_header(gcode.read_text().splitlines()).strokes_id == planned.strokes_id
    main(["toolpath", str(job), "--machine", "grbl-3018-diamond", "--seed", "7"])
    again = Toolpath.load(job / "toolpath" / "toolpath.json")
    assert again.strokes_id != planned.strokes_id  # another order of the same strokes
    code, _, err = _stream([str(job), "--port", SIM], "")  # the emulator: a warning
    assert "was exported from another plan than" in err
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    code, _, err = _stream([str(job), "--port", SIM, "--yes"], "")
    refusal = err.rstrip().splitlines()[-1]
    assert code == 2 and refusal.startswith("error: refusing to stream with --yes: ")
    assert f"run `scratchfab export {job} --format gcode` first" in refusal
    main(["export", str(job), "--format", "gcode"])
    rec = tmp_path / "rec.jsonl"
    code, out, err = _stream([str(job), "--port", f"{SIM}&record={rec}", "--yes"], "")
    assert code == 0, err
    assert "another plan" not in err and _gcode_received(read_record(rec))
