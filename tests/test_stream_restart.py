"""What `stream` says and does after a dropped cable, and before a partial board.

A job survives a dropped cable: the message says what to do next (re-home or re-zero,
then the same command with --resume); rerunning without --resume under --yes refuses
rather than cutting again the strokes already done, and the question asked without --yes
says that it starts from the top. A board the machine's envelope cuts short (a toolpath
planned with force) is said, and on a machine asked about (refused under --yes).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from stream_helpers import PARTIAL_BOARD_CASES
from test_stream import SIM, cut_counts, read_record, write_job
from test_stream_cli_input import _gcode_received, _stream

from scratchfab.export.gcode import gcode_lines
from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.sender_program import load_program
from scratchfab.model.job import JobLayout
from scratchfab.toolpath.plan import Toolpath, partial_text

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
    """A short error line, then the advice, a line each: first the machine stands still,
    then re-home or re-zero and the same command with --resume."""
    _, _, _, err = dropped
    lines = err.rstrip().splitlines()
    first = next(k for k, line in enumerate(lines) if line.startswith("error: "))
    error, advice = lines[first], lines[first + 1 :]
    assert error.startswith("error: connection lost") and len(error) <= 100
    assert len(advice) >= 2 and all(line.startswith("  ") for line in advice)
    wait = next(k for k, line in enumerate(advice) if "wait until it stops or press" in line)
    # the emulator's homing is off ($22=0): $H would answer error:5, so re-zero only
    then = next(k for k, line in enumerate(advice) if "re-zero the machine" in line)
    assert "re-home" not in advice[then]
    assert wait < then and "the same command with --resume" in advice[then]
    assert "--recut-unsure" in advice[then]


def test_a_faults_clauses_go_on_lines_of_their_own_outside_parentheses():
    from scratchfab.machine.stream_job import fault_lines

    text = "lost: x (a; b); held (spindle off; tool up); then (c) run --resume"
    assert fault_lines(text).splitlines() == [
        "lost: x (a; b)",
        "  held (spindle off; tool up)",
        "  then (c) run --resume",
    ]
    assert fault_lines("one clause (a; b)") == "one clause (a; b)"


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


def test_an_unfinished_stream_that_began_no_stroke_is_no_reason_to_refuse(tmp_path):
    """The stream stopped during the set-up lines: no stroke was begun, so a stream from
    the top under --yes cuts nothing twice and goes ahead, and its question says no
    'again'."""
    job = tmp_path / "job.gcode"
    cuts = write_job(job, 6)
    assert _stream([str(job), "--port", _QUICK, "--yes"], "")[0] == 0
    first_stroke = load_program(job).strokes[0][0]
    journal = default_journal_path(job)
    kept = [  # the run's start and its set-up lines' acknowledgements, as a killed sender's
        line
        for line in journal.read_text().splitlines()
        if json.loads(line)["ev"] == "start"
        or (json.loads(line)["ev"] == "ack" and json.loads(line).get("i", 0) < first_stroke)
    ]
    assert len(kept) > 2
    journal.write_text("\n".join(kept) + "\n")
    rec = tmp_path / "r1.jsonl"
    code, out, err = _stream([str(job), "--port", f"{_QUICK}&record={rec}"], "n\n")
    question = next(ln for ln in err.splitlines() if ln.startswith("Stream "))
    assert code == 2 and "cutting again" not in question
    code, out, err = _stream([str(job), "--port", f"{_QUICK}&record={rec}", "--yes"], "")
    assert code == 0, err
    assert "done:" in out and cut_counts([read_record(rec)], cuts) == [1] * len(cuts)


def test_an_unfinished_stream_with_every_line_acknowledged_is_not_told_to_continue(tmp_path):
    """Every line acknowledged, the journal not closed (the link lost at its very end): a
    stream from the top under --yes is refused without 'continue it with --resume', which
    has nothing left to cut; --resume closes the journal."""
    job = tmp_path / "job.gcode"
    write_job(job, 4)
    assert _stream([str(job), "--port", _QUICK, "--yes"], "")[0] == 0
    journal = default_journal_path(job)
    lines = journal.read_text().splitlines()
    assert json.loads(lines[-1])["ev"] == "end"
    end_block = len(load_program(job).blocks) - 1
    lost = {"ev": "lost", "reason": "connection lost", "executed_through": end_block}
    lines[-1] = json.dumps(lost)  # the link went after the last line, before the end
    journal.write_text("\n".join(lines) + "\n")
    before = journal.read_bytes()
    rec = tmp_path / "r1.jsonl"
    code, _, err = _stream([str(job), "--port", f"{_QUICK}&record={rec}", "--yes"], "")
    last = err.rstrip().splitlines()[-1]
    assert code == 2 and "every line acknowledged" in last and "cut the whole board again" in last
    assert "continue it with --resume" not in last and last.endswith("nothing was sent")
    assert not rec.exists() and journal.read_bytes() == before
    code, _, err = _stream([str(job), "--port", f"{_QUICK}&record={rec}"], "n\n")
    question = next(ln for ln in err.splitlines() if ln.startswith("Stream "))
    assert code == 2 and "cutting again" in question and "continues where" not in question
    code, out, _ = _stream([str(job), "--port", _QUICK, "--yes", "--resume"], "")
    assert code == 0 and "every line is done" in out and "nothing to do" in out


def _partial_job(tmp_path, outside: int, clipped: int) -> tuple[JobLayout, dict]:
    """A job folder whose toolpath.json (3018 profile) says ``outside`` of its scratches
    lay off the envelope and ``clipped`` were clipped, and the G-code exported from it."""
    layout = JobLayout(tmp_path / "job")
    profile = load_profile("grbl-3018-diamond")
    env = profile.envelope
    rng = np.random.default_rng(5)
    lo = np.array([env.x_mm[0], env.y_mm[0]]) + 20.0
    hi = np.array([env.x_mm[1], env.y_mm[1]]) - 20.0
    a = rng.uniform(lo, hi, (6, 2))
    strokes = np.stack([a, a + rng.uniform(-5.0, 5.0, (6, 2))], axis=1).round(3)
    outline = np.array([lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]])
    stats = {"input_count": 6 + outside, "outside_count": outside, "clipped_count": clipped}
    tp = Toolpath(strokes, np.arange(6), (100.0, 100.0), outline, profile, stats)
    layout.toolpath_json.parent.mkdir(parents=True)
    tp.save(layout.toolpath_json)
    gcode = layout.export_file("gcode")
    gcode.parent.mkdir(parents=True)
    gcode.write_text("\n".join(gcode_lines(tp)) + "\n")
    return layout, stats


@pytest.mark.parametrize(("real", "flags", "answers", "refusal"), PARTIAL_BOARD_CASES)
def test_a_partial_board_is_said_and_on_a_machine_asked_about(
    tmp_path, monkeypatch, real, flags, answers, refusal
):
    layout, stats = _partial_job(tmp_path, outside=3, clipped=1)
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: not real)
    rec = tmp_path / "rec.jsonl"
    code, out, err = _stream([str(layout.root), "--port", f"{SIM}&record={rec}", *flags], answers)
    assert "Traceback" not in err
    lost = (
        f"{stats['outside_count']} of {stats['input_count']} scratches lie outside the "
        f"machine's envelope (not cut) and {stats['clipped_count']} are clipped to it "
        f"({layout.toolpath_preview})"
    )
    assert f"warning: a partial board: {lost}" in err
    assert ("Cut a partial board? " + lost in err) == (real and not flags)
    if refusal is not None:
        assert code == 2 and refusal in err
        assert not rec.exists() and not layout.journal.exists()  # asked before connecting
    else:
        assert code == 0, err
        assert "done:" in out and _gcode_received(read_record(rec))


def test_a_whole_board_is_neither_said_nor_asked_about(tmp_path, monkeypatch):
    layout, _ = _partial_job(tmp_path, outside=0, clipped=0)
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    code, _, err = _stream([str(layout.root), "--port", SIM], "y\n")
    assert code == 0, err
    assert "partial board" not in err


def test_a_broken_toolpath_json_with_machine_given_streams_on_the_headers_partial_check(
    tmp_path,
):
    """The toolpath unread, the G-code's own header still says the board is partial."""
    layout, stats = _partial_job(tmp_path, outside=3, clipped=0)
    layout.toolpath_json.write_text(json.dumps({"format": "nonsense"}))
    args = [str(layout.root), "--port", SIM, "--yes"]
    code, _, err = _stream(args, "")
    assert code == 2 and f"{layout.toolpath_json}: not a scratchfab toolpath" in err
    code, _, err = _stream([*args, "--machine", "grbl-3018-diamond"], "")
    assert code == 0, err
    gcode = layout.export_file("gcode")
    lost = f"{partial_text(stats)} (the header of {gcode} says so)"
    assert f"warning: a partial board: {lost}" in err
