"""Check mode's ALARM: worded for the machine's $22 as a streamed alarm is, and the Alarm left.

GRBL checks soft limits even in check mode ($C): ALARM:2 locks it, and the reset that
ends check mode leaves it in Alarm. The check said the alarm's meaning alone, in words
for a machine with homing, and "nothing moved": not that the controller stays locked,
nor how to leave it where homing is off ($22=0: $H answers error:5).
"""

from __future__ import annotations

import pytest
from stream_helpers import FAST

from scratchfab.errors import ScratchfabError
from scratchfab.machine.sender import Streamer, _Fault, open_port
from scratchfab.machine.sender_program import load_program
from scratchfab.machine.stream_job import _check

# X-500 is past the emulator's 200 mm of X travel: GRBL's soft limit, checked in $C
GCODE = "G21G90\nG0Z-1\nG0X-5Y-5\nG1Z-2F100\nG1X-500F600\nG0Z-1\nM2\n"


@pytest.mark.parametrize("homing", [True, False])
def test_a_check_mode_alarm_says_the_controller_stays_locked_and_how_to_leave(tmp_path, homing):
    gcode = tmp_path / "job.gcode"
    gcode.write_text(GCODE)
    program = load_program(gcode)
    port = open_port("grblsim://?baud=0&time_scale=0&soft_limits=1&homed=1", 115200)
    said: list[str] = []
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        if not homing:  # as a $$ that said $22=0 (the emulator's soft limits need it on)
            streamer.info.settings[22] = 0.0
        with pytest.raises(ScratchfabError) as exc:
            _check(streamer, program, gcode, said.append)
    finally:
        port.close()
    assert port.sim.state == "Alarm"  # the reference: the emulator stays locked
    alarm = [line for line in said if "ALARM:2" in line]
    assert len(alarm) == 1 and alarm[0].startswith(f"{gcode}:5: ALARM:2 (soft limit")
    assert alarm[0].endswith("): G1X-500F600")
    message = str(exc.value)
    assert message.startswith(f"{gcode}: check mode found 1 problem(s); nothing moved")
    assert "the controller stays in Alarm: unlock it ($X)" in message
    # homing off: $H is refused (error:5), so the advice never says to home
    assert ("$22=0: $H answers error:5" in message) is not homing
    assert ("$H)" in message) is False
    assert "jog" not in message and "raise" not in message  # check mode moved nothing


def test_a_silent_controller_after_the_check_reset_keeps_the_alarm(tmp_path, monkeypatch):
    """No status report after the reset that follows check mode's ALARM: the ALARM and
    its advice stand, not a "no status report" fault in their place."""
    gcode = tmp_path / "job.gcode"
    gcode.write_text(GCODE)
    program = load_program(gcode)
    port = open_port("grblsim://?baud=0&time_scale=0&soft_limits=1&homed=1", 115200)
    said: list[str] = []
    asked: list[float] = []

    def silent(timeout: float = 2.0):
        asked.append(timeout)
        raise _Fault("no status report from the controller", kind="silent")

    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        monkeypatch.setattr(streamer, "_status_now", silent)
        with pytest.raises(ScratchfabError) as exc:
            _check(streamer, program, gcode, said.append)
    finally:
        port.close()
    assert asked  # the status was asked for, and none came
    assert port.sim.state == "Alarm"
    assert any(line.startswith(f"{gcode}:5: ALARM:2 (soft limit") for line in said), said
    message = str(exc.value)
    assert "no status report" not in message, message
    assert message.startswith(f"{gcode}: check mode found 1 problem(s); nothing moved")
    assert "the controller stays in Alarm: unlock it ($X)" in message, message
