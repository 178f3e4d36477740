"""On a machine with homing on (``$22=1``) a Z tool left down is raised by homing.

A 3018 owner's walk: after the controller reset itself mid-job the stop said "the tool
was NOT raised (...; jog Z up)", yet the controller boots locked in Alarm, where GRBL
refuses a jog (``error:8``, not Idle) until unlocked, and ``$H`` homes Z first (Grbl's default
``HOMING_CYCLE_0``), raising it. The advice names homing for a Z tool there; a servo
scribe keeps its unlock, up command, homing order (it has no Z for homing to lift).
"""

from __future__ import annotations

import dataclasses
import time

import pytest
from stream_helpers import FAST, stream_program

from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender import HOME_RAISES, StreamFault, open_port
from scratchfab.machine.sender_program import load_program

#: A homed 3018 whose controller resets itself (a brown-out) after its 8th G-code line.
PORT = "grblsim://?baud=0&time_scale=0.02&soft_limits=1&homed=1&$130=300&$131=180&$132=45"
JOB = [
    "G21 G90", "G0 Z-27", "G0 X-250 Y-160", "G1 Z-30.2 F200", "G1 X-240 F600",
    "G1 X-240 Y-150", "G1 X-250 Y-150", "G1 X-250 Y-160", "G0 Z-27", "G0 X-200 Y-160",
    "G1 Z-30.2 F200", "G1 X-190 F600", "G0 Z-27", "M2",
]  # fmt: skip
#: The same for a servo scribe: M3 lowers it, M5 lifts it.
SERVO = [
    "G21 G90", "M5", "G1 X-250 Y-160 F3000", "M3 S60", "G4 P0.1", "G1 X-240 F600",
    "G1 X-240 Y-150", "G1 X-250 Y-150", "M5", "G4 P0.1", "G1 X-200 Y-160 F3000", "M3 S60",
    "G1 X-190 F600", "M5", "M2",
]  # fmt: skip


def _answers(port, line: str) -> list[str]:
    """What the emulator answers to ``line`` within a second."""
    port.write(line.encode() + b"\n")
    said: list[str] = []
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline and not any(s == "ok" or s.startswith("error") for s in said):
        said += [s for s in port.read(4096).decode(errors="replace").splitlines() if s]
    return said


@pytest.mark.parametrize("machine", ["grbl-3018-diamond", "grbl-plotter-scribe"])
def test_a_reset_on_a_homing_machine_says_how_the_tool_is_raised(tmp_path, machine):
    profile = load_profile(machine)
    job = tmp_path / "job.gcode"
    if profile.tool_control.mode == "servo":
        job.write_text("\n".join(SERVO) + "\n")
    else:
        job.write_text("\n".join(JOB) + "\n")
    url = f"{PORT}&reset_after=8"
    port = open_port(url, 115200)
    options = dataclasses.replace(FAST, profile=profile, lift=True)
    try:
        with pytest.raises(StreamFault) as exc:
            stream_program(port, load_program(job), tmp_path / "journal", options)
        message = str(exc.value)
        # the reference: the emulator rebooted locked, and refuses a jog until unlocked
        # (Grbl 1.1 runs $J only in Idle or Jog: error:8)
        assert port.sim.state == "Alarm"
        assert _answers(port, "$J=G91 Z5 F100") == ["error:8"], port.sim.state
    finally:
        port.close()
    assert "the controller reset itself mid-job" in message and "NOT raised" in message
    assert "jog Z up" not in message, message
    if profile.tool_control.mode == "servo":
        up = profile.tool_control.command("off")
        at = [message.find(s) for s in ("unlock it ($X)", f"its up command {up}", "($H)")]
        assert -1 not in at and at == sorted(at), message
    else:
        assert HOME_RAISES in message, message


def test_a_controller_found_in_alarm_with_a_z_tool_is_told_homing_raises_it(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("\n".join(JOB) + "\n")
    port = open_port("grblsim://?baud=0&time_scale=0.02&$22=1", 115200)  # boots in Alarm
    options = dataclasses.replace(FAST, profile=load_profile("grbl-3018-diamond"))
    try:
        with pytest.raises(StreamFault) as exc:
            stream_program(port, load_program(job), tmp_path / "journal", options)
        assert port.sim.state == "Alarm" and not any(
            e["ev"] == "rx" and e["g"] for e in port.sim.record
        )  # nothing was sent
    finally:
        port.close()
    message = str(exc.value)
    assert message.startswith("controller is in Alarm: ") and HOME_RAISES in message, message
    # an unlock leaves the tool where it is: then (and only then) a jog raises it
    assert message.index(HOME_RAISES) < message.index("unlock it ($X), then jog Z up"), message
