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
