"""What `stream` says and does after a dropped cable.

A job survives a dropped cable: the message says what to do next (re-home or re-zero,
then the same command with --resume); rerunning without --resume under --yes refuses
rather than cutting again the strokes already done, and the question asked without --yes
says that it starts from the top.
"""

from __future__ import annotations

import pytest
from test_stream import cut_counts, read_record, write_job
from test_stream_cli_input import _gcode_received, _stream

from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.sender_program import load_program

_QUICK = "grblsim://?baud=0&time_scale=0.002"


@pytest.fixture
def dropped(tmp_path):
    """A 40-stroke job whose stream lost its link at block 150: (job, cuts, record, stderr)."""
    job = tmp_path / "job.gcode"
    cuts = write_job(job, 40)
    rec = tmp_path / "r0.jsonl"
    code, _, err = _stream(
        [str(job), "--port", f"{_QUICK}&disconnect_after=150&record={rec}", "--yes"], ""
    )
    assert code == 3
    return job, cuts, rec, err


def test_a_dropped_cable_says_to_re_home_and_resume(dropped):
    _, _, _, err = dropped
    last = err.rstrip().splitlines()[-1]
    assert last.startswith("error: connection lost")
    assert "wait until it stops or press its reset" in last  # first the machine stands still
    tail = last[last.index("press its reset") :]
    assert "re-home or re-zero" in tail and "the same command with --resume" in tail
    assert "--recut-unsure" in tail


def test_a_rerun_under_yes_without_resume_refuses_instead_of_cutting_again(dropped, tmp_path):
    """The unfinished journal: --yes without --resume names the line reached, --resume and
    how to start over; nothing is sent and the journal is untouched. --resume then cuts
    every stroke, at most one twice."""
    job, cuts, rec0, _ = dropped
    journal = default_journal_path(job)
    before = journal.read_bytes()
    acked = [ev["i"] for ev in read_journal(journal) if ev["ev"] == "ack" and "i" in ev]
    reached = load_program(job).blocks[max(acked)].lineno
    rec = tmp_path / "r1.jsonl"
    code, _, err = _stream([str(job), "--port", f"{_QUICK}&record={rec}", "--yes"], "")
    assert code == 2
    last = err.rstrip().splitlines()[-1]
    assert last.startswith(f"error: {journal} shows an unfinished stream of this file")
    assert f"reached line {reached};" in last and "cut those strokes again" in last
    assert "continue it with --resume" in last and "move the journal aside" in last
    assert "without --yes" in last and last.endswith("nothing was sent")
    assert not rec.exists()  # refused before connecting
    assert journal.read_bytes() == before
    rec2 = tmp_path / "r2.jsonl"
    code, out, _ = _stream([str(job), "--port", f"{_QUICK}&record={rec2}", "--yes", "--resume"], "")
    assert code == 0 and "resuming at line" in out
    counts = cut_counts([read_record(rec0), read_record(rec2)], cuts)
    assert min(counts) == 1 and max(counts) <= 2 and counts.count(2) <= 1


@pytest.mark.parametrize("answer", ["n", "y"])
def test_the_question_over_an_unfinished_journal_says_from_the_top(dropped, tmp_path, answer):
    job, cuts, _, _ = dropped
    rec = tmp_path / "r1.jsonl"
    code, _, err = _stream([str(job), "--port", f"{_QUICK}&record={rec}"], f"{answer}\n")
    question = next(ln for ln in err.splitlines() if ln.startswith("Stream "))
    assert " from the top, cutting again what the unfinished stream cut" in question
    assert "--resume continues where it stopped" in question
    if answer == "n":
        assert code == 2 and "not confirmed; nothing was sent" in err
        assert not _gcode_received(read_record(rec))
    else:  # started over on purpose: the whole file, every stroke cut
        assert code == 0
        assert min(cut_counts([read_record(rec)], cuts)) == 1


def test_the_question_over_a_finished_journal_says_nothing_of_the_top(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 3)
    assert _stream([str(job), "--port", _QUICK, "--yes"], "")[0] == 0
    code, _, err = _stream([str(job), "--port", _QUICK], "y\n")
    assert code == 0
    question = next(ln for ln in err.splitlines() if ln.startswith("Stream "))
    assert "from the top" not in question and "unfinished" not in err
