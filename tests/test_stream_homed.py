"""A resume after an alarm that may have lost the position waits for a person's word.

GRBL needs `$H` or `$X` after such an alarm and answers both alike: the sender cannot tell
whether the machine was homed, and after `$X` alone the resumed strokes land off. On a
machine the resume is asked about before anything is sent, refused under --yes, and goes
ahead unasked with --homed (`stream --resume --homed`, `run --homed`). The emulator, which
moves nothing, only warns (test_stream_resume_warning).
"""

from __future__ import annotations

import pytest
from stream_helpers import alarmed_job, at_a_terminal, hard_limit_run  # noqa: F401
from test_stream import SIM, read_record
from test_stream_cli_input import _gcode_received, _stream

from scratchfab.errors import ScratchfabError
from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.stream_job import lost_position_warning


@pytest.fixture(params=[True, "maybe"])
def alarmed(tmp_path, request):
    """A job stopped after 12 acknowledged lines by an alarm that (maybe) lost the position:
    (the G-code, the lost-position warning)."""
    job = tmp_path / "job.gcode"
    return job, alarmed_job(job, request.param, 1)


def _sessions(job) -> int:
    return sum(ev["ev"] == "start" for ev in read_journal(default_journal_path(job)))


@pytest.mark.usefixtures("at_a_terminal")  # a person answers
@pytest.mark.parametrize(
    ("flags", "answers", "refusal"),
    [
        (["--yes"], "", "error: refusing to resume with --yes: "),
        ([], "n\n", "error: not confirmed; nothing was sent: "),
        ([], "y\ny\n", None),  # homed, then the usual question
        (["--yes", "--homed"], "", None),
        (["--homed"], "y\n", None),  # only the usual question
    ],
)
def test_a_resume_after_a_lost_position_on_a_machine_needs_homed_or_a_yes(
    alarmed, tmp_path, monkeypatch, flags, answers, refusal
):
    job, warning = alarmed
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    rec = tmp_path / "rec.jsonl"
    before = _sessions(job)
    args = [str(job), "--port", f"{SIM}&record={rec}", "--resume", *flags]
    code, out, err = _stream(args, answers)
    assert "Traceback" not in err
    question = f"{warning[0].upper()}{warning[1:]}. Was the machine homed ($H)"
    assert (question in err) == ("--homed" not in flags and "--yes" not in flags)
    if refusal is not None:
        assert code == 2
        last = err.rstrip().splitlines()[-1]
        assert last.startswith(refusal) and "--homed" in last and "$H" in last
        assert warning in last or "--yes" not in flags
        # refused before connecting: the controller heard nothing, the journal is as it was
        assert not rec.exists() and _sessions(job) == before
        return
    assert code == 0, err
    assert "done:" in out and _gcode_received(read_record(rec))
    said = "which may have lost the position; --homed: the machine was homed" in err
    assert said == ("--homed" in flags)
    assert "warning (repeated)" not in err  # a person answered for it: not said again


def test_homed_only_applies_with_resume(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z2\n")
    code, _, err = _stream([str(job), "--port", SIM, "--homed", "--yes"], "")
    assert code == 2 and "--homed only applies with --resume" in err


def test_run_resumes_after_a_lost_position_only_with_homed(tmp_path, monkeypatch, capsys):
    """The pipeline's stream stage resumes an interrupted stream by itself: after an alarm
    that may have lost the position, `run --yes` refuses until `run --yes --homed`."""

    from scratchfab.cli import main
    from scratchfab.pipeline.config import load_pipeline
    from scratchfab.pipeline.runner import run_pipeline

    path, job, journal = hard_limit_run(tmp_path)
    warning = lost_position_warning(read_journal(journal))
    assert warning is not None
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    text = journal.read_bytes()
    with pytest.raises(ScratchfabError) as refused:
        run_pipeline(load_pipeline(path), job, say=lambda _: None, confirm=None)
    assert "refusing to resume with --yes" in str(refused.value) and "--homed" in str(refused.value)
    assert journal.read_bytes() == text  # nothing was sent
    capsys.readouterr()
    main(["run", str(path), "--out", str(job), "--yes", "--homed"])
    out, _ = capsys.readouterr()
    assert "ALARM:1, which may have lost the position; --homed: the machine was homed" in out
    assert "[stream] done" in out
    after = read_journal(journal)
    resumed = max(k for k, e in enumerate(after) if e["ev"] == "start")
    assert after[resumed]["resume"] is True and after[-1]["ev"] == "end"
