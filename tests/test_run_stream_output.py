"""`scratchfab run`'s output after a stream fault: the error, then where the report is.

The run-only note ("here `scratchfab run` has no --resume") was glued onto the fault's last
clause (the tool's "jog Z up") and never named --homed, which the resume after a reset
asks for; and the "report:" line came before the error it should follow.
"""

from __future__ import annotations

import pytest
from conftest import PIPELINE, write_pipeline

from scratchfab.cli import main
from scratchfab.pipeline.runner import as_run_advice


def test_a_reset_during_runs_stream_prints_the_error_then_the_report(tmp_path, capsys):
    port = next(line for line in PIPELINE.splitlines() if line.startswith("port ="))
    path = write_pipeline(tmp_path, edits={port: port[:-1] + '&reset_after=30"'})
    job = tmp_path / "job"
    with pytest.raises(SystemExit) as exc:
        main(["run", str(path), "--out", str(job)])
    assert exc.value.code == 3
    out, err = capsys.readouterr()
    assert "report:" not in out  # it follows the error, on the same stream
    lines = err.rstrip().splitlines()
    first = next(k for k, line in enumerate(lines) if line.startswith("error: "))
    assert "the controller reset itself" in lines[first]
    assert lines[-1] == f"report: {job / 'report.html'}"
    note = next(line for line in lines[first:] if "has no --resume" in line)
    assert note.startswith("  once the position is found again as said above, add --homed")
    assert all("has no --resume" not in line for line in lines if "NOT raised" in line)


@pytest.mark.parametrize(
    ("sender", "note"),
    [
        # one line: the note follows it; no position lost, no --homed
        ("connection lost: reconnect, re-home, then --resume", " (here"),
        # a fault's clauses on lines of their own: the note on one of its own, with --homed
        ("reset itself\n  its position may be lost: re-zero, then --resume", "\n  once the"),
    ],
)
def test_the_run_note_follows_the_messages_shape(sender, note):
    text = as_run_advice(sender)
    assert text.startswith(sender + note)
    assert text.endswith("(here `scratchfab run` has no --resume: run it again and it resumes)")
    assert ("--homed" in text) == ("lost: re-zero" in sender)
