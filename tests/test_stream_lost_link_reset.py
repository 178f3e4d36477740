"""A resume after a dropped link asks whether the machine was homed where the controller reset.

An Arduino resets when its port is opened, and a board powered over the cable loses power
with it: a controller without homing then boots Idle at machine zero, answering as if
nothing happened. The journal's ``lost`` event records the last report's MPos; a resume
that finds the controller at machine zero though it stood elsewhere asks as after a reset
(refused under --yes without --homed; the emulator warns). One that kept power stands at
the end of its queue and resumes unasked.
"""

from __future__ import annotations

import json
import re
import time

import pytest
from stream_helpers import at_a_terminal  # noqa: F401  (the fixture)
from test_stream import SIM, read_record, write_job
from test_stream_cli_input import _stream

from scratchfab.cli import main
from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.stream_job import reset_since_last_run

COMMON = ["--banner-timeout", "0.3"]
QUICK = {"baud": 0, "time_scale": 0.002}


def _drop_link(tmp_path, rec_name="r0.jsonl"):
    """A 40-stroke job whose stream lost its link after 151 lines, through a pty that keeps
    power: (the G-code, the pty, the journal's ``lost`` event)."""
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    pty = GrblPty(
        SimOptions(**QUICK, disconnect_after=151, record=str(tmp_path / rec_name))
    ).start()
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", pty.path, "--yes", *COMMON])
    assert exc.value.code == 3
    lost = read_journal(default_journal_path(job))[-1]
    assert lost["ev"] == "lost"
    return job, pty, lost


def _settled(pty: GrblPty) -> tuple[float, float, float]:
    """Where a controller that kept power stands once it ran the queue it had received."""
    last, since = None, time.monotonic()
    while time.monotonic() - since < 0.3:
        if pty.sim.mpos != last:
            last, since = pty.sim.mpos, time.monotonic()
        time.sleep(0.02)
    return pty.sim.mpos


def _resume(job, port, *flags):
    main(["stream", str(job), "--port", port, "--resume", *flags, *COMMON])


def _gcode_rx(record) -> list[str]:
    return [e["text"] for e in read_record(record) if e["ev"] == "rx" and e["g"]]


def test_lost_event_records_the_last_reported_position(tmp_path, capsys):
    """The event's MPos is the last report's, as the last progress line showed it (WCO 0)."""
    job, pty, lost = _drop_link(tmp_path)
    pty.close()
    shown = re.findall(r" X(-?[\d.]+) Y(-?[\d.]+) Z(-?[\d.]+)", capsys.readouterr().err)[-1]
    assert lost["mpos"] == pytest.approx([float(v) for v in shown], abs=0.005)
    assert any(abs(v) > 0.1 for v in lost["mpos"])  # mid-job, away from machine zero
    assert lost["wco"] == [0.0, 0.0, 0.0]


def test_machine_that_rebooted_is_refused_under_yes_and_resumes_with_homed(tmp_path, capsys):
    """A fresh controller (a reboot) stands at machine zero: under --yes the resume is
    refused once connected, with no G-code sent; --homed resumes with a note."""
    job, pty, lost = _drop_link(tmp_path)
    pty.close()
    capsys.readouterr()
    rec1 = tmp_path / "r1.jsonl"
    with GrblPty(SimOptions(**QUICK, record=str(rec1))) as booted:
        with pytest.raises(SystemExit) as exc:
            _resume(job, booted.path, "--yes")
    assert exc.value.code != 0
    err = capsys.readouterr().err
    assert "refusing to resume with --yes" in err and "stands at machine zero" in err
    assert "--homed" in err
    assert not _gcode_rx(rec1)  # nothing but queries before the check
    rec2 = tmp_path / "r2.jsonl"
    with GrblPty(SimOptions(**QUICK, record=str(rec2))) as booted:
        _resume(job, booted.path, "--yes", "--homed")
    out = capsys.readouterr()
    assert "--homed: the machine was" in out.err + out.out
    assert "done:" in out.out + out.err
    assert _gcode_rx(rec2)


@pytest.mark.usefixtures("at_a_terminal")  # a person answers
def test_machine_that_rebooted_asks_and_a_no_sends_nothing(tmp_path):
    job, pty, _ = _drop_link(tmp_path)
    pty.close()
    rec = tmp_path / "r1.jsonl"
    with GrblPty(SimOptions(**QUICK, record=str(rec))) as booted:
        code, out, err = _stream([str(job), "--port", booted.path, "--resume"], "n\n")
    assert code == 2
    assert "stands at machine zero" in out + err and "Was the machine" in out + err
    assert "not confirmed; nothing was sent" in err
    assert not _gcode_rx(rec)


def test_controller_that_kept_power_resumes_unasked(tmp_path, capsys):
    """The same controller, still powered, stands where its queue ended (not where the last
    report saw it): no question, under --yes it resumes."""
    job, pty, lost = _drop_link(tmp_path)
    where = _settled(pty)
    pty.close()
    assert max(abs(a - b) for a, b in zip(where, lost["mpos"], strict=True)) > 0.01
    capsys.readouterr()
    rec = tmp_path / "r1.jsonl"
    kept = GrblPty(SimOptions(**QUICK, record=str(rec)))
    kept.sim.mpos = kept.sim._target = kept.sim._gc.position = where  # as it was left
    with kept:
        kept.start()
        _resume(job, kept.path, "--yes")
    out = capsys.readouterr()
    assert "machine zero" not in out.out + out.err
    assert "done:" in out.out + out.err


def test_emulator_after_a_lost_link_warns_and_repeats(tmp_path, capsys):
    """grblsim:// is a fresh controller on every open: it moves nothing, so it warns."""
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    with pytest.raises(SystemExit):
        main(["stream", str(job), "--port", f"{SIM}&disconnect_after=151", "--yes", *COMMON])
    capsys.readouterr()
    _resume(job, SIM, "--yes")
    err = capsys.readouterr().err
    assert "warning: the run before this resume ended with a lost link" in err
    assert "warning (repeated): the run before this resume ended with a lost link" in err


@pytest.mark.parametrize(
    ("was", "now", "steps", "reset"),
    [
        ([10.0, 20.0, -1.0], (0.0, 0.0, 0.0), None, True),
        ([10.0, 20.0, -1.0], (0.0, 0.05, 0.0), None, True),  # two 0.025 mm steps + digit
        ([10.0, 20.0, -1.0], (0.0, 0.06, 0.0), None, False),
        ([10.0, 20.0, -1.0], (0.0, 0.006, 0.0), [0.0025, 0.0025, 0.0025], True),
        ([10.0, 20.0, -1.0], (0.0, 0.007, 0.0), [0.0025, 0.0025, 0.0025], False),
        ([10.0, 20.0, -1.0], (12.0, 20.0, -1.0), None, False),  # ran its queue, kept power
        ([0.0, 0.0, 0.0], (0.0, 0.0, 0.0), None, False),  # stood at zero: tells nothing
        (None, (0.0, 0.0, 0.0), None, False),  # an older journal: no position recorded
    ],
)
def test_reset_since_last_run_bounds(was, now, steps, reset):
    lost = {"ev": "lost", "reason": "x", "executed_through": 3}
    if was is not None:
        lost["mpos"] = was
    events = [{"ev": "start", "steps": steps}, {"ev": "ack", "i": 0}, lost]
    found = reset_since_last_run(events, now)
    assert (found is not None) == reset
    if reset:
        assert found["lost"] is True and found["mpos_now"] == list(now)
    assert reset_since_last_run(events, None) is None


def _without_position(job) -> None:
    """The journal's ``lost`` event without ``mpos`` and ``wco``: as a journal written before
    they were recorded, or a drop before any status report, leaves it."""
    journal = default_journal_path(job)
    events = [json.loads(line) for line in journal.read_text().splitlines()]
    assert events[-1]["ev"] == "lost" and "mpos" in events[-1]
    for key in ("mpos", "wco"):
        events[-1].pop(key)
    journal.write_text("".join(json.dumps(ev) + "\n" for ev in events))


NO_POSITION = "ended with a lost link before any position of the machine was recorded"


@pytest.mark.usefixtures("at_a_terminal")  # a person answers
@pytest.mark.parametrize(
    ("flags", "answers", "refusal"),
    [
        (["--yes"], "", "error: refusing to resume with --yes: "),
        ([], "n\n", "error: not confirmed; nothing was sent: "),
        ([], "y\ny\n", None),  # kept power (or homed), then the usual question
        (["--yes", "--homed"], "", None),
    ],
)
def test_a_drop_with_no_position_recorded_asks_before_connecting(tmp_path, flags, answers, refusal):
    """Whether the controller reset cannot be told without the position it had: asked as
    after a reset, even of one that kept power; nothing is sent before the answer."""
    job, pty, _ = _drop_link(tmp_path)
    where = _settled(pty)
    pty.close()
    _without_position(job)
    rec = tmp_path / "r1.jsonl"
    kept = GrblPty(SimOptions(**QUICK, record=str(rec)))
    kept.sim.mpos = kept.sim._target = kept.sim._gc.position = where  # it kept power
    with kept:
        kept.start()
        code, out, err = _stream([str(job), "--port", kept.path, "--resume", *flags], answers)
    assert "Traceback" not in err
    asked = "Was the machine" in err and "or did its controller keep power" in err
    assert asked == ("--yes" not in flags)
    if refusal is not None:
        assert code == 2
        last = err.rstrip().splitlines()[-1]
        assert last.startswith(refusal) and "--homed" in last
        assert NO_POSITION in last or "--yes" not in flags
        assert not _gcode_rx(rec)  # nothing but the connect's queries, if that
        return
    assert code == 0, err
    assert "done:" in out + err and _gcode_rx(rec)
    if "--homed" in flags:
        note = "note: the run before this resume ended with a lost link, with no position"
        assert note in err


def test_a_drop_with_no_position_recorded_warns_on_the_emulator(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    with pytest.raises(SystemExit):
        main(["stream", str(job), "--port", f"{SIM}&disconnect_after=151", "--yes", *COMMON])
    _without_position(job)
    capsys.readouterr()
    _resume(job, SIM, "--yes")
    err = capsys.readouterr().err
    assert f"warning: the run before this resume {NO_POSITION}" in err
    assert f"warning (repeated): the run before this resume {NO_POSITION}" in err
