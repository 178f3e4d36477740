"""A servo scribe found in Alarm on a machine with homing: unlock, raise it, then home.

``$H`` moves X and Y with the scribe as it stands (homing lifts a Z tool first, never a
servo), and GRBL in Alarm takes no G-code, the up command included: the advice orders the
unlock before the up command and the homing after it, at connect and after a mid-job alarm.
"""

from __future__ import annotations

import pytest
from test_stream_cli_input import _stream
from test_stream_lift import servo_job

from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender import Streamer, StreamOptions

PORT = "grblsim://?baud=0&time_scale=0.02&$22=1"  # homing on: it boots in Alarm
PLOTTER = "grbl-plotter-scribe"


def _in_order(text: str, steps: list[str]) -> None:
    at = [text.find(step) for step in steps]
    assert -1 not in at and at == sorted(at), text


@pytest.mark.parametrize("machine", [PLOTTER, "grbl-3018-diamond"])
def test_the_connect_refusal_orders_unlock_raise_home(tmp_path, machine):
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=3)
    code, _, err = _stream([str(job), "--port", PORT, "--yes", "--machine", machine], "")
    assert code == 3 and "Traceback" not in err
    last = err.rstrip().splitlines()[-1]
    assert last.startswith("error: controller is in Alarm") and "nothing was sent" in last
    profile = load_profile(machine)
    if profile.tool_control.mode == "servo":
        up = profile.tool_control.command("off")
        _in_order(last, ["unlock it ($X)", f"raise the scribe with its up command {up}", "($H)"])
    else:  # a Z tool: homing lifts Z first; an unlock alone leaves Z to jog up
        _in_order(last, ["home it ($H)", "unlock it ($X)", "jog Z up"])


@pytest.mark.parametrize(
    ("lost", "home"),
    [
        (True, "home it ($H) (its position may be lost"),
        (None, "home it ($H) if its position may be lost"),
    ],
)
def test_a_servo_alarm_mid_job_is_told_to_raise_it_before_homing(lost, home):
    streamer = Streamer(None, StreamOptions(profile=load_profile(PLOTTER)))  # type: ignore[arg-type]
    streamer.info.settings[22] = 1.0
    text = streamer._leave_alarm(lost, "home it ($H) or unlock it ($X)")
    up = load_profile(PLOTTER).tool_control.command("off")
    _in_order(text, ["unlock it ($X) yourself", f"its up command {up}", home])
    assert "or unlock it" not in text  # the unlock comes first, always
