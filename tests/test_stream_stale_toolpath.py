"""`stream JOB` after optimize or design ran again: the toolpath's own inputs are stale.

`toolpath` and `export` refuse a layout or toolpath made from other inputs than there are
now; `stream` read only the G-code's strokes id against toolpath.json, so after
`optimize JOB --resume` it streamed the old board.gcode without a word (under --yes it
cut it). Now it warns; on a machine it asks, and under --yes refuses naming the commands
to rerun. The emulator is only warned of, as for the other checks.
"""

from __future__ import annotations

import pytest
from conftest import write_pipeline
from test_stream import SIM, read_record
from test_stream_cli_input import _gcode_received, _stream

from scratchfab.cli import main
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline
from scratchfab.toolpath import Toolpath
from scratchfab.toolpath.inputs import check_current

STALE = "was planned from other inputs than there are now"


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A tiny job run through export (its toolpath and G-code current), kept pristine."""
    folder = tmp_path_factory.mktemp("stale")
    run_pipeline(
        load_pipeline(write_pipeline(folder)), folder / "job", until="export", say=lambda _: None
    )
    return folder / "job"


def _copy(exported, tmp_path):
    import shutil

    job = tmp_path / "job"
    shutil.copytree(exported, job)
    return job


def test_a_current_toolpath_streams_without_a_word(exported, tmp_path, monkeypatch):
    job = _copy(exported, tmp_path)
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    rec = tmp_path / "rec.jsonl"
    code, out, err = _stream([str(job), "--port", f"{SIM}&record={rec}", "--yes"], "")
    assert code == 0, err
    assert STALE not in err and "done:" in out and _gcode_received(read_record(rec))


def test_after_optimize_resume_the_old_gcode_is_named_asked_about_and_refused_under_yes(
    exported, tmp_path, monkeypatch, capsys
):
    job = _copy(exported, tmp_path)
    capsys.readouterr()
    assert main(["optimize", str(job), "--resume", "--iterations", "6"]) in (None, 0)
    stale, _ = check_current(Toolpath.load(job / "toolpath" / "toolpath.json"))
    assert stale is not None and "scratches.csv changed since" in stale  # export's own finding
    assert f"note: {stale}" in capsys.readouterr().out.splitlines()  # optimize says it at once
    export = f"scratchfab export {job} --format gcode"
    toolpath = f"scratchfab toolpath {job} --machine grbl-3018-diamond"

    # the emulator moves nothing: warned, and it streams
    code, out, err = _stream([str(job), "--port", SIM, "--yes"], "")
    assert code == 0, err
    warning = next(line for line in err.splitlines() if STALE in line)
    assert warning.startswith("warning: ") and "scratches.csv changed since" in warning
    assert f"`{toolpath}`" in warning and f"`{export}`" in warning

    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    # a machine under --yes: refused before connecting, naming both commands
    rec = tmp_path / "rec.jsonl"
    code, _, err = _stream([str(job), "--port", f"{SIM}&record={rec}", "--yes"], "")
    refusal = err.rstrip().splitlines()[-1]
    assert code == 2 and refusal.startswith("error: refusing to stream with --yes: "), err
    assert "scratches.csv changed since" in refusal
    assert f"`{toolpath}`" in refusal and f"`{export}`" in refusal
    assert "run without --yes to be asked" in refusal and "nothing was sent" in refusal
    assert not rec.exists()  # never connected

    # a machine, a person asked: the warning names the change and the commands, once (the
    # ~300-character text was printed again in full as the question); the question is short
    code, _, err = _stream([str(job), "--port", f"{SIM}&record={rec}"], "n\n")
    assert code == 2 and "not confirmed; nothing was sent" in err
    assert err.count("scratches.csv changed since") == 1 and err.count(f"`{export}`") == 1, err
    question = next(line for line in err.splitlines() if "anyway" in line)
    assert "Stream the out-of-date plan of " in question and STALE not in question
    assert err.index("warning: ") < err.index(question)
    assert not rec.exists()

    # the advice followed: toolpath and export again, and it streams unasked
    assert main(["toolpath", str(job), "--machine", "grbl-3018-diamond"]) in (None, 0)
    assert main(["export", str(job), "--format", "gcode"]) in (None, 0)
    code, out, err = _stream([str(job), "--port", f"{SIM}&record={rec}", "--yes"], "")
    assert code == 0, err
    assert STALE not in err and _gcode_received(read_record(rec))


def test_after_a_design_change_optimize_is_named_first(exported, tmp_path, monkeypatch):
    """A design changed since: the layout is stale too, so optimize comes before toolpath
    (toolpath alone would refuse the earlier design's layout)."""
    job = _copy(exported, tmp_path)
    design = job / "design" / "design.toml"
    text = design.read_text()
    assert "position_mm = [0.0, 187.3, 463.6]" in text
    design.write_text(
        text.replace("position_mm = [0.0, 187.3, 463.6]", "position_mm = [0.0, 180.0, 460.0]")
    )
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    code, _, err = _stream([str(job), "--port", SIM, "--yes"], "")
    refusal = err.rstrip().splitlines()[-1]
    assert code == 2 and refusal.startswith("error: refusing to stream with --yes: "), err
    assert "design.toml changed since" in refusal
    optimize = refusal.index(f"`scratchfab optimize {job}`")
    assert (
        optimize
        < refusal.index(f"`scratchfab toolpath {job}")
        < refusal.index(f"`scratchfab export {job} --format gcode`")
    )


def test_a_job_given_relative_is_named_relative(exported, tmp_path, monkeypatch):
    """Given as a path relative to the current directory, the job's files are named so in
    the warning and the commands it gives (not one path as given, the others absolute)."""
    job = _copy(exported, tmp_path)
    assert main(["optimize", str(job), "--resume", "--iterations", "6"]) in (None, 0)
    monkeypatch.chdir(tmp_path)
    code, _, err = _stream(["job", "--port", SIM, "--yes"], "")
    assert code == 0, err
    warning = next(line for line in err.splitlines() if STALE in line)
    assert str(tmp_path) not in warning, warning
    assert warning.startswith("warning: job/export/board.gcode cuts an out-of-date plan: ")
    assert "job/toolpath/toolpath.json was planned from" in warning
    assert "`scratchfab export job --format gcode`" in warning
