"""Edges of the machine-safety checks that a mutation review found untested.

Arcs given by one offset only, the 0.01 mm tolerance of the pre-stream comparison, the
G-code grid at the envelope's edge, an unfinished resumed session, the end sequence with a
custom off command, and the rollback of a folder swap.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest
from gcode_interp import interpret
from test_export import random_scratches
from test_stream import _arc_samples, _bench_profile, read_record

from scratchfab.errors import ScratchfabError
from scratchfab.export.gcode import _Grid, gcode_lines
from scratchfab.fileio import atomic_folder, write_text
from scratchfab.machine.profile import load_profile, profile_from_mapping
from scratchfab.machine.sender_checks import compare, job_extent
from scratchfab.machine.sender_journal import Journal, interrupted, read_journal
from scratchfab.machine.sender_program import load_program
from scratchfab.model.design import Board
from scratchfab.toolpath import plan_toolpath

# --------------------------------------------------------------------------- one-offset arcs


@pytest.mark.parametrize(
    ("start", "motion", "end", "words", "ij"),
    [
        ((0.0, 0.0), "G2", (0.0, -20.0), "J-10", (0.0, -10.0)),  # right half, out to X=10
        ((0.0, 0.0), "G3", (0.0, -20.0), "J-10", (0.0, -10.0)),  # left half, out to X=-10
        ((0.0, 38.0), "G2", (10.0, 38.0), "I5", (5.0, 0.0)),  # upper half, up to Y=43
        ((0.0, 38.0), "G3", (10.0, 38.0), "I5", (5.0, 0.0)),  # lower half, down to Y=33
        ((3.0, 1.0), "G2", (3.0, 1.0), "J4", (0.0, 4.0)),  # full circle about (3, 5)
    ],
)
def test_extent_of_an_arc_with_one_offset_matches_sampled_points(
    tmp_path, start, motion, end, words, ij
):
    job = tmp_path / "arc.gcode"
    job.write_text(
        f"G21 G90 G17\nG0 X{start[0]:g} Y{start[1]:g}\n"
        f"{motion} X{end[0]:g} Y{end[1]:g} {words} F100\n"
    )
    (x_lo, y_lo, _), (x_hi, y_hi, _) = job_extent(load_program(job))
    pts = _arc_samples(start, end, motion == "G2", ij=ij)
    assert np.allclose((x_lo, y_lo, x_hi, y_hi), (*pts.min(0), *pts.max(0)), atol=1e-6)


@pytest.mark.parametrize(
    ("start", "arc", "inside"),
    [
        # centre (0, -10), radius 10: reaches X = 10, the envelope's edge
        ("X0 Y0", "G2 X0 Y-20 J-10", True),
        # centre (1, -10): reaches X = 11; both ends at X = 1 lie inside
        ("X1 Y0", "G2 X1 Y-20 J-10", False),
        ("X-1 Y0", "G3 X-1 Y-20 J-10", False),  # centre (-1, -10): reaches X = -11
        ("X1 Y0", "G3 X1 Y-20 J-10", True),  # the other way round: X down to -9
        ("X0 Y38", "G2 X10 Y38 I5", False),  # over the top: Y = 43 > 40
        ("X0 Y38", "G3 X10 Y38 I5", True),  # under: Y down to 33
    ],
)
def test_compare_refuses_a_one_offset_arc_that_bulges_out(tmp_path, start, arc, inside):
    job = tmp_path / "j.gcode"
    job.write_text(f"G21 G90 G17\nG0 Z1\nG0 {start}\n{arc} F100\n")
    refusals = compare({}, None, load_program(job), _bench_profile()).refusals
    if inside:
        assert refusals == []
    else:
        (refusal,) = refusals
        axis = "X" if "J" in arc else "Y"
        assert refusal.startswith(f"{job}:4: the job's {axis} range [")
        assert "leaves the envelope" in refusal


# --------------------------------------------------------------------------- 0.01 mm tolerance


@pytest.mark.parametrize(("over", "accepted"), [(0.005, True), (0.05, False)])
@pytest.mark.parametrize("side", ["lo", "hi"])
def test_profile_envelope_tolerance(tmp_path, over, accepted, side):
    """_bench_profile's X envelope is [-10, 10]: 10.005 passes, 10.05 does not."""
    x = 10.0 + over if side == "hi" else -10.0 - over
    job = tmp_path / "j.gcode"
    job.write_text(f"G21 G90\nG0 X0 Y0\nG0 X{x:.3f}\n")
    refusals = compare({}, None, load_program(job), _bench_profile()).refusals
    if accepted:
        assert refusals == []
    else:
        assert refusals == [
            f"{job}:3: the job's X range [{min(0, x):g}, {max(0, x):g}] mm leaves the envelope "
            "[-10, 10] of machine 'bench'"
        ]


@pytest.mark.parametrize(("over", "accepted"), [(0.005, True), (0.05, False)])
def test_grbl_travel_span_tolerance(tmp_path, over, accepted):
    """$130=20: a job from X0 to X20.005 fits, one to X20.05 does not."""
    job = tmp_path / "j.gcode"
    job.write_text(f"G21 G90\nG0 X0 Y0\nG0 X{20.0 + over:.3f}\n")
    settings = {20: 0, 22: 0, 130: 20.0, 131: 100.0, 132: 50.0}
    refusals = compare(settings, None, load_program(job)).refusals
    if accepted:
        assert refusals == []
    else:
        assert refusals == [
            f"{job}:3: the job spans {20.0 + over:g} mm in X but GRBL's travel is $130=20 mm: "
            "it cannot fit on this machine"
        ]


@pytest.mark.parametrize(("over", "accepted"), [(0.005, True), (0.05, False)])
@pytest.mark.parametrize("side", ["lo", "hi"])
def test_soft_limit_tolerance(tmp_path, over, accepted, side):
    """Soft limits allow -300..0 in machine X; work X = machine X - WCO (-150), so the
    work range is -150..150: 150.005 passes (machine 0.005), 150.05 does not."""
    x = 150.0 + over if side == "hi" else -150.0 - over
    job = tmp_path / "j.gcode"
    job.write_text(f"G21 G90\nG0 X{x:.3f} Y0\n")
    settings = {20: 1, 22: 1, 130: 300.0, 131: 180.0, 132: 45.0}
    refusals = compare(settings, (-150.0, -90.0, -40.0), load_program(job)).refusals
    if accepted:
        assert refusals == []
    else:
        m = x - 150.0
        assert refusals == [
            f"{job}:2: the job's X range is {m:g}..{m:g} mm in machine coordinates (work offset "
            "-150); GRBL soft limits allow -300..0 (ALARM:2)"
        ]


# --------------------------------------------------------------------------- G-code grid


def _edge_profile(decimals: int, x_mm=(-290.0, -0.0004), start=(-0.0004, -10.0)):
    table = load_profile("grbl-3018-diamond").to_table()
    table["envelope"]["x_mm"] = list(x_mm)
    table["envelope"]["coordinates"] = "work"
    table["start_mm"] = list(start)
    table["tool"]["tolerance_mm"] = 0.5  # lets decimals = 0 through the profile's check
    table["gcode"]["decimals"] = decimals
    return profile_from_mapping(table, "<edge>")


@pytest.mark.parametrize("decimals", range(4))
def test_gcode_clamps_to_the_envelope_upper_edge(decimals):
    """Start X -0.0004 rounds to 0, past the edge; the largest grid value inside is -10^-d."""
    profile = _edge_profile(decimals)
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    tp = plan_toolpath(random_scratches(np.random.default_rng(7), 20), board, profile)
    run = interpret("\n".join(gcode_lines(tp, profile)) + "\n")
    assert run.final_position is not None and run.moves
    points = np.array([p for mv in run.moves for p in (mv.start, mv.end)])
    env = profile.envelope
    for k, (lo, hi) in enumerate((env.x_mm, env.y_mm, env.z_mm)):
        assert np.all((points[:, k] >= lo) & (points[:, k] <= hi)), "XYZ"[k]
    # the job starts and ends at the start position, clamped onto the grid inside the edge
    assert run.moves[0].start[:2] == (-(10.0**-decimals), -10.0)
    assert run.final_position[:2] == (-(10.0**-decimals), -10.0)


def test_gcode_refuses_an_axis_with_no_value_on_the_grid():
    """[0.0001, 0.0004] holds no multiple of 0.001."""
    profile = _edge_profile(3, x_mm=(0.0001, 0.0004), start=(0.0002, -10.0))
    with pytest.raises(ScratchfabError, match=r"x_mm \[0\.0001, 0\.0004\] holds no value"):
        _Grid(profile)


# --------------------------------------------------------------------------- journal


def test_a_resumed_session_without_an_end_is_interrupted(tmp_path):
    """start, ack, end, start, ack: the first run finished, the second did not."""
    job = tmp_path / "j.gcode"
    job.write_text("G21 G90\nG0 X0 Y0\nG1 X1 F100\n")
    prog = load_program(job)
    path = tmp_path / "journal.jsonl"
    journal = Journal(path).open()
    journal.start(prog, resume=False)
    journal.write("ack", i=0, line=1)
    journal.write("end", complete=True)
    journal.start(prog, resume=True, start=1)
    journal.write("ack", i=1, line=2)
    journal.close()
    events = read_journal(path)
    assert [ev["ev"] for ev in events] == ["start", "ack", "end", "start", "ack"]
    assert interrupted(events, prog.sha256)
    assert not interrupted(events, "another file")
    assert not interrupted([*events, {"ev": "end", "complete": True}], prog.sha256)


# --------------------------------------------------------------------------- end sequence


@pytest.mark.parametrize("off", ["M5 S0", "S0 M5"])
def test_spindle_job_ends_with_the_custom_off_command_then_travels(rng, off):
    table = load_profile("grbl-3018-diamond").to_table()
    table["tool_control"] = {"mode": "spindle", "on": "M3 S{power}", "off": off, "power": 8000}
    profile = profile_from_mapping(table, "<spindle>")
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    tp = plan_toolpath(random_scratches(rng, 20), board, profile)
    lines = gcode_lines(tp, profile)
    assert lines[-1] == "M2" and lines[-3] == off
    run = interpret("\n".join(lines) + "\n")
    last = run.moves[-1]
    assert last.line_no == len(lines) - 1  # the final travel
    assert not last.spindle
    assert last.end[:2] == tuple(profile.start_mm)
    assert last.start[2] == last.end[2] == profile.z.safe_mm
    assert run.moves[-2].spindle  # it was on until the off command


# --------------------------------------------------------------------------- folder swap


def test_atomic_folder_puts_the_old_folder_back_when_the_swap_fails(tmp_path, monkeypatch):
    target = tmp_path / "stage"
    with atomic_folder(target) as new:
        write_text(new / "a.txt", "old")
    real_replace = os.replace

    def failing(src, dst):
        if Path(src).name.endswith(".tmp") and Path(dst) == target:
            raise OSError(errno.EACCES, os.strerror(errno.EACCES))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(ScratchfabError) as info, atomic_folder(target) as new:
        write_text(new / "a.txt", "new")
    monkeypatch.undo()
    assert str(info.value) == f"{target}: cannot write (Permission denied)"
    assert (target / "a.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stage"]  # no temporaries
    with atomic_folder(target) as new:  # the swap that works leaves no old folder behind
        write_text(new / "a.txt", "new")
    assert (target / "a.txt").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stage"]


# --------------------------------------------------------------------------- refusals name the file


_OUT_AT_5 = "G21 G90\nG0 Z1\nG0 X0 Y0\nG1 X5 F100\nG1 X30 Y-5\nG1 X40\nG0 Z2\n"  # X 30: line 5


@pytest.mark.parametrize(
    ("settings", "wco", "profile", "prefix", "says"),
    [
        ({}, None, True, ":5: ", "X range [0, 40] mm leaves the envelope [-10, 10]"),
        ({130: 20.0}, None, False, ":5: ", "spans 40 mm in X but GRBL's travel is $130=20"),
        ({20: 1, 22: 1, 130: 200.0, 131: 200.0, 132: 200.0}, (-25.0, -50.0, -5.0), False,
         ":5: ", "X range is -25..15 mm in machine coordinates"),
        ({20: 1, 22: 1}, None, False, ": ", "GRBL soft limits are on ($20=1) but the work"),
    ],
)  # fmt: skip
def test_every_refusal_starts_with_the_file_and_the_first_line_too_far(
    tmp_path, settings, wco, profile, prefix, says
):
    """The first line that goes out (line 5), not the extreme one (line 6), is named."""
    job = tmp_path / "j.gcode"
    job.write_text(_OUT_AT_5)
    found = compare(settings, wco, load_program(job), _bench_profile() if profile else None)
    (refusal,) = [r for r in found.refusals if says in r]
    assert refusal.startswith(f"{job}{prefix}")
    assert all(r.startswith(f"{job}:") for r in found.refusals)


def test_a_refusal_on_the_command_line_names_the_file_and_line(tmp_path, capsys):
    """Soft limits on, work X 0 at machine X -25: work X 30 (line 5) is machine X 5."""
    from scratchfab.cli import main

    job = tmp_path / "j.gcode"
    job.write_text(_OUT_AT_5)
    rec = tmp_path / "rec.jsonl"
    port = f"grblsim://?time_scale=0&soft_limits=1&homed=1&wco=-25,-100,-10&record={rec}"
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", port, "--yes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.splitlines()[-1]
    assert err.startswith(f"error: {job}:5: the job's X range is -25..15 mm in machine ")
    assert "(nothing was sent)" in err
    assert not [e for e in read_record(rec) if e["ev"] == "rx" and e["g"]]  # no G-code sent
