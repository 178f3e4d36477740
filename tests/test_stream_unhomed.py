"""A machine with homing on, found where homing never puts it, was unlocked, not homed.

GRBL 1.1 counts a homed machine's space from the home corner down (``-$13x <= MPos <= 0``
whatever ``$23``). A controller with homing on (``$22=1``) that reset boots locked, at
machine zero wherever the tool stood; unlocked (``$X``) and jogged it can stand at a
positive X or Y, or below ``-$13x``: then its machine zero (and the work zero) moved, and
a resume asks as after a reset. Inside that space ``$H`` and ``$X`` with a jog still look
alike; a recorded position outside it (a build homing to machine zero) tells nothing.
"""

from __future__ import annotations

import pytest
from test_stream import write_job
from test_stream_cli_input import _stream
from test_stream_lost_link_reset import _gcode_rx

from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.stream_job import lost_position_warning, reset_since_last_run

QUICK = {"baud": 0, "time_scale": 0.002}
WCO = (-100.0, -100.0, -10.0)  # the job's -32..32 mm lie inside GRBL's -200..0 travel


def _events(ev: str, was: list[float]) -> list[dict]:
    start = {"ev": "start", "homing": True, "steps": [0.01, 0.01, 0.01]}
    return [start, {"ev": "ack", "i": 0}, {"ev": ev, "executed_through": 0, "mpos": was}]


@pytest.mark.parametrize("ev", ["stop", "lost"])
@pytest.mark.parametrize(
    ("was", "now", "travel", "why"),
    [
        ([-120.0, -80.0, -5.0], (-1.0, -1.0, -1.0), (200.0, 200.0), None),  # homed again
        ([-120.0, -80.0, -5.0], (-150.0, -20.0, 0.0), (200.0, 200.0), None),  # inside: alike
        ([-120.0, -80.0, -5.0], (20.0, -30.0, 0.0), (200.0, 200.0), "unhomed"),
        # above 0: a homed machine with soft limits off jogs up to its pull-off (1 mm by
        # default) and a little more before its switch: 2 mm and two steps pass
        ([-120.0, -80.0, -5.0], (-30.0, 2.1, 0.0), (200.0, 200.0), "unhomed"),
        ([-120.0, -80.0, -5.0], (-30.0, 1.9, 0.0), (200.0, 200.0), None),
        ([-120.0, -80.0, -5.0], (-30.0, 0.05, 0.0), (200.0, 200.0), None),
        ([-120.0, -80.0, -5.0], (-30.0, -230.0, 0.0), (200.0, 200.0), "unhomed"),
        # below -$131: 5 mm (its far end's stop) pass
        ([-120.0, -80.0, -5.0], (-30.0, -204.9, 0.0), (200.0, 200.0), None),
        ([-120.0, -80.0, -5.0], (-30.0, -205.1, 0.0), (200.0, 200.0), "unhomed"),
        ([-120.0, -80.0, -5.0], (-30.0, -230.0, 0.0), (None, None), None),  # travel unknown
        ([10.0, 20.0, 0.0], (30.0, 40.0, 0.0), (200.0, 200.0), None),  # homes to zero
    ],
)
def test_a_position_outside_the_homed_space_is_a_reset(ev, was, now, travel, why):
    found = reset_since_last_run(_events(ev, was), now, None, True, travel=travel)
    assert (None if found is None else found["why"]) == why
    # a larger pull-off ($27) widens the margin above 0 by as much
    wide = reset_since_last_run(_events(ev, was), now, None, True, travel=travel, pulloff=3.0)
    above = now[1] > 0.0 and now[0] <= 0.0
    assert (None if wide is None else wide["why"]) == (None if above and now[1] < 4.0 else why)
    # homing off: the stop's "moved" rule as before, the homed space not consulted
    off = reset_since_last_run(_events(ev, was), now, None, False, travel=travel)
    moved = ev == "stop" and abs(now[0] - was[0]) + abs(now[1] - was[1]) > 0.05
    assert (None if off is None else off["why"]) == ("moved" if moved else None)


def test_the_warning_names_the_unlock_and_the_homed_space():
    events = _events("stop", [-120.0, -80.0, -5.0])
    found = reset_since_last_run(events, (20.0, -30.0, 0.0), None, True, travel=(200.0, 200.0))
    text = lost_position_warning([*events, found], None, True)
    assert text is not None
    assert "outside the space homing gives it (MPos X20 Y-30 Z0" in text
    assert "unlocked ($X) and jogged, not homed" in text
    assert "homed ($H)" in text  # what to do: home it


def _stopped(tmp_path):
    """A job stopped by an error on a homed pty controller: (the G-code, the stop event)."""
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    options = SimOptions(**QUICK, wco=WCO, soft_limits=True, homed=True, error_at=151)
    with GrblPty(options) as pty:
        pty.start()
        code, _, err = _stream([str(job), "--port", pty.path, "--yes"], "")
    assert code == 3, err
    events = read_journal(default_journal_path(job))
    assert events[0]["homing"] is True and events[-1]["ev"] == "stop"
    return job, events[-1]


def _unlocked_at(rec, mpos) -> GrblPty:
    """A pty controller with homing on ($22=1, soft limits off) that reset earlier and was
    unlocked ($X) and jogged since: Idle at ``mpos``, its G54 offset kept."""
    pty = GrblPty(SimOptions(**QUICK, wco=WCO, record=str(rec), settings={22: 1}))
    sim = pty.sim
    sim.mpos = sim._target = sim._gc.position = tuple(mpos)

    def unlocked(t: float) -> None:  # powered up earlier; $X since: Idle, not Alarm
        sim._log(t, "power")
        sim._restart(t)

    sim._power_up = unlocked  # type: ignore[method-assign]
    return pty


def _homed_at(rec) -> GrblPty:
    """A pty controller with homing on, homed ($H) since: Idle at MPos -$27."""
    return GrblPty(SimOptions(**QUICK, wco=WCO, record=str(rec), soft_limits=True, homed=True))


@pytest.mark.parametrize("homed", [False, True])
def test_a_resume_on_an_unlocked_machine_is_refused_under_yes(tmp_path, homed):
    job, stop = _stopped(tmp_path)
    assert all(-200.0 < v < 0.0 for v in stop["mpos"][:2])  # inside the homed space
    rec = tmp_path / "r1.jsonl"
    pty = _homed_at(rec) if homed else _unlocked_at(rec, (25.0, -40.0, -2.0))
    with pty:
        pty.start()
        code, out, err = _stream([str(job), "--port", pty.path, "--resume", "--yes"], "")
    if homed:  # $H: inside the homed space, resumed unasked
        assert code == 0, err
        assert "the run before this resume" not in out + err and _gcode_rx(rec)
        return
    assert code == 2 and "Traceback" not in err
    last = err.rstrip().splitlines()[-1]
    assert last.startswith("error: refusing to resume with --yes: the run before this resume")
    assert "outside the space homing gives it" in last and "--homed" in last
    assert not _gcode_rx(rec)
