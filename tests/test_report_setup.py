"""report.html's set-up step: the advice follows the profile the toolpath was planned with."""

from __future__ import annotations

import html
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_report import fake_job

from scratchfab.machine.profile import MachineProfile, load_profile
from scratchfab.pipeline.report import _setup_step, write_report
from scratchfab.toolpath import Toolpath


def _plan(job: Path, profile: MachineProfile, board_mm: tuple[float, float] = (60.0, 40.0)) -> None:
    """A toolpath.json of one stroke planned for ``profile`` (its statistics kept)."""
    import json

    file = job / "toolpath" / "toolpath.json"
    stats = json.loads(file.read_text())["statistics"]
    x, y = profile.board.offset_mm
    outline = np.array([[x, y], [x + 60, y], [x + 60, y + 40], [x, y + 40]], dtype=np.float64)
    stroke = np.array([[[x + 1, y + 1], [x + 5, y + 5]]], dtype=np.float64)
    Toolpath(stroke, np.zeros(1, np.int64), board_mm, outline, profile, stats).save(file)


def _words(fragment: str) -> str:
    return " ".join(html.unescape(re.sub(r"<[^>]+>", "", fragment)).split())


def test_machine_coordinates_profile_says_do_not_zero_on_the_board(tmp_path):
    job = fake_job(tmp_path)
    profile = load_profile("grbl-3018-diamond")
    assert profile.envelope.coordinates == "machine"
    _plan(job, profile)
    step = _words(_setup_step(job))
    assert "do not zero the work coordinates on the board" in step
    # the work system in use (P0), as stream's refusal says to clear it
    assert "G10 L2 P0 X0 Y0 Z0 for the work system in use, G92.1, G49" in step
    assert "G10 L20" not in step and "P1" not in step
    x, y = profile.board.offset_mm
    assert "board's corner at machine -X -Y (front left where machine +Y runs away" in step
    assert f"the picture's bottom-left corner) at X {x:g} Y {y:g}" in step
    assert f"Z {profile.z.engrave_mm:g} mm" in step
    # the travel height, which the first move from home runs at too (a 3018 owner's clamps)
    assert f"travelling at Z {profile.z.safe_mm:g} mm (every travel, the first one" in step
    assert "clamps and anything else on the bed must lie lower" in step


def test_work_coordinates_profile_is_told_to_set_the_zero_on_the_board(tmp_path):
    job = fake_job(tmp_path)
    base = load_profile("grbl-3018-diamond")
    profile = replace(
        base,
        name="lab engraver",
        envelope=replace(base.envelope, coordinates="work"),
        board=replace(base.board, origin="upper-right"),
    )
    _plan(job, profile)
    step = _words(_setup_step(job))
    x, y = profile.board.offset_mm
    assert "do not zero" not in step and "G10 L2 " not in step
    assert "'lab engraver'" in step
    # The work zero is set where the board lies: its corner gets the profile's offset.
    assert "board's corner at machine +X +Y (back right where machine +Y runs away" in step
    assert f"Jog the tool to the board's +X +Y corner and send G10 L20 P0 X{x:g} Y{y:g} " in step
    assert "in the work system in use, P0, which the G-code runs in" in step
    assert "G92" in step  # named as the one not to use (a soft reset clears it)
    assert f"Z {profile.z.engrave_mm:g} mm" in step and "G10 L20 P0 Z0 there" in step
    assert f"Z {profile.z.engrave_mm:g} must lie a little below" in step


def test_a_servo_profile_is_not_told_a_z_height(tmp_path):
    job = fake_job(tmp_path)
    profile = load_profile("grbl-plotter-scribe")
    assert profile.envelope.coordinates == "work" and profile.tool_control.mode == "servo"
    _plan(job, profile)
    step = _words(_setup_step(job))
    assert "do not zero" not in step
    assert "-X -Y corner and send G10 L20 P0 X20 Y20 there" in step
    assert " Z " not in step and "setup.z" not in _setup_step(job)
    assert profile.tool_control.command("on") in step


def test_the_report_shows_the_work_coordinates_advice(tmp_path):
    job = fake_job(tmp_path)
    _plan(job, load_profile("grbl-plotter-scribe"))
    page = write_report(job, "tiny").read_text()
    steps = re.search(r"<ol data-next='[^']+'>(.*?)</ol>", page)
    assert steps is not None
    assert "do not zero the work coordinates" not in page
    assert "G10 L20 P0 X20 Y20" in _words(steps.group(1))


def test_the_work_zero_command_is_written_as_the_export_writes_numbers(tmp_path):
    """A tiny or long offset gives a command GRBL takes: fixed decimals, no exponent."""
    job = fake_job(tmp_path)
    base = load_profile("grbl-plotter-scribe")
    profile = replace(base, board=replace(base.board, offset_mm=(0.00001, 123.4567891)))
    _plan(job, profile)
    step = _words(_setup_step(job))
    assert "send G10 L20 P0 X0 Y123.457 there" in step, step
    assert "e-05" not in step and "corner) at X 0 Y 123.457" in step


@pytest.mark.parametrize("rotation", [0, 90, 180, 270])
def test_the_set_up_step_says_which_way_the_boards_top_edge_faces(tmp_path, rotation):
    """The views hold with the board's top edge up: the step says where it lies to mark it."""
    job = fake_job(tmp_path)
    base = load_profile("grbl-plotter-scribe")
    profile = replace(base, board=replace(base.board, rotation_deg=rotation))
    _plan(job, profile)
    # Independently: where the board's top-edge midpoint lands from its centre.
    centre, top = profile.board_to_machine(np.array([[0.0, 0.0], [0.0, 20.0]]), (60.0, 40.0))
    dx, dy = np.round(top - centre).astype(int)
    axis = "X" if dx else "Y"
    expected = ("+" if (dx or dy) > 0 else "-") + axis
    step = _words(_setup_step(job))
    assert f"top edge (the picture's top, the design's +y) faces machine {expected} (" in step
    side = {"+Y": "away from you", "-Y": "toward you", "+X": "to your right", "-X": "to your left"}
    assert side[expected] in step and "before you unclamp it" in step
    # Said as the machine's axis, with the way to check it on one's own machine.
    assert f"the way the tool moves over the bed when you jog {expected}: " in step


#: Where the [board] origin corner lies on the machine, from its front (+Y away).
_FROM_FRONT = {"lower": "front", "upper": "back"}


@pytest.mark.parametrize("rotation", [0, 90, 180, 270])
@pytest.mark.parametrize("origin", ["lower-left", "lower-right", "upper-left", "upper-right"])
def test_the_origin_corner_is_named_on_the_machine_and_on_the_picture(tmp_path, rotation, origin):
    """On a turned board the profile's origin corner is the outline's corner on the
    machine, not the picture's: the step names both, for every rotation and corner."""
    job = fake_job(tmp_path)
    base = load_profile("grbl-plotter-scribe")
    profile = replace(base, board=replace(base.board, rotation_deg=rotation, origin=origin))
    _plan(job, profile, (60.0, 40.0))
    # Independently: turn the picture's corners counter-clockwise by the rotation and take
    # the one on the machine's side named by the origin (a 60 x 40 board: no ties).
    vertical, horizontal = origin.split("-")
    want = np.array([1 if horizontal == "right" else -1, 1 if vertical == "upper" else -1])
    a = np.radians(rotation)
    turn = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    picture = None
    for top in ("bottom", "top"):
        for left in ("left", "right"):
            corner = np.array([30.0 if left == "right" else -30.0, 20.0 if top == "top" else -20.0])
            if (np.sign(np.round(turn @ corner, 9)) == want).all():
                picture = f"{top}-{left}"
    assert picture is not None
    axes = f"{'+' if want[0] > 0 else '-'}X {'+' if want[1] > 0 else '-'}Y"
    step = _words(_setup_step(job))
    x, y = profile.board.offset_mm
    seen = f"{_FROM_FRONT[vertical]} {horizontal}"
    turned = f", the board being turned {rotation}°" if rotation else ""
    assert (
        f"the board's corner at machine {axes} ({seen} where machine +Y runs away from you, "
        f"as on most desktop engravers; the picture's {picture} corner{turned}) at X {x:g} "
        f"Y {y:g}" in step
    ), step
    assert f"Jog the tool to the board's {axes} corner and send G10 L20 P0 X{x:g} Y{y:g}" in step
    assert "lower-left" not in step and "upper-right" not in step


def test_a_centred_board_is_set_at_its_centre(tmp_path):
    job = fake_job(tmp_path)
    base = load_profile("grbl-plotter-scribe")
    profile = replace(base, board=replace(base.board, rotation_deg=90, origin="center"))
    _plan(job, profile)
    step = _words(_setup_step(job))
    x, y = profile.board.offset_mm
    assert f"the board's centre at X {x:g} Y {y:g}" in step
    assert f"Jog the tool to the board's centre and send G10 L20 P0 X{x:g} Y{y:g}" in step
    assert "corner" not in step


@pytest.mark.parametrize(
    ("offset", "shift"),
    [
        ((20.0, 20.0), "20 mm +X and 20 mm +Y"),
        ((0.00001, 123.4567891), "123.457 mm +Y"),
        ((-10.5, 0.0), "10.5 mm -X"),
        ((0.0, 0.0), None),
    ],
)
def test_the_set_up_step_cannot_be_read_as_zeroing_on_the_board(tmp_path, offset, shift):
    """A plotter owner zeroed X0 Y0 at the board's corner: the step names the corner with
    its numbers and says where a zero there moves the cuts (by the offset, each axis)."""
    job = fake_job(tmp_path)
    base = load_profile("grbl-plotter-scribe")
    profile = replace(base, board=replace(base.board, offset_mm=offset))
    _plan(job, profile)
    step = _words(_setup_step(job))
    x, y = (f"{round(v, 3):g}" for v in offset)  # as the G-code writes them (3 decimals)
    assert f"send G10 L20 P0 X{x} Y{y} there" in step
    if shift is None:  # the corner is X0 Y0: nothing to warn of
        assert "not X0 Y0" not in step and "G10 L20 P0 X0 Y0 there." in step
    else:
        said = (
            f"there: the board's -X -Y corner is X {x} Y {y} in the G-code, not X0 Y0 "
            f"(zeroing X and Y there, with G10 L20 P0 X0 Y0, would move every cut {shift} "
            "from where the design puts it)."
        )
        assert said in step, step


def test_the_report_gives_the_command_stream_sends_at_the_profile_s_decimals(tmp_path):
    """The set-up step's numbers and command are the ones ``stream --zero-here`` sends
    (one formatter of the work offset): at 2 decimals, no ``-0`` for a tiny negative."""
    from scratchfab.machine.stream_job import zero_here_command

    job = fake_job(tmp_path)
    base = load_profile("grbl-plotter-scribe")
    profile = replace(
        base,
        board=replace(base.board, offset_mm=(-0.001, 12.3456)),
        gcode=replace(base.gcode, decimals=2),
    )
    _plan(job, profile)
    step = _words(_setup_step(job))
    assert zero_here_command(profile)[1] == "G10 L20 P0 X0 Y12.35"  # by hand: 2 decimals
    assert "send G10 L20 P0 X0 Y12.35 there" in step, step
    assert "corner) at X 0 Y 12.35," in step and "X -0" not in step
