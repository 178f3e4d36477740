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


def _plan(job: Path, profile: MachineProfile) -> None:
    """A toolpath.json of one stroke planned for ``profile`` (its statistics kept)."""
    import json

    file = job / "toolpath" / "toolpath.json"
    stats = json.loads(file.read_text())["statistics"]
    x, y = profile.board.offset_mm
    outline = np.array([[x, y], [x + 60, y], [x + 60, y + 40], [x, y + 40]], dtype=np.float64)
    stroke = np.array([[[x + 1, y + 1], [x + 5, y + 5]]], dtype=np.float64)
    Toolpath(stroke, np.zeros(1, np.int64), (60.0, 40.0), outline, profile, stats).save(file)


def _words(fragment: str) -> str:
    return " ".join(html.unescape(re.sub(r"<[^>]+>", "", fragment)).split())


def test_machine_coordinates_profile_says_do_not_zero_on_the_board(tmp_path):
    job = fake_job(tmp_path)
    profile = load_profile("grbl-3018-diamond")
    assert profile.envelope.coordinates == "machine"
    _plan(job, profile)
    step = _words(_setup_step(job))
    assert "do not zero the work coordinates on the board" in step
    assert "G10 L2 P1 X0 Y0 Z0" in step and "G10 L20" not in step
    x, y = profile.board.offset_mm
    assert f"lower-left corner at X {x:g} Y {y:g}" in step
    assert f"Z {profile.z.engrave_mm:g} mm" in step


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
    assert "do not zero" not in step and "G10 L2 P1" not in step
    assert "'lab engraver'" in step
    # The work zero is set where the board lies: its corner gets the profile's offset.
    assert f"upper-right corner and send G10 L20 P1 X{x:g} Y{y:g} there" in step
    assert "G92" in step  # named as the one not to use (a soft reset clears it)
    assert f"Z {profile.z.engrave_mm:g} mm" in step and "G10 L20 P1 Z0 there" in step
    assert f"Z {profile.z.engrave_mm:g} must lie a little below" in step


def test_a_servo_profile_is_not_told_a_z_height(tmp_path):
    job = fake_job(tmp_path)
    profile = load_profile("grbl-plotter-scribe")
    assert profile.envelope.coordinates == "work" and profile.tool_control.mode == "servo"
    _plan(job, profile)
    step = _words(_setup_step(job))
    assert "do not zero" not in step
    assert "lower-left corner and send G10 L20 P1 X20 Y20 there" in step
    assert " Z " not in step and "setup.z" not in _setup_step(job)
    assert profile.tool_control.command("on") in step


def test_the_report_shows_the_work_coordinates_advice(tmp_path):
    job = fake_job(tmp_path)
    _plan(job, load_profile("grbl-plotter-scribe"))
    page = write_report(job, "tiny").read_text()
    steps = re.search(r"<ol data-next='[^']+'>(.*?)</ol>", page)
    assert steps is not None
    assert "do not zero the work coordinates" not in page
    assert "G10 L20 P1 X20 Y20" in _words(steps.group(1))


def test_the_work_zero_command_is_written_as_the_export_writes_numbers(tmp_path):
    """A tiny or long offset gives a command GRBL takes: fixed decimals, no exponent."""
    job = fake_job(tmp_path)
    base = load_profile("grbl-plotter-scribe")
    profile = replace(base, board=replace(base.board, offset_mm=(0.00001, 123.4567891)))
    _plan(job, profile)
    step = _words(_setup_step(job))
    assert "send G10 L20 P1 X0 Y123.457 there" in step, step
    assert "e-05" not in step and "corner at X 0 Y 123.457" in step


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
    assert f"top edge (the design's +y) faces machine {expected} (" in step
    side = {"+Y": "away from you", "-Y": "toward you", "+X": "to your right", "-X": "to your left"}
    assert side[expected] in step and "before you unclamp it" in step
