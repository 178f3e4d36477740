"""A soft limit (``ALARM:2``) that GRBL raises while a feed hold still slows the machine.

Grbl 1.1h reads lines while a feed hold decelerates (``Hold:1``: ``sys.suspend`` is only
set once the hold is complete), and ``limits_soft_check`` on a target outside the travel
then calls ``mc_reset`` at once: with ``STEP_CONTROL_EXECUTE_HOLD`` set it kills the
steppers at speed ("position has likely been lost") and only ``ALARM:2`` is reported. In
a cycle it holds first and resets at rest (position kept). The emulator's record says
which (``lost``: the speed it stopped from); the sender must tell the user the same.
"""

from __future__ import annotations

import time

import pytest
from stream_helpers import (
    FAST,
    HeldUntilFeedHold,
    executed_blocks,
    interrupt_after,
    stream_program,
)

from scratchfab.machine.sender import Streamer, StreamFault, StreamStopped, open_port
from scratchfab.machine.sender_journal import read_journal
from scratchfab.machine.sender_program import load_program
from scratchfab.machine.stream_job import _say_lost_position

#: Homed at machine X -1 (``$27``), soft limits on: X travels -200..0. 2 mm moves down X
#: at 20 mm/s fill the planner, so a line waits in the RX buffer for a block to end;
#: block 22 (G1X10) lies outside.
_MOVES = ["G21G90", "G1X-3F1200"] + [f"G1X{-3 - 2 * k}" for k in range(1, 30)]
_JOB = "\n".join([*_MOVES[:22], "G1X10", *_MOVES[22:]]) + "\n"
_URL = "grblsim://?baud=115200&soft_limits=1&homed=1"
_LOST = "position is likely lost, home it ($H)"


def _stream(tmp_path, stop_after: int | None, ask: str = "stop"):
    """Stream the job; a Ctrl-C once more than ``stop_after`` lines are acknowledged
    (None: none), answered ``ask``. The exception, the journal and the emulator's record."""
    job = tmp_path / "job.gcode"
    job.write_text(_JOB)
    progress = interrupt_after(stop_after) if stop_after is not None else None

    inner = open_port(_URL, 115200)
    # the outside line is read only once the sender's hold came, however late
    port = HeldUntilFeedHold(inner, b"G1X10") if stop_after is not None else inner
    try:
        with pytest.raises((StreamStopped, StreamFault)) as exc:
            stream_program(
                port,
                load_program(job),
                tmp_path / "j.jsonl",
                on_progress=progress,
                ask_interrupt=lambda: _answer(ask, inner.sim.record),
            )
    finally:
        port.close()
    return exc.value, read_journal(tmp_path / "j.jsonl"), inner.sim.record


def _answer(ask: str, record: list[dict]) -> str:
    """``ask`` once the emulator has raised its alarm (at most 10 s): the hold slows for
    about 2 s (20 mm/s at GRBL's default 10 mm/s^2), so the alarm comes while the question
    waits, as it would for a person, and not after an instant "resume" on a machine busy
    with other work."""
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and not _alarms(list(record)):
        time.sleep(0.01)
    return ask


def _alarms(record) -> list[dict]:
    return [e for e in record if e["ev"] == "alarm"]


@pytest.mark.parametrize("ask", ["stop", "resume"])
def test_a_soft_limit_read_during_a_slowing_hold_is_told_as_a_lost_position(tmp_path, ask):
    """Ctrl-C holds the machine at speed; the line after the planner's full queue is read
    while it slows down: ALARM:2 at speed. Stopped or resumed, the message says the
    position is likely lost (home it), the journal's alarm says so, and the journal counts
    as run only moves the emulator finished."""
    exc, events, record = _stream(tmp_path, 19, ask)
    (alarm,) = _alarms(record)
    assert alarm["code"] == 2 and alarm["lost"] > 0.0  # the reference: stopped at speed
    assert "ALARM:2" in str(exc) and _LOST in str(exc)
    assert "unlock it ($X)" not in str(exc)
    assert [(e["code"], e.get("lost")) for e in events if e["ev"] == "alarm"] == [(2, True)]
    said: list[str] = []
    _say_lost_position(events, said.append)  # what a later --resume says once connected
    assert len(said) == 1 and "homed ($H) since" in said[0]
    through = events[-1]["executed_through"]
    assert events[-1]["ev"] == "stop" and through < 22
    assert set(range(1, through + 1)) <= executed_blocks(record)  # the moves surely ran


def test_a_soft_limit_read_in_a_cycle_is_not_told_as_surely_lost(tmp_path):
    """Without the sender's hold, GRBL reads the line in the cycle, holds (Hold:1), then
    alarms at rest: the position is kept. The sender cannot tell that hold from one of the
    controller's feed hold button (the same reports): it says the position is kept if
    the hold was GRBL's own, and asks for homing otherwise; the journal's alarm says the
    position is maybe lost, which a later --resume tells (only the last session's)."""
    exc, events, record = _stream(tmp_path, None)
    (alarm,) = _alarms(record)
    assert alarm["code"] == 2 and "lost" not in alarm
    assert any(e["ev"] == "state" and e["state"] == "Hold:1" for e in record)
    assert "ALARM:2" in str(exc) and _LOST not in str(exc)
    assert "position is kept if that was GRBL's own soft-limit hold" in str(exc)
    assert [(e["code"], e.get("lost")) for e in events if e["ev"] == "alarm"] == [(2, "maybe")]
    said: list[str] = []
    _say_lost_position(events, said.append)
    assert len(said) == 1 and "unless you know" not in said[0]
    assert "or you know the hold was GRBL's own" in said[0] and "homed ($H) since" in said[0]
    # an earlier session's alarm is not this run's: only the last session counts
    stop = {"ev": "stop", "reason": "stopped by the user", "mpos": [1.0, 2.0, 0.0]}
    later = [{"ev": "start"}, stop]
    said.clear()
    _say_lost_position([*events, *later], said.append)
    assert said == []


def test_after_the_alarm_at_speed_a_resume_is_refused_until_homed(tmp_path):
    """GRBL keeps its Alarm over the reset (``main``'s prior state): a --resume's connect
    is refused until the machine is homed or unlocked, as after ALARM:3."""
    job = tmp_path / "job.gcode"
    job.write_text(_JOB)
    port = HeldUntilFeedHold(open_port(_URL, 115200), b"G1X10")
    try:
        progress = interrupt_after(19)
        with pytest.raises(StreamStopped):
            stream_program(
                port,
                load_program(job),
                tmp_path / "j.jsonl",
                on_progress=progress,
                ask_interrupt=lambda: "stop",
            )
        with pytest.raises(StreamFault, match=r"controller is in Alarm: home it \(\$H\)"):
            Streamer(port, FAST).connect()
    finally:
        port.close()
    assert _alarms(port.sim.record)[0]["lost"] > 0.0
