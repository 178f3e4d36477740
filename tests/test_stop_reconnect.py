"""A resume after an ordinary stop checks that the controller did not reset since.

An Arduino resets when its port is opened: a controller without homing (``$22=0``) then
boots Idle with machine zero wherever the tool stands, and its G54 offset (kept in EEPROM)
counts from there, so the rest of the board would be cut shifted. The ``stop`` event
records ``mpos`` and ``wco`` as a ``lost`` one does; a resume that finds the controller at
machine zero, elsewhere in X/Y (a jog, or a reset and a jog: alike without homing) or with
another work offset asks whether it was homed or re-zeroed (refused under --yes without
--homed; the emulator, a fresh controller on every open, warns). One that kept power and
was not jogged (or only in Z, as a stop that could not raise the tool advises) resumes
unasked.
"""

from __future__ import annotations

import pytest
from stream_helpers import at_a_terminal  # noqa: F401  (the fixture)
from test_stream import SIM, write_job
from test_stream_cli_input import _stream
from test_stream_lost_link_reset import _gcode_rx

from scratchfab.cli import main
from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.stream_job import reset_since_last_run

COMMON = ["--banner-timeout", "0.3"]
QUICK = {"baud": 0, "time_scale": 0.002}
WCO = (-30.0, -40.0, -5.0)


def _stopped(tmp_path):
    """A 40-stroke job stopped by an error at line 151 on a pty controller with a G54
    offset: (the G-code, where the controller stands after the stop, the stop event)."""
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    with GrblPty(SimOptions(**QUICK, wco=WCO, error_at=151)) as pty:
        pty.start()
        with pytest.raises(SystemExit) as exc:
            main(["stream", str(job), "--port", pty.path, "--yes", *COMMON])
        where = pty.sim.mpos
    assert exc.value.code == 3
    stop = read_journal(default_journal_path(job))[-1]
    assert stop["ev"] == "stop"
    return job, where, stop


def _controller(rec, mpos=None, wco=WCO) -> GrblPty:
    """A pty controller at ``mpos`` (None: as it boots, at machine zero) with ``wco``."""
    pty = GrblPty(SimOptions(**QUICK, wco=wco, record=str(rec)))
    if mpos is not None:
        pty.sim.mpos = pty.sim._target = pty.sim._gc.position = tuple(mpos)
    return pty


def test_the_stop_event_records_where_the_machine_stood(tmp_path):
    _, where, stop = _stopped(tmp_path)
    assert stop["mpos"] == pytest.approx(list(where), abs=0.002)
    assert max(abs(v) for v in where[:2]) > 1.0  # mid-job, away from machine zero
    assert stop["wco"] == pytest.approx(list(WCO))


@pytest.mark.parametrize(
    ("shift", "wco", "words"),
    [
        (None, WCO, "now stands at machine zero"),  # a reboot on the port's opening
        ((5.0, 0.0, 0.0), WCO, "the machine stands elsewhere now"),  # jogged, or reset+jog
        ((0.0, 0.0, 0.0), (-31.0, -40.0, -5.0), "the work offset changed since"),
    ],
)
def test_a_controller_that_may_have_lost_its_zero_is_refused_under_yes(tmp_path, shift, wco, words):
    job, where, _ = _stopped(tmp_path)
    mpos = None if shift is None else [a + b for a, b in zip(where, shift, strict=True)]
    rec = tmp_path / "r1.jsonl"
    with _controller(rec, mpos, wco) as pty:
        pty.start()
        code, _, err = _stream([str(job), "--port", pty.path, "--resume", "--yes"], "")
    assert code == 2 and "Traceback" not in err
    last = err.rstrip().splitlines()[-1]
    assert last.startswith("error: refusing to resume with --yes: the run before this resume")
    assert words in last and "--homed" in last
    assert not _gcode_rx(rec)  # nothing but the connect's queries


@pytest.mark.usefixtures("at_a_terminal")  # a person answers
def test_a_rebooted_controller_asks_and_a_no_sends_nothing(tmp_path):
    job, _, _ = _stopped(tmp_path)
    rec = tmp_path / "r1.jsonl"
    with _controller(rec) as pty:
        pty.start()
        code, out, err = _stream([str(job), "--port", pty.path, "--resume"], "n\n")
    assert code == 2
    assert "now stands at machine zero" in out + err and "Was the machine" in out + err
    assert "not confirmed; nothing was sent" in err
    assert not _gcode_rx(rec)


@pytest.mark.usefixtures("at_a_terminal")  # a person answers
def test_a_jogged_machine_is_asked_whether_it_was_only_jogged(tmp_path):
    job, where, _ = _stopped(tmp_path)
    rec = tmp_path / "r1.jsonl"
    with _controller(rec, [where[0], where[1] - 3.0, where[2]]) as pty:
        pty.start()
        code, out, err = _stream([str(job), "--port", pty.path, "--resume"], "y\ny\n")
    assert code == 0, err
    assert "or was it only jogged and its controller never reset" in out + err
    assert "done:" in out + err and _gcode_rx(rec)


@pytest.mark.parametrize("z_jog", [0.0, 2.5])
def test_a_controller_that_kept_power_resumes_unasked(tmp_path, capsys, z_jog):
    """Where the stop left it, or with only Z jogged up (the stop's own advice when the tool
    could not be raised): no question, under --yes it resumes."""
    job, where, _ = _stopped(tmp_path)
    capsys.readouterr()
    rec = tmp_path / "r1.jsonl"
    with _controller(rec, [where[0], where[1], where[2] + z_jog]) as pty:
        pty.start()
        main(["stream", str(job), "--port", pty.path, "--resume", "--yes", *COMMON])
    out = capsys.readouterr()
    assert "the run before this resume" not in out.out + out.err
    assert "done:" in out.out + out.err


def resume_homed_on_a_rebooted_controller(job, tmp_path, capsys):
    """``stream JOB --resume --yes --homed`` on a controller that rebooted (at machine zero,
    its work offset kept): what it said, and whether G-code reached the controller."""
    capsys.readouterr()
    rec = tmp_path / "r1.jsonl"
    with _controller(rec) as pty:
        pty.start()
        main(["stream", str(job), "--port", pty.path, "--resume", "--yes", "--homed", *COMMON])
    return capsys.readouterr(), _gcode_rx(rec)


def test_homed_resumes_a_rebooted_controller_with_a_note(tmp_path, capsys):
    job, _, _ = _stopped(tmp_path)
    out, sent = resume_homed_on_a_rebooted_controller(job, tmp_path, capsys)
    assert "the controller reset since (it stands at machine zero)" in out.err
    assert "--homed: the machine was" in out.err
    assert "done:" in out.out + out.err and sent


def test_the_emulator_warns_after_a_stop(tmp_path, capsys):
    """grblsim:// is a fresh controller on every open, at machine zero: it warns."""
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    with pytest.raises(SystemExit):
        main(["stream", str(job), "--port", f"{SIM}&error_at=151", "--yes", *COMMON])
    capsys.readouterr()
    main(["stream", str(job), "--port", SIM, "--resume", "--yes", *COMMON])
    err = capsys.readouterr().err
    assert "warning: the run before this resume was stopped" in err
    assert "warning (repeated): the run before this resume was stopped" in err


def _events(ev, was, wco=None, steps=None):
    closing = {"ev": ev, "reason": "x", "executed_through": 3, "mpos": was}
    if wco is not None:
        closing["wco"] = wco
    return [{"ev": "start", "steps": steps}, {"ev": "ack", "i": 0}, closing]


@pytest.mark.parametrize(
    ("now", "wco_now", "homing", "why"),
    [
        ((10.0, 20.0, -1.0), (1.0, 2.0, 3.0), None, None),  # kept power, not jogged
        ((10.05, 19.95, 4.0), (1.0, 2.0, 3.0), False, None),  # two steps + digit; Z jogged
        ((10.06, 20.0, -1.0), (1.0, 2.0, 3.0), False, "moved"),
        ((10.06, 20.0, -1.0), (1.0, 2.0, 3.0), None, "moved"),  # $22 not known
        ((15.0, 20.0, -1.0), (1.0, 2.0, 3.0), True, None),  # homing on: a reset boots locked
        ((0.0, 0.05, 3.0), (1.0, 2.0, 3.0), True, "zero"),  # Z jogged after the reboot
        ((10.0, 20.0, -1.0), (1.0, 2.01, 3.0), None, "wco"),
        ((10.0, 20.0, -1.0), None, None, None),  # no offset read now
    ],
)
def test_reset_since_last_run_after_a_stop(now, wco_now, homing, why):
    events = _events("stop", [10.0, 20.0, -1.0], [1.0, 2.0, 3.0])
    found = reset_since_last_run(events, now, wco_now, homing)
    assert (None if found is None else found["why"]) == why
    if found is not None:
        assert found["lost"] is True and found["mpos_now"] == list(now)
    # a lost link's controller that kept power ran its queue: only machine zero tells
    lost = reset_since_last_run(_events("lost", [10.0, 20.0, -1.0]), now, wco_now, homing)
    assert (None if lost is None else lost["why"]) == ("zero" if why == "zero" else None)


def test_a_stop_recorded_without_a_position_tells_nothing():
    events = _events("stop", None)
    assert reset_since_last_run(events, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), None) is None
