"""A servo scribe held up by ``M3 S<up>`` (not M5): its strokes, resume and lift.

Many hobby servo plotters hold the pen up with a non-zero S. Exported from a copy of the
bundled plotter profile whose ``off`` is ``M3 S90``, a job must stream, stop and resume at
the stroke it stopped in, as the same job with ``off = "M5"`` does.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import pytest
from stream_helpers import FAST
from test_stream import _profile_job

from scratchfab.cli import main
from scratchfab.errors import ConfigError
from scratchfab.machine.profile import find_bundled, load_profile
from scratchfab.machine.sender import StreamOptions
from scratchfab.machine.sender_program import (
    check_tool_up_at_end,
    load_program,
    resume_point,
    resume_preamble,
)

UP, DOWN = 90.0, 35.0
SIM = "grblsim://?baud=0&time_scale=0.002&$130=300&$131=200"


@pytest.fixture(autouse=True)
def _short_banner_settle(monkeypatch):
    """The emulator sends a banner's messages with it: read on 0.02 s, as ``FAST`` does."""
    monkeypatch.setattr(
        "scratchfab.machine.stream_job.StreamOptions",
        functools.partial(StreamOptions, banner_settle=FAST.banner_settle),
    )


def servo_profile(tmp_path: Path, off: str = f"M3 S{UP:g}") -> Path:
    """The bundled plotter profile copied as a maker would: ``off`` and power changed."""
    text = find_bundled("machine_profiles", "grbl-plotter-scribe", "machine").read_text()
    assert 'off = "M5"' in text and "power = 60.0" in text
    text = text.replace('off = "M5"', f'off = "{off}"').replace("power = 60.0", f"power = {DOWN}")
    path = tmp_path / "servo.toml"
    path.write_text(text)
    return path


def export_job(tmp_path: Path, profile_path: Path, n: int = 12, seed: int = 5, travel=True):
    """G-code from the exporter for ``n`` random strokes; returns (path, strokes array)."""
    profile = load_profile(profile_path)
    if not travel:  # travel with G0 instead of G1 at the travel feed
        from dataclasses import replace

        profile = replace(profile, feeds=replace(profile.feeds, travel_mm_min=None))
    box = ((30.0, 30.0), (150.0, 120.0))
    path, tp = _profile_job(tmp_path, profile, n, seed, box=box, stem=f"job-{seed}")
    return path, tp.strokes


def read_record(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def scratch_counts(records: list[list[dict]], strokes: np.ndarray) -> list[int]:
    """How often each stroke was drawn from its start to its end with the scribe down.

    The emulator's record in order: a spindle change acts only once the planner is empty
    (every move before it has been logged), so the S in force at a move's ``exec`` is the
    last ``spindle`` event before it. Down: M3 at the profile's power.
    """
    counts = [0] * len(strokes)
    keys = {tuple(np.round(s.ravel(), 3)): k for k, s in enumerate(strokes)}
    for rec in records:
        spindle, s = "M5", 0.0
        for e in rec:
            if e["ev"] == "spindle":
                spindle, s = e["spindle"], e["s"]
            elif e["ev"] == "exec" and spindle == "M3" and s == DOWN:
                key = tuple(round(v, 3) for v in (*e["frm"][:2], *e["to"][:2]))
                if key in keys:
                    counts[keys[key]] += 1
    return counts


def cut_blocks(prog, strokes: np.ndarray) -> list[int]:
    """The block index of each stroke's cutting move (G1 to its end under S``DOWN``)."""
    out = []
    for s in strokes:
        end = tuple(np.round(s[1], 3))
        out.append(
            next(
                b.index
                for b in prog.blocks
                if b.motion and b.modal.speed == DOWN and (b.modal.x, b.modal.y) == end
            )
        )
    return out


@pytest.mark.parametrize("travel", [True, False], ids=["g1-travel", "g0-travel"])
def test_an_s_lift_jobs_strokes_are_its_cuts(tmp_path, travel):
    """One stroke per toolpath stroke, holding its cut and no travel, read from the file."""
    path, strokes = export_job(tmp_path, servo_profile(tmp_path), travel=travel)
    prog = load_program(path)
    assert prog.pen_mode and len(prog.strokes) == len(strokes)
    cuts = cut_blocks(prog, strokes)
    for (first, last), cut in zip(prog.strokes, cuts, strict=True):
        assert first < cut < last
        inside = prog.blocks[first : last + 1]
        moves = [b for b in inside if b.motion]
        assert [b.index for b in moves] == [cut]  # the cut only: no travel inside
        assert prog.blocks[first].modal.speed == DOWN  # lowered here ...
        assert prog.blocks[last].modal.speed == UP  # ... lifted here
    check_tool_up_at_end(prog)


def test_an_s_lift_job_resumes_at_the_stroke_it_stopped_in(tmp_path):
    """The preamble lifts with the file's own up command (not M5), travels as the file
    does (G1 at its travel feed) to the stroke's start, with the servo's dwell."""
    profile_path = servo_profile(tmp_path)
    path, strokes = export_job(tmp_path, profile_path)
    prog = load_program(path)
    cuts = cut_blocks(prog, strokes)
    k = 5
    start = resume_point(prog, set(range(cuts[k])))  # stopped before stroke 5's cut ended
    assert start == prog.strokes[k][0]
    pre = resume_preamble(prog, start)
    travel = load_profile(profile_path).feeds.travel_mm_min
    x, y = strokes[k, 0]
    assert pre[1:4] == [f"M3S{UP:g}", "G4P0.15", "M9"]
    assert pre[4] == f"G1F{travel:g}X{x:g}Y{y:g}"
    assert not any(t.startswith("M5") for t in pre)


def test_an_s_lift_job_cut_short_is_refused(tmp_path):
    path, _ = export_job(tmp_path, servo_profile(tmp_path), n=3)
    lines = path.read_text().splitlines()
    last_cut = max(i for i, t in enumerate(lines) if t.startswith("G1") and "F1200" in t)
    short = tmp_path / "short.gcode"
    short.write_text("\n".join(lines[: last_cut + 1]) + "\n")
    # alone, the file cannot tell its up state (it ends on a cut): every M3 is down
    with pytest.raises(ConfigError, match=r"ends with the tool down \(spindle output M3\)"):
        check_tool_up_at_end(load_program(short))
    expected = rf"ends with the tool down \(spindle output M3 S{DOWN:g}, not the S{UP:g} "
    with pytest.raises(ConfigError, match=expected):
        check_tool_up_at_end(load_program(short, tool_up=f"M3 S{UP:g}"))


def drop_and_resume(tmp_path, capsys, off: str, fault: str, machine: bool):
    """Export with ``off``, stream until ``fault``, resume: (resume line said, per-stroke
    scratch counts over both runs, blocks the resume sent, the file's strokes)."""
    folder = tmp_path / off.replace(" ", "")
    folder.mkdir()
    profile_path = servo_profile(folder, off)
    path, strokes = export_job(folder, profile_path, n=30)
    recs = [folder / "r1.jsonl", folder / "r2.jsonl"]
    common = ["--yes", "--banner-timeout", "0.3"]
    common += ["--machine", str(profile_path)] if machine else []
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(path), "--port", f"{SIM}&{fault}&record={recs[0]}", *common])
    assert exc.value.code == 3
    capsys.readouterr()
    first = scratch_counts([read_record(recs[0])], strokes)
    assert 0 < sum(first) < len(strokes)  # stopped mid-job
    main(["stream", str(path), "--port", f"{SIM}&record={recs[1]}", "--resume", *common])
    said = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("resuming"))
    counts = scratch_counts([read_record(r) for r in recs], strokes)
    sent = [e["text"] for e in read_record(recs[1]) if e["ev"] == "rx" and e["g"]]
    return said.split(";")[0], counts, sent, load_program(path).strokes


@pytest.mark.parametrize(
    ("fault", "machine"),
    [("disconnect_after=90", False), ("disconnect_after=90", True), ("error_at=90", True)],
    ids=["link-drop", "link-drop-machine", "error-machine"],
)
def test_stop_then_resume_scratches_every_stroke_as_the_m5_job_does(
    tmp_path, capsys, fault, machine
):
    """`stream` stops mid-job (a dropped link, an error), `stream --resume`: the S-lift job
    restarts at the same line as its M5 twin (same lines but the up command), each stroke
    scratched once (one the lost link left unsure at most twice), the scribe lifted by
    the file's own up command before the preamble moves."""
    lifted = drop_and_resume(tmp_path, capsys, f"M3 S{UP:g}", fault, machine)
    m5 = drop_and_resume(tmp_path, capsys, "M5", fault, machine)
    said, counts, sent, strokes = lifted
    assert said == m5[0] and counts == m5[1] and strokes == m5[3]
    assert min(counts) == 1 and max(counts) <= 2 and counts.count(2) <= 1
    assert said.startswith("resuming at line")
    assert sent[1] == f"M3S{UP:g}" and m5[2][1] == "M5"
    assert [t[:2] for t in sent[2:5]] == ["G4", "M9", "G1"]  # the servo's dwell, then travel


def write(tmp_path: Path, name: str, lines: list[str]) -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def plotter_lines(up: str, down: str, first: list[str], travel: str = "G1") -> list[str]:
    """Two strokes (X10 to X11, X20 to X21 at Y5) lowered by ``down``, lifted by ``up``,
    after the set-up lines ``first``; travel by ``travel`` (G0, or G1 at F4000)."""
    feed = " F4000" if travel == "G1" else ""
    lines = ["G21 G90", *first]
    for x in (10, 20):
        lines += [f"{travel} X{x} Y5{feed}", down, "G4 P0.1", f"G1 X{x + 1} F1200", up, "G4 P0.1"]
    return [*lines, f"{travel} X0 Y0{feed}", "M2"]


def cut_ends(prog) -> list[tuple[float | None, float | None]]:
    """Where each stroke's moves end: the XY of its motion blocks."""
    return [
        tuple((b.modal.x, b.modal.y) for b in prog.blocks[a : z + 1] if b.motion)
        for a, z in prog.strokes
    ]


CUTS = [((11.0, 5.0),), ((21.0, 5.0),)]


@pytest.mark.parametrize(
    ("up", "first", "travel", "tool_up"),
    [
        ("M3 S90", ["M3 S90"], "G1", None),  # the first XY move runs under the up S
        ("M3 S90", ["M3 S90"], "G0", None),  # the rapids run under it
        ("M4 S120", ["M4 S120"], "G1", None),
        ("M3 S0", ["M3 S0"], "G1", None),  # S0: the output off, as M5
        ("M3 S90", ["M5", "G1 X1 Y1 F4000", "M3 S90"], "G1", "M3 S90"),  # told by the profile
        ("M5", ["M5"], "G1", None),  # an M5 job: unchanged
        ("M5", ["M5"], "G1", "M3 S90"),  # a profile whose S the job never moves under
    ],
)
def test_the_up_state_is_read_from_the_file_or_the_profile(tmp_path, up, first, travel, tool_up):
    path = write(tmp_path, "j.gcode", plotter_lines(up, "M3 S35", first, travel))
    prog = load_program(path, tool_up=tool_up)
    assert prog.pen_mode and cut_ends(prog) == CUTS
    assert prog.tool_up == ("M5" if up == "M5" else up.replace(" ", ""))
    assert resume_preamble(prog, prog.strokes[1][0])[1] == prog.tool_up


def test_a_job_that_does_not_tell_its_up_state_keeps_m3_as_down(tmp_path):
    """Two S levels but nothing telling which one lifts: the first move under M5, no
    rapids (or rapids under both levels, as a laser job's): every M3 counts as down, one
    stroke, as before, and a resume there is refused rather than guessed."""
    job = plotter_lines("M3 S90", "M3 S35", ["M5", "G1 X1 Y1 F4000", "M3 S90"])
    laser = ["G21 G90", "M3 S90", "G0 X5 Y5", "G1 X6 S35 F600", "G0 X8 S90", "G1 X9", "M5", "M2"]
    for name, lines in (("job", job), ("laser", laser)):
        prog = load_program(write(tmp_path, f"{name}.gcode", lines))
        on = next(b.index for b in prog.blocks if b.modal.spindle == "M3")
        off = next(b.index for b in prog.blocks[on:] if b.modal.spindle == "M5")
        assert prog.tool_up == "M5" and prog.lift_speed is None
        assert prog.strokes == [(on, off)]


def test_a_file_that_starts_drawing_at_once_is_not_guessed(tmp_path):
    """A reviewer's foreign file: its first XY move draws (S30) and its last travels home
    (S90). The first move's level alone named S30 the up state: strokes and travels
    swapped, a resume lowering the pen before its move back. The two ends disagree, so
    nothing is guessed: every M3 counts as down (one stroke), a resume refused."""
    lines = ["G21 G90 G17 G94", "M3 S30", "G1 X10 Y10 F1000", "M3 S90", "G1 X20 Y10",
             "M3 S30", "G1 X20 Y20", "M3 S90", "G1 X30 Y20", "M3 S30", "G1 X30 Y30",
             "M3 S90", "G1 X0 Y0", "M5", "M2"]  # fmt: skip
    prog = load_program(write(tmp_path, "drawn.gcode", lines))
    assert prog.tool_up == "M5" and prog.lift_speed is None
    on = next(b.index for b in prog.blocks if b.modal.spindle == "M3")
    off = next(b.index for b in prog.blocks[on:] if b.modal.spindle == "M5")
    assert prog.strokes == [(on, off)]
    # with the profile's up command the same file is read right: S30 draws
    told = load_program(write(tmp_path, "told.gcode", lines), tool_up="M3 S90")
    assert told.tool_up == "M3S90" and told.lift_speed == 90
    drawn = [told.blocks[a : b + 1] for a, b in told.strokes]
    assert all(any(x.modal.speed == 30 for x in span) for span in drawn)
    assert not any(b.modal.speed == 30 and b.modal.x == 0 for b in told.blocks if b.motion)


def test_a_stop_without_a_profile_lifts_with_the_files_up_command(tmp_path, capsys):
    """``scratchfab stream`` with no --machine: a stop's lift after the reset is the file's
    own up state (M3 S90), the first line the controller gets after the Ctrl-X."""
    path, _ = export_job(tmp_path, servo_profile(tmp_path), n=20)
    rec = tmp_path / "r.jsonl"
    port = f"{SIM}&error_at=40&record={rec}"
    with pytest.raises(SystemExit):
        main(["stream", str(path), "--port", port, "--yes", "--banner-timeout", "0.3"])
    capsys.readouterr()
    r = read_record(rec)
    reset = max(k for k, e in enumerate(r) if e["ev"] == "rt" and e["ch"] == 0x18)
    assert [e["text"] for e in r[reset:] if e["ev"] == "rx"][:1] == [f"M3S{UP:g}"]


def test_the_profile_tells_the_stream_what_the_file_does_not(tmp_path, capsys):
    """A file that does not show which S lifts (its first move runs under M5) resumes at
    its stroke when streamed with a servo profile whose ``off`` is ``M3 S90``: the stream
    reads the file with the profile's up command, as the exporter wrote it."""
    path = write(
        tmp_path, "j.gcode", plotter_lines("M3 S90", "M3 S35", ["M5", "G1 X1 Y1 F4000", "M3 S90"])
    )
    rec = tmp_path / "r.jsonl"
    common = ["--yes", "--banner-timeout", "0.3", "--machine", str(servo_profile(tmp_path))]
    with pytest.raises(SystemExit):
        main(["stream", str(path), "--port", f"{SIM}&error_at=12&record={rec}", *common])
    capsys.readouterr()
    main(["stream", str(path), "--port", f"{SIM}&record={rec}", "--resume", *common])
    out = capsys.readouterr().out
    assert "resuming at line" in out and "preamble: G21G90G17G94 M3S90" in out, out


@pytest.mark.parametrize(
    ("off", "laser", "machine", "warned"),
    [
        (f"M3 S{UP:g}", 1, True, True),  # the profile's up command keeps the output on
        (f"M3 S{UP:g}", 1, False, True),  # the file's own up state tells the same
        (f"M3 S{UP:g}", 0, True, False),  # laser mode off: the hold keeps the output
        ("M5", 1, True, False),  # lifted by switching the output off: nothing to drop
    ],
)
def test_laser_mode_with_a_servo_held_up_by_s_is_warned(
    tmp_path, capsys, off, laser, machine, warned
):
    """GRBL's laser mode ($32=1) switches the output off in a feed hold and in G0 moves:
    a servo held up by M3 S90 drops the scribe there. Said at connect."""
    profile = servo_profile(tmp_path, off=off)
    path, _ = export_job(tmp_path, profile, n=3)
    args = ["stream", str(path), "--port", f"{SIM}&$32={laser}", "--yes"]
    main([*args, "--banner-timeout", "0.3", *(["--machine", str(profile)] if machine else [])])
    err = capsys.readouterr().err
    said = "GRBL laser mode is on ($32=1) and the scribe is held up by 'M3S90'" in err
    said = said or "GRBL laser mode is on ($32=1) and the scribe is held up by 'M3 S90'" in err
    assert said == warned, err
    assert ("turn laser mode off ($32=0)" in err) == warned


@pytest.mark.parametrize(
    ("up", "off", "expected"),
    [
        ("M3 S90", "M5", "M3S90"),  # the file holds up by S90 although the profile says M5
        ("M3 S90", "M3 S90", "M3S90"),
        ("M5", "M5", "M5"),
        ("M5", None, "M5"),
        ("M3 S90", None, "M3S90"),
    ],
)
def test_a_stop_lifts_with_what_the_file_moves_under(tmp_path, up, off, expected):
    """A reviewer: a file held up by M3 S90 streamed with the bundled plotter (off = M5):
    the resume lifted with S90 but a stop with the profile's M5 (PWM 0: the servo goes
    wherever that puts it) and the laser-mode warning stayed silent. One rule serves all."""
    from scratchfab.machine.sender_checks import laser_mode_warning
    from scratchfab.machine.sender_program import servo_up

    prog = load_program(write(tmp_path, "j.gcode", plotter_lines(up, "M3 S35", [up])), tool_up=off)
    assert servo_up(prog, off) == expected
    assert servo_up(None, off) == (off or "M5")
    plotter = load_profile("grbl-plotter-scribe")
    assert plotter.tool_control.command("off") == "M5"
    warned = laser_mode_warning({32: 1}, prog, plotter)
    assert (warned is not None) == (expected != "M5")
    assert laser_mode_warning({32: 0}, prog, plotter) is None
