"""The advice after a lost position names the exact zeroing command and a servo's up command.

A plotter owner (no homing, servo scribe, the bundled plotter profile: its board's
lower-left corner at offset (20, 20)) read "set the work zero again on the board's origin"
and sent ``G10 L20 P0 X0 Y0`` at the board's corner: the job landed 20 mm off. With a
profile known the advice names the command as the G-code writes the numbers; without
one, the words stay. And "the tool was NOT raised (... jog Z up)" after a reset told a
servo plotter, which has no Z, to jog it.
"""

from __future__ import annotations

import dataclasses
import math

import pytest
from stream_helpers import FAST, stream_program
from test_stream_cli_input import _stream
from test_stream_lift import servo_job

from scratchfab.machine.grbl_codes import alarm_meaning
from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender import (
    StreamFault,
    open_port,
    refind,
    work_zero_command,
    zero_kept_advice,
)
from scratchfab.machine.sender_program import load_program

PORT = "grblsim://?baud=0&time_scale=0.02"
LIFT = dataclasses.replace(FAST, lift=True)


def _placed(offset, origin="lower-left", decimals=3):
    plotter = load_profile("grbl-plotter-scribe")
    board = dataclasses.replace(plotter.board, offset_mm=offset, origin=origin)
    gcode = dataclasses.replace(plotter.gcode, decimals=decimals)
    return dataclasses.replace(plotter, board=board, gcode=gcode)


@pytest.mark.parametrize(
    ("offset", "origin", "decimals", "command", "point"),
    [
        ((20.0, 20.0), "lower-left", 3, "G10 L20 P0 X20 Y20", "lower-left corner"),
        ((12.5, -3.25), "upper-right", 3, "G10 L20 P0 X12.5 Y-3.25", "upper-right corner"),
        ((1.23456, 0.0), "center", 2, "G10 L20 P0 X1.23 Y0", "centre"),
    ],
)
@pytest.mark.parametrize("homing", [False, None])
def test_a_known_profile_names_the_command_at_the_boards_origin(
    offset, origin, decimals, command, point, homing
):
    how = refind(_placed(offset, origin, decimals), homing)
    assert f"jog to the board's {point} and send `{command}` there" in how.do
    assert f"jog to the board's {point} and send `{command}` there" in how.again
    assert f"(`{command}` at the board's {point})" in how.done
    assert "X0 Y0" not in how.do + how.done


def test_no_profile_keeps_the_words():
    how = refind(None, False)
    assert "set the work zero again on the board's origin" in how.do
    assert "G10" not in how.do + how.done


def _reset_servo_job(tmp_path, machine):
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=6)
    args = [str(job), "--port", f"{PORT}&reset_after=12", "--yes"]
    return _stream(args + (["--machine", machine] if machine else []), "")


@pytest.mark.parametrize("machine", ["grbl-plotter-scribe", None])
def test_a_servo_job_after_a_reset_is_told_its_up_command_not_to_jog_z(tmp_path, machine):
    """The bundled plotter's up command is its [tool_control] off; a foreign plotter file
    (M3 lowers, M5 lifts) is told M5."""
    code, _, err = _reset_servo_job(tmp_path, machine)
    assert code == 3, err
    up = load_profile(machine).tool_control.off if machine else "M5"
    assert "the tool was NOT raised (the controller reset itself" in err
    assert f"raise the scribe with its up command {up}" in err
    assert "jog Z up" not in err


def test_an_alarm_at_speed_names_re_zero_where_homing_is_off(tmp_path):
    """ALARM:3 (a reset while the machine moves, here one the sender did not send) said
    "re-home" on a machine without homing ($22=0), where $H answers error:5."""

    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z2\n" + "".join(f"G1 X{k} Y{k % 3} F300\n" for k in range(40)))
    port = open_port("grblsim://?baud=0&time_scale=0.05&$22=0", 115200)
    sent: list[int] = []

    def reset_mid_move(p):
        if p.acked > 5 and p.state.startswith("Run") and not sent:
            sent.append(1)
            port.write(b"\x18")

    try:
        with pytest.raises(StreamFault) as exc:
            stream_program(
                port, load_program(job), tmp_path / "j.jsonl", LIFT, on_progress=reset_mid_move
            )
    finally:
        port.close()
    text = str(exc.value)
    assert "ALARM:3 (reset while in motion; position is likely lost, re-zero)" in text, text
    assert "re-home" not in text and "($H)" not in text  # "$H answers error:5" told
    assert alarm_meaning(3).endswith("likely lost, re-home")  # $22 not known: as before
    # the tool raised before the move to the board's origin, not dragged there
    steps = ["unlock it ($X)", "jog Z up", "set the work zero again on the board's origin"]
    at = [text.find(step) for step in steps]
    assert -1 not in at and at == sorted(at), text


PLOTTER_GRBL = "$110=5000&$111=5000&$112=400&$120=500&$121=500&$122=10&$130=300&$131=200"


@pytest.mark.parametrize("z_moves", [False, True])
def test_a_job_that_never_moves_z_is_not_warned_of_grbls_z_settings(tmp_path, z_moves):
    """A servo plotter's GRBL keeps a slow Z ($112, $122): no Z move, no warning. A job with
    Z moves on the same controller is warned. And a work-coordinate profile, which counts
    from the work zero set on the board, is not told on every stream that homing is off."""
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=3)
    if z_moves:
        text = job.read_text().replace("M3 S60", "G1 Z-0.5 F100\nM3 S60")
        job.write_text(text.replace("M5\nG4", "G0 Z0.5\nM5\nG4"))
    port = f"{PORT}&{PLOTTER_GRBL}"
    code, _, err = _stream(
        [str(job), "--port", port, "--yes", "--machine", "grbl-plotter-scribe"], ""
    )
    assert code == 0, err
    z_warnings = [line for line in err.splitlines() if "$112=" in line or "$122=" in line]
    assert len(z_warnings) == (2 if z_moves else 0), z_warnings
    assert "homing is off" not in err
    code, _, err = _stream([str(job), "--port", port, "--yes"], "")  # no profile: said
    assert code == 0 and "GRBL homing is off ($22=0)" in err


def test_a_drop_during_check_mode_says_nothing_was_cut(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\n" + "".join(f"G1 X{k} Y1 F300\n" for k in range(30)) + "M2\n")
    code, _, err = _stream([str(job), "--port", f"{PORT}&disconnect_after=10", "--check"], "")
    assert code == 3, err
    error = next(line for line in err.splitlines() if line.startswith("error: "))
    assert error.startswith("error: connection lost") and "nothing was cut (check mode)" in error


@pytest.mark.parametrize("name", ["grbl-plotter-scribe", None])
def test_a_cleared_g92_zero_is_set_again_with_the_profiles_command(tmp_path, name):
    """The resume's refusal where a reset cleared the run's G92 zero names the command."""
    from scratchfab.errors import ScratchfabError
    from scratchfab.machine.stream_job import _check_same_zero

    events = [{"ev": "start", "wco": [25.0, 25.0, 0.0], "g92": [5.0, 5.0, 0.0]}]
    profile = None if name is None else load_profile(name)
    with pytest.raises(ScratchfabError) as exc:
        _check_same_zero(events, (20.0, 20.0, 0.0), None, tmp_path / "j", print, False, profile)
    text = str(exc.value)
    # first the earlier offset itself (the machine position kept), in GRBL's words
    assert "set the same zero again with `G21 G10 L2 P0 X25 Y25 Z0` (the earlier" in text
    if name is None:  # the G-code's origin, with the axis words G10 needs
        assert "`G10 L20 P0 X0 Y0 Z0` there (P0: the work system in use" in text
    else:
        assert (
            "else set the same zero again: jog to the board's lower-left corner and send " in text
        )
        assert "`G10 L20 P0 X20 Y20` there (P0: the work system in use; a reset keeps it" in text


def test_a_long_check_mode_shows_its_progress(tmp_path, monkeypatch):
    monkeypatch.setattr("scratchfab.machine.sender.CHECK_QUIET_S", 0.0)
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\n" + "".join(f"G1 X{k % 50} Y1 F300\n" for k in range(99)) + "M2\n")
    code, _, err = _stream([str(job), "--port", PORT, "--check", "--yes"], "")
    assert code == 0, err
    shown = [line for line in err.splitlines() if line.startswith("check mode: ")]
    assert [line.split(" lines")[0] for line in shown] == [
        # the first count that reaches each tenth of the 101 lines
        *(f"check mode: {10 * t}% {math.ceil(t * 101 / 10)}/101" for t in range(1, 10)),
        "check mode: 101",
    ]


def test_a_foreign_file_held_up_by_s_is_lifted_with_its_own_up_command(tmp_path):
    """Without a profile the lift after a stop is the file's own up state (M3 S90 here),
    not M5, which a reset has done and which leaves such a servo where PWM 0 puts it."""
    from test_stream_servo_lift import export_job, servo_profile

    job, _ = export_job(tmp_path, servo_profile(tmp_path), n=12)
    prog = load_program(job)  # no profile: the up state read from the file
    assert prog.pen_mode and prog.tool_up == "M3S90"
    said: list[str] = []
    port = open_port(f"{PORT}&error_at=40&record={tmp_path / 'rec.jsonl'}", 115200)
    try:
        with pytest.raises(StreamFault) as exc:
            stream_program(port, prog, tmp_path / "j.jsonl", LIFT, on_message=said.append)
    finally:
        port.close()
    assert "raising the scribe with the file's up command 'M3S90'" in said, said
    assert "scribe raised (M3S90)" in str(exc.value)
    spindle = [e for e in port.sim.record if e["ev"] == "spindle"]
    assert (spindle[-1]["spindle"], spindle[-1]["s"]) == ("M3", 90.0)  # up, as the file holds it


def test_a_lost_alarm_where_homing_is_off_raises_the_tool_before_the_zero(tmp_path):
    """A controller found in Alarm mid-job (its ALARM message lost on the line): where
    homing is off ($22=0, as the connect's $$ would say) every advice in the stop's
    message unlocks, raises the tool, then sets the work zero again, in that order."""
    import re
    import time

    from test_stream import _Deaf, write_job

    from scratchfab.machine.sender import Streamer
    from scratchfab.machine.sender_journal import Journal

    job = tmp_path / "job.gcode"
    write_job(job, 30)
    url = "grblsim://?baud=0&time_scale=0.01&soft_limits=1&homed=1&wco=-100,-100,-10&reset_after=60"
    port = open_port(url, 115200)
    streamer = Streamer(port, LIFT)
    streamer.connect()
    streamer.info.settings[22] = 0.0  # the advice words follow $22 as read at connect
    streamer.port = _Deaf(port)
    j = Journal(tmp_path / "j.jsonl").open()
    t0 = time.monotonic()
    try:
        with pytest.raises(StreamFault) as exc:
            streamer.stream(load_program(job), j)
    finally:
        j.close()
        port.close()
    assert time.monotonic() - t0 < 20
    text = str(exc.value)
    assert "so the controller is in Alarm" in text or "reports Alarm after line" in text, text
    advice = [m.start() for m in re.finditer(r"unlock it \(\$X\)", text)]
    assert len(advice) == 2, text  # the fault's and the stop's
    for at in advice:
        rest = text[at:]
        raised, zeroed = rest.find("jog Z up"), rest.find("set the work zero again")
        assert 0 < raised < zeroed, text
    assert "home it ($H)" not in text


def _z_tool_in_work_coordinates():
    diamond = load_profile("grbl-3018-diamond")
    envelope = dataclasses.replace(diamond.envelope, coordinates="work")
    return dataclasses.replace(diamond, envelope=envelope)


@pytest.mark.parametrize("homing", [False, None])
def test_a_z_tool_is_told_to_zero_z_on_the_boards_surface(homing):
    """A work-coordinate profile with a Z tool counts its [z] heights from the board's
    surface: the re-zero advice sets Z there too, after X and Y; a servo's has no Z step."""
    profile = _z_tool_in_work_coordinates()
    assert profile.tool_control.mode == "z"
    point, command = work_zero_command(profile)
    how = refind(profile, homing)
    for text in (how.do, how.again, zero_kept_advice(profile)):
        steps = [f"send `{command}`", "board's surface", "`G10 L20 P0 Z0`"]
        at = [text.find(step) for step in steps]
        assert -1 not in at and at == sorted(at), text
    assert f"(`{command}` at the board's {point}) and Z on the board's surface" in how.done
    servo = refind(_placed((20.0, 20.0)), homing)
    assert "Z0" not in servo.do + servo.again + servo.done
