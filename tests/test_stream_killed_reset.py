"""A resume after a killed sender, or a stop with no position, checks for a reset since.

A sender killed or crashed mid-job leaves its journal's session without a ``stop`` or
``lost`` event, so no position was recorded. A controller that kept power ran its queue to
the end of the last acknowledged line; one found at machine zero though that line ended
elsewhere reset since (an Arduino resets when its port is opened): the resume asks as after
a reset (refused under --yes before any G-code line; --homed goes on). A stop whose
reports gave no machine position cannot tell: the resume asks, on the safe side.
"""

from __future__ import annotations

import json
import re

import pytest
from test_stop_reconnect import (
    COMMON,
    QUICK,
    WCO,
    _controller,
    _stopped,
    resume_homed_on_a_rebooted_controller,
)
from test_stream import write_job
from test_stream_cli_input import _stream
from test_stream_lost_link_reset import _gcode_rx

from scratchfab.cli import main
from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.sender_program import load_program
from scratchfab.machine.stream_job import reset_since_last_run


def _killed(tmp_path):
    """A stopped run's journal with its ``stop`` cut off, as a killed sender leaves it:
    (the G-code, the machine position at the end of its last acknowledged line)."""
    job, _, _ = _stopped(tmp_path)
    journal = default_journal_path(job)
    lines = journal.read_text().splitlines()
    assert json.loads(lines[-1])["ev"] == "stop"
    journal.write_text("\n".join(lines[:-1]) + "\n")
    last = [ev for ev in read_journal(journal) if ev["ev"] == "ack"][-1]["line"]
    xy = [0.0, 0.0]
    for text in job.read_text().splitlines()[:last]:  # the file's own words, read afresh
        for k, axis in enumerate("XY"):
            found = re.search(rf"{axis}(-?[\d.]+)", text.split(";")[0])
            xy[k] = float(found.group(1)) if found else xy[k]
    return job, (xy[0] + WCO[0], xy[1] + WCO[1])


def test_a_rebooted_controller_after_a_killed_sender_is_refused_under_yes(tmp_path):
    job, end = _killed(tmp_path)
    assert max(abs(v) for v in end) > 1.0  # the job's last line ended away from zero
    rec = tmp_path / "r1.jsonl"
    with _controller(rec) as pty:  # rebooted: machine zero where the tool stands
        pty.start()
        code, _, err = _stream([str(job), "--port", pty.path, "--resume", "--yes"], "")
    assert code == 2 and "Traceback" not in err
    last = err.rstrip().splitlines()[-1]
    assert last.startswith("error: refusing to resume with --yes: the run before this resume")
    assert "the sender killed or crashed" in last and "--homed" in last
    assert f"X{end[0]:g} Y{end[1]:g}" in last.replace(" mm", "")
    assert not _gcode_rx(rec)  # nothing but the connect's queries


def test_a_controller_that_ran_its_queue_resumes_unasked(tmp_path, capsys):
    job, end = _killed(tmp_path)
    capsys.readouterr()
    rec = tmp_path / "r1.jsonl"
    with _controller(rec, [end[0], end[1], -3.0]) as pty:
        pty.start()
        main(["stream", str(job), "--port", pty.path, "--resume", "--yes", *COMMON])
    out = capsys.readouterr()
    assert "the run before this resume" not in out.out + out.err
    assert "done:" in out.out + out.err and _gcode_rx(rec)


def test_homed_resumes_after_a_killed_sender_with_a_note(tmp_path, capsys):
    job, _ = _killed(tmp_path)
    out, sent = resume_homed_on_a_rebooted_controller(job, tmp_path, capsys)
    assert "the sender killed (no stop recorded)" in out.err
    assert "done:" in out.out + out.err and sent


@pytest.mark.parametrize("closing", ["stop", "lost", "end"])
def test_a_closed_session_is_not_read_as_killed(tmp_path, closing):
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z2\nG0 X10 Y20\nG1 Z-0.1 F100\nG1 X12 Y20 F300\n")
    program = load_program(job)
    acks = [{"ev": "ack", "i": i} for i in range(len(program.blocks))]
    start = {"ev": "start", "wco": [1.0, 2.0, 0.0], "steps": None}
    killed = reset_since_last_run([start, *acks], (0.0, 0.0, 0.0), program=program)
    assert killed is not None and killed["why"] == "zero" and killed["ev"] == "killed"
    assert killed["mpos"][:2] == [13.0, 22.0]
    assert reset_since_last_run([start, *acks], (13.0, 22.0, 0.0), program=program) is None
    assert reset_since_last_run([start, *acks], (0.0, 0.0, 0.0)) is None  # no program
    closed = [start, *acks, {"ev": closing, "reason": "x", "executed_through": 3}]
    assert reset_since_last_run(closed, (0.0, 0.0, 0.0), program=program) is None


@pytest.mark.parametrize("s10", [0, 2])
def test_a_stop_recorded_without_a_position_asks_on_resume(tmp_path, s10):
    """Reports in WPos only ($10=0 or 2) on a build that sends no WCO: the stop records no
    machine position, so a resume cannot tell a reset: it asks, refused under --yes."""
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    sim = {**QUICK, "wco": WCO, "wco_field": False, "settings": {10: s10}}
    with GrblPty(SimOptions(**sim, error_at=151)) as pty:
        pty.start()
        code, _, err = _stream([str(job), "--port", pty.path, "--yes"], "")
    assert code == 3, err
    stop = read_journal(default_journal_path(job))[-1]
    assert stop["ev"] == "stop" and "mpos" not in stop
    rec = tmp_path / "r1.jsonl"
    with GrblPty(SimOptions(**sim, record=str(rec))) as pty:
        pty.start()
        code, _, err = _stream([str(job), "--port", pty.path, "--resume", "--yes"], "")
    assert code == 2 and "Traceback" not in err
    last = err.rstrip().splitlines()[-1]
    assert last.startswith("error: refusing to resume with --yes: the run before this resume")
    assert "no position of the machine recorded" in last and "--homed" in last
    assert not _gcode_rx(rec)
    # --homed goes on, with a note naming why it asked
    rec2 = tmp_path / "r2.jsonl"
    with GrblPty(SimOptions(**sim, record=str(rec2))) as pty:
        pty.start()
        code, _, err = _stream([str(job), "--port", pty.path, "--resume", "--yes", "--homed"], "")
    assert code == 0, err
    assert "a stop, with no position of the machine recorded" in err and _gcode_rx(rec2)


@pytest.mark.parametrize("homing", [True, False, None])
def test_a_stop_without_a_position_asks_unless_the_machine_homes(homing):
    """A stop journaled without ``mpos`` (as every stop before this version) asks on resume
    where the session's homing was off or not recorded (a journal that old records none);
    with homing on a controller that reset boots locked in Alarm, which the connect
    refuses, so it resumes unasked."""
    from scratchfab.machine.stream_job import lost_position_warning

    start = {"ev": "start", "sha256": "x", "blocks": 60}
    if homing is not None:
        start["homing"] = homing
    acks = [{"ev": "ack", "i": i} for i in range(40)]
    stop = {"ev": "stop", "reason": "stopped by Ctrl-C", "executed_through": 39}
    warning = lost_position_warning([start, *acks, stop], homing=homing)
    assert (warning is None) == (homing is True)
    if warning is not None:
        assert "no position of the machine recorded" in warning
        assert "the journal is older than such records" in warning
