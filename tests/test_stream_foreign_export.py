"""A G-code of another job copied into JOB/export is not called an earlier plan of this job.

``stream JOB`` compares the header's strokes id with ``toolpath.json``'s. One that differs
was called "exported from another plan ... (planned again since)" even where it came from
another job: no earlier plan's id is kept, but a file newer than the plan was not exported
from it, nor from a plan before it.
"""

from __future__ import annotations

import shutil

from test_stream import SIM
from test_stream_cli_input import _stream

from scratchfab.cli import main


def test_another_jobs_gcode_is_not_called_an_earlier_plan(tmp_path, monkeypatch):
    from conftest import write_pipeline

    from scratchfab.pipeline.config import load_pipeline
    from scratchfab.pipeline.runner import run_pipeline

    job = tmp_path / "job"
    run_pipeline(load_pipeline(write_pipeline(tmp_path)), job, until="export", say=lambda _: None)
    other = tmp_path / "other"
    shutil.copytree(job, other)
    main(["toolpath", str(other), "--machine", "grbl-3018-diamond", "--seed", "7", "--force"])
    main(["export", str(other), "--format", "gcode"])
    shutil.copy(other / "export" / "board.gcode", job / "export" / "board.gcode")  # a new mtime
    code, _, err = _stream([str(job), "--port", SIM], "")  # the emulator: a warning
    assert "was not exported from this job's toolpath" in err
    assert "another plan" not in err and "planned again since" not in err
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    code, _, err = _stream([str(job), "--port", SIM, "--yes"], "")
    refusal = err.rstrip().splitlines()[-1]
    assert code == 2 and refusal.startswith("error: refusing to stream with --yes: ")
    assert "not exported from this job's toolpath" in refusal
    assert f"run `scratchfab export {job} --format gcode` first" in refusal
