"""`scratchfab stream` against the GRBL emulator, through grblsim:// and a real pty."""

from __future__ import annotations

import functools
import json
import math
import re
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import serial
from stream_helpers import FAST, executed_blocks, interrupt_after, stopped_after, stream_program

from scratchfab.cli import main
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.profile import Z_UNLIMITED_MM, load_profile
from scratchfab.machine.sender import (
    ControllerInfo,
    Status,
    Streamer,
    StreamFault,
    StreamOptions,
    StreamStopped,
    open_port,
)
from scratchfab.machine.sender_checks import compare, job_extent
from scratchfab.machine.sender_journal import (
    Journal,
    default_journal_path,
    done_blocks,
    interrupted,
    read_journal,
)
from scratchfab.machine.sender_program import (
    load_program,
    resume_point,
    resume_preamble,
    strip_block,
)
from scratchfab.machine.stream_job import run_stream_job


@pytest.fixture(autouse=True)
def _short_banner_settle(monkeypatch):
    """The CLI reads on 0.1 s after each banner; the emulator sends a banner's messages
    with it, so the CLI run in these tests reads on for 0.02 s (as ``FAST`` does)."""
    monkeypatch.setattr(
        "scratchfab.machine.stream_job.StreamOptions",
        functools.partial(StreamOptions, banner_settle=FAST.banner_settle),
    )


def write_job(
    path: Path, strokes: int, seed: int = 7
) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """An exporter-style job; returns each stroke's (start, end) in work mm."""
    rng = np.random.default_rng(seed)
    lines = ["; scratchfab test job", "G21 G90 G17 G94", "G0 Z2"]
    cuts = []
    for _ in range(strokes):
        x, y = np.round(rng.uniform(-30, 30, 2), 3)
        u, v = np.round(rng.uniform(-2, 2, 2), 3)
        lines += [
            "G0 Z2",
            f"G0 X{x:.3f} Y{y:.3f}",
            "G1 Z-0.05 F200",
            f"G1 X{x + u:.3f} Y{y + v:.3f} F600  (cut)",
            "G0 Z2",
        ]
        cuts.append(((float(x), float(y)), (round(float(x + u), 3), round(float(y + v), 3))))
    lines.append("M2")
    path.write_text("\n".join(lines) + "\n")
    return cuts


def read_record(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def cut_counts(records: list[list[dict]], cuts) -> list[int]:
    """How often each stroke's cut was executed (both ends matching, tool below Z=0)."""
    counts = [0] * len(cuts)
    index = {}
    for k, (a, b) in enumerate(cuts):
        index.setdefault(
            (round(a[0], 3), round(a[1], 3), round(b[0], 3), round(b[1], 3)), []
        ).append(k)
    for rec in records:
        for e in rec:
            if e["ev"] != "exec" or e["rapid"] or e["to"][2] >= 0 or e["frm"][2] >= 0:
                continue
            key = (
                round(e["frm"][0], 3),
                round(e["frm"][1], 3),
                round(e["to"][0], 3),
                round(e["to"][1], 3),
            )
            if key[:2] == key[2:]:
                continue
            for k in index.get(key, []):
                counts[k] += 1
    return counts


# --------------------------------------------------------------------------- program


def test_strip_block_matches_grbl_preprocessing():
    assert strip_block("g1 x1.5 (move!) y2 ; done") == "G1X1.5Y2"
    assert strip_block("(only a comment)") == ""
    assert strip_block("%") == ""


def test_strokes_in_z_and_servo_jobs(tmp_path):
    z = tmp_path / "z.gcode"
    z.write_text(
        "G21G90\nG0Z1\nG0X1Y1\nG1Z-0.1F100\nG1X2F300\nG1Y2\nG0Z1\nG0X5\nG1Z-0.1\nG1X6\nG0Z1\n"
    )
    prog = load_program(z)
    assert not prog.pen_mode
    assert [(prog.blocks[a].lineno, prog.blocks[b].lineno) for a, b in prog.strokes] == [
        (4, 7),
        (9, 11),
    ]
    surface = tmp_path / "surface.gcode"  # engraving at Z=0, travelling at Z=2: auto threshold
    surface.write_text("G21G90\nG0Z2\nG0X1Y1\nG1Z0F100\nG1X2F300\nG0Z2\nG0X5\nG1Z0\nG1X6\nG0Z2\n")
    prog = load_program(surface)
    assert prog.z_threshold == 1.0
    assert [(prog.blocks[a].lineno, prog.blocks[b].lineno) for a, b in prog.strokes] == [
        (4, 6),
        (8, 10),
    ]
    servo = tmp_path / "servo.gcode"
    servo.write_text("G21G90\nM5\nG0X1Y1\nM3S40\nG1X2F500\nM5\nG0X3\nM3S40\nG1X4\nM5\n")
    prog = load_program(servo)
    assert prog.pen_mode
    assert [(prog.blocks[a].lineno, prog.blocks[b].lineno) for a, b in prog.strokes] == [
        (4, 6),
        (8, 10),
    ]


def test_bad_lines_are_refused_with_their_line(tmp_path):
    bad = tmp_path / "bad.gcode"
    bad.write_text("G21\nG0 X1 " + "Y1 " * 40 + "\n")
    with pytest.raises(ConfigError, match=r"bad.gcode:2: .*at most 79"):
        load_program(bad)
    bad.write_text("G21\nG0 X1 ?\n")
    with pytest.raises(ConfigError, match=r"bad.gcode:2: .*realtime"):
        load_program(bad)


def test_resume_preamble_raises_z_before_xy(tmp_path):
    job = tmp_path / "j.gcode"
    write_job(job, 3)
    prog = load_program(job)
    second = prog.strokes[1][0]
    assert resume_point(prog, set(range(second))) == second
    pre = resume_preamble(prog, second)
    assert pre[0].startswith("G21G90")
    z_up = next(k for k, t in enumerate(pre) if t.startswith("G0Z"))
    xy = next(k for k, t in enumerate(pre) if t.startswith("G0X"))
    assert z_up < xy
    before = prog.blocks[second - 1].modal
    assert pre[xy] == f"G0X{before.x:g}Y{before.y:g}"
    assert pre[z_up] == "G0Z2"


def test_default_journal_path(tmp_path):
    assert (
        default_journal_path(tmp_path / "JOB" / "export" / "board.gcode")
        == (tmp_path / "JOB" / "stream" / "journal.jsonl").resolve()
    )
    assert default_journal_path(tmp_path / "x.nc").name == "x.nc.journal.jsonl"


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: None, ": no journal to resume from (stream without --resume first)"),
        (lambda p: p.mkdir(), ": is a directory, expected a journal file"),
        (lambda p: p.write_bytes(b"\xff\xfe{"), ": not a journal (not UTF-8 text)"),
        (
            lambda p: p.write_text('"hand edited"\n{}\n'),
            ":1: not a journal line (move the journal aside to stream from the top)",
        ),
    ],
)
def test_read_journal_errors_name_the_file(tmp_path, make, message):
    path = tmp_path / "j.jsonl"
    make(path)
    with pytest.raises(ConfigError) as info:
        read_journal(path)
    assert str(info.value) == f"{path}{message}"


def test_load_program_errors_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_program(tmp_path / "none.gcode")
    (tmp_path / "dir.gcode").mkdir()
    with pytest.raises(ConfigError, match="is a directory, expected a G-code file"):
        load_program(tmp_path / "dir.gcode")


def test_journal_rejects_changed_file(tmp_path):
    job = tmp_path / "j.gcode"
    write_job(job, 2)
    prog = load_program(job)
    j = Journal(tmp_path / "j.jsonl").open()
    j.write("start", sha256="0" * 64, file=str(job), blocks=len(prog.blocks), resume=False)
    j.close()
    with pytest.raises(ConfigError, match="different version"):
        done_blocks(read_journal(tmp_path / "j.jsonl"), prog.sha256, "j.jsonl")


def test_lost_link_blocks_count_done_unless_recut_unsure():
    events = [
        {"ev": "start", "sha256": "a", "resume": False},
        *({"ev": "ack", "i": i} for i in range(10)),
        {"ev": "lost", "reason": "connection lost", "executed_through": 5},
        {"ev": "start", "sha256": "a", "resume": True},
        *({"ev": "ack", "i": i} for i in range(6, 8)),
    ]
    assert done_blocks(events, "a", "j") == set(range(10))
    # the resume that followed the lost link settled it; only a loss ending the last run counts
    assert done_blocks(events, "a", "j", recut_unsure=True) == set(range(10))
    lost_again = [
        *events,
        *({"ev": "ack", "i": i} for i in range(10, 13)),
        {"ev": "lost", "reason": "connection lost", "executed_through": 10},
    ]
    assert done_blocks(lost_again, "a", "j") == set(range(13))
    assert done_blocks(lost_again, "a", "j", recut_unsure=True) == set(range(11))
    assert interrupted(events, "a") and not interrupted(events, "b")
    assert not interrupted([*events, {"ev": "end", "complete": True}], "a")
    assert not interrupted([], "a")


def test_runs_before_the_last_fresh_start_do_not_count():
    events = [
        {"ev": "start", "sha256": "v1", "resume": False},
        *({"ev": "ack", "i": i} for i in range(50)),
        {"ev": "end", "complete": True},
        {"ev": "start", "sha256": "v2", "resume": False},
        *({"ev": "ack", "i": i} for i in range(4)),
        {"ev": "lost", "reason": "connection lost", "executed_through": 1},
    ]
    assert done_blocks(events, "v2", "j") == set(range(4))  # v1's run is not held against v2
    assert done_blocks(events, "v2", "j", recut_unsure=True) == {0, 1}
    with pytest.raises(ConfigError, match="different version"):
        done_blocks(events, "v1", "j")


def test_resume_with_nothing_left_closes_the_journal(tmp_path):
    job = tmp_path / "job"
    gcode = job / "export" / "board.gcode"
    gcode.parent.mkdir(parents=True)
    write_job(gcode, 2)
    prog = load_program(gcode)
    journal = job / "stream" / "journal.jsonl"
    j = Journal(journal).open()
    j.start(prog, resume=False)
    for b in prog.blocks:
        j.write("ack", i=b.index, line=b.lineno)
    j.write("lost", reason="connection lost", executed_through=len(prog.blocks) - 1)
    j.close()
    said: list[str] = []
    run_stream_job(job, "grblsim://?baud=0&time_scale=0.001", say=said.append)
    assert any("nothing to do" in line for line in said)
    assert not interrupted(read_journal(journal), prog.sha256)  # a later run starts fresh


@pytest.mark.parametrize(("baud", "opened"), [(None, 57600), (9600, 9600)])
def test_port_opens_at_the_given_baud_else_the_profiles(tmp_path, monkeypatch, baud, opened):
    job = tmp_path / "job"
    gcode = job / "export" / "board.gcode"
    gcode.parent.mkdir(parents=True)
    write_job(gcode, 2)
    base = load_profile("grbl-3018-diamond")
    profile = replace(base, serial=replace(base.serial, baud=57600))
    bauds: list[int] = []

    def fake_open(port: str, rate: int):
        bauds.append(rate)
        raise ScratchfabError("not opened")

    monkeypatch.setattr("scratchfab.machine.stream_job.open_port", fake_open)
    with pytest.raises(ScratchfabError, match="not opened"):
        run_stream_job(job, "/dev/ttyFAKE", baud=baud, machine=profile)
    assert bauds == [opened]


def test_compare_with_profile_and_soft_limits(tmp_path):
    job = tmp_path / "j.gcode"
    write_job(job, 5)
    prog = load_program(job)
    settings = {20: 1, 22: 1, 110: 500, 111: 500, 112: 500, 130: 200, 131: 200, 132: 200}
    settings |= {120: 10, 121: 10, 122: 10}
    profile = _bench_profile()
    found = compare(settings, (0.0, 0.0, 0.0), prog, profile)
    assert any("X range" in r and "envelope" in r for r in found.refusals)  # job wider than 10 mm
    assert any("soft limits allow" in r for r in found.refusals)  # positive X in machine space
    assert (
        "GRBL $110=500 mm/min is below the X max rate 1000 of machine 'bench': feeds are "
        "clamped, the estimate is optimistic" in found.warnings
    )
    slow = [w for w in found.warnings if "mm/s^2" in w]  # GRBL's defaults: 10 mm/s^2
    assert slow == [
        "GRBL $120=10 mm/s^2 is below the X acceleration 200 of machine 'bench': the job "
        "takes longer than the toolpath's estimate (the ETA here uses GRBL's)",
        "GRBL $122=10 mm/s^2 is below the Z acceleration 50 of machine 'bench': the job "
        "takes longer than the toolpath's estimate (the ETA here uses GRBL's)",
    ]
    ok = compare(settings, (-100.0, -100.0, -10.0), prog, None)
    assert ok.refusals == []


@pytest.mark.parametrize(
    ("text", "clamped"),
    [
        ("G21G90\nG1X1F900\n", {"X": 900.0}),  # mm/min as written
        ("G20G90\nG1X1F40\n", {"X": 1016.0}),  # 40 in/min is 1016 mm/min
        ("G20G90\nG1X1F30\n", {}),  # 762 mm/min: within $110
        ("G21G90\nG1X3Y4F1000\n", {}),  # X at 600, Y at 800 mm/min
        ("G21G90\nG1X3Y4F1100\n", {"Y": 880.0}),  # X at 660, Y at 880
        ("G21G90\nG0Z0\nG1Z-1F200\nG1X10F700\n", {}),  # Z moves at 200, X at 700
        ("G21G90\nG0Z0\nG1Z-1F400\n", {"Z": 400.0}),
        ("G21G90\nG0X-5Y0\nG2X5Y0I5J0F900\n", {"X": 900.0, "Y": 900.0}),  # arc: full feed
        ("G21G90G93\nG1X1F5000\n", {}),  # inverse time: F is 1/min, not a speed
        ("G21G90\nG0X100F5000\n", {}),  # G0 runs at the max rates by definition
    ],
)
def test_compare_warns_of_axis_speeds_above_grbl_max_rates(tmp_path, text, clamped):
    """Each axis' speed in mm/min, whatever the file's units, against its own ``$11x``."""
    job = tmp_path / "j.gcode"
    job.write_text(text)
    settings = {20: 0, 22: 1, 110: 800, 111: 800, 112: 300}
    found = compare(settings, None, load_program(job), start_xy=(0.0, 0.0))  # from X0 Y0
    rates = {"X": 800, "Y": 800, "Z": 300}
    assert [w for w in found.warnings if "GRBL clamps it" in w] == [
        f"the job moves {axis} at up to {speed:g} mm/min but GRBL's ${110 + 'XYZ'.index(axis)}="
        f"{rates[axis]} mm/min: GRBL clamps it, the job runs slower"
        for axis, speed in clamped.items()
    ]


def _arc_samples(start, end, cw, ij=None, r=None, n=20001):
    """Points along a G17 arc, centre by circle intersection (R) or offset (I, J)."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    if r is None:
        centre = start + np.asarray(ij, float)
    else:
        mid, chord = 0.5 * (start + end), end - start
        d = np.hypot(*chord)
        normal = np.array([-chord[1], chord[0]]) / d
        h = math.sqrt(r * r - 0.25 * d * d)
        centre = None
        for c in (mid + h * normal, mid - h * normal):  # R > 0: the arc of at most 180 deg
            a0 = math.atan2(*(start - c)[::-1])
            a1 = math.atan2(*(end - c)[::-1])
            sweep = ((a0 - a1) if cw else (a1 - a0)) % math.tau
            if (sweep <= math.pi + 1e-9) == (r > 0):
                centre = c
        assert centre is not None
    radius = np.hypot(*(start - centre))
    a0 = math.atan2(*(start - centre)[::-1])
    a1 = math.atan2(*(end - centre)[::-1])
    sweep = ((a0 - a1) if cw else (a1 - a0)) % math.tau or math.tau
    t = a0 + (-1 if cw else 1) * np.linspace(0.0, sweep, n)
    return centre + radius * np.stack([np.cos(t), np.sin(t)], 1)


@pytest.mark.parametrize("seed", range(40))
def test_arc_extent_matches_a_sampled_arc(tmp_path, seed):
    rng = np.random.default_rng(seed)
    start = np.round(rng.uniform(-50, 50, 2), 4)
    cw = bool(rng.integers(2))
    if seed % 3 == 0:  # I/J offsets; every fifth a full circle
        ij = np.round(rng.uniform(-20, 20, 2), 4)
        angle = rng.uniform(0, math.tau)
        on_circle = start + ij + np.hypot(*ij) * np.array([math.cos(angle), math.sin(angle)])
        end = start if seed % 5 == 0 else np.round(on_circle, 4)
        words, pts = f"I{ij[0]:.4f}J{ij[1]:.4f}", _arc_samples(start, end, cw, ij=ij)
    else:
        end = np.round(start + rng.uniform(-30, 30, 2), 4)
        half = 0.5 * np.hypot(*(end - start))
        r = round(rng.uniform(half * 1.01, half * 3) * (1 if seed % 2 else -1), 4)
        words, pts = f"R{r:.4f}", _arc_samples(start, end, cw, r=r)
    job = tmp_path / "arc.gcode"
    job.write_text(
        f"G21G90G17\nG0X{start[0]:.4f}Y{start[1]:.4f}\n"
        f"G{2 if cw else 3}X{end[0]:.4f}Y{end[1]:.4f}{words}F100\n"
    )
    (x_lo, y_lo, _), (x_hi, y_hi, _) = job_extent(load_program(job))
    want = (*pts.min(0), *pts.max(0))
    assert np.allclose((x_lo, y_lo, x_hi, y_hi), want, atol=2e-3)


def _bench_profile(x=(-10.0, 10.0)):
    return SimpleNamespace(
        name="bench",
        envelope=SimpleNamespace(
            x_mm=x,
            y_mm=(-40.0, 40.0),
            z_mm=(-5.0, 5.0),
            max_travel_mm=(20.0, 80.0, 10.0),
            coordinates="work",
        ),
        motion=SimpleNamespace(
            max_rate_mm_min=(1000.0, 500.0, 500.0), acceleration_mm_s2=(200.0, 10.0, 50.0)
        ),
    )


def test_profile_without_z_range_asks_no_z_travel(tmp_path):
    job = tmp_path / "j.gcode"
    job.write_text("G21G90\nG0Z0\nG0X-20Y-20\nG1Z-1F100\nG1X-18\nG0Z0\n")
    base = load_profile("grbl-3018-diamond")  # in work coordinates: any offset will do
    profile = replace(base, envelope=replace(base.envelope, coordinates="work"))
    settings = {20: 1, 22: 1, 110: 5000, 111: 5000, 112: 600, 130: 300, 131: 180, 132: 45}
    wco = (-150.0, -90.0, -40.0)
    assert compare(settings, wco, load_program(job), profile).refusals == []
    unlimited = replace(profile, envelope=replace(profile.envelope, z_mm=Z_UNLIMITED_MM))
    assert unlimited.envelope.max_travel_mm[2] is None
    assert compare(settings, wco, load_program(job), unlimited).refusals == []
    # a profile that does give Z still has it compared with $132
    settings[132] = 20
    travel = f"{job}: machine '{profile.name}' expects 45 mm of Z travel but GRBL has $132=20"
    assert travel in compare(settings, wco, load_program(job), profile).refusals
    assert travel not in compare(settings, wco, load_program(job), unlimited).refusals


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("G92X0Y0", "G92 changes the work coordinates"),
        ("G92.1", "G92.1 changes the work coordinates"),
        ("G10L20P1X0", "G10 changes the work coordinates"),
        ("G55", "G55 selects another work coordinate system"),
        ("G53G0X-500", "G53 moves in machine coordinates"),
        ("G28", "G28 moves through a stored machine position"),
        ("G30G91Z0", "G30 moves through a stored machine position"),
        ("G18G2X1Z1R2", "an arc in the G18 plane"),
    ],
)
def test_compare_refuses_lines_the_sender_cannot_follow(tmp_path, line, reason):
    job = tmp_path / "j.gcode"
    job.write_text(f"G21G90G17\nG0Z1\nG0X1Y1\n{line}\nG0X2Y2\n")
    found = compare({}, None, load_program(job), _bench_profile())
    assert found.refusals == [
        f"{job}:4: {reason} ({line!r}); the sender cannot follow the position past it, so the "
        "envelope cannot be checked"
    ]
    assert compare({}, None, load_program(job), None).refusals == []  # nothing to check


def test_compare_refuses_an_arc_that_bulges_out_of_the_envelope(tmp_path):
    job = tmp_path / "j.gcode"
    # From (5, -5) to (5, 5) counter-clockwise about (5, 0): reaches X = 10 exactly.
    job.write_text("G21G90G17\nG0Z1\nG0X5Y-5\nG3X5Y5I0J5F100\n")
    assert compare({}, None, load_program(job), _bench_profile()).refusals == []
    job.write_text("G21G90G17\nG0Z1\nG0X5Y-5\nG3X5Y5I1J5F100\n")  # centre (6, 0)
    (refusal,) = compare({}, None, load_program(job), _bench_profile()).refusals
    assert refusal.startswith(f"{job}:4: the job's X range [")
    assert "leaves the envelope [-10, 10]" in refusal


# --------------------------------------------------------------------------- streaming


def _received_gcode(record) -> list[str]:
    return [e["text"] for e in record if e["ev"] == "rx" and e["g"]]


@pytest.mark.parametrize("protocol", ["counting", "simple"])
@pytest.mark.parametrize("link", ["grblsim", "pty"])
def test_1000_lines_arrive_once_in_order(tmp_path, protocol, link):
    job = tmp_path / "job.gcode"
    write_job(job, 200)  # 1003 G-code lines
    prog = load_program(job)
    assert len(prog.blocks) >= 1000
    options = StreamOptions(
        protocol=protocol, banner_timeout=0.3, banner_settle=0.02, stall_timeout=2.0
    )
    if link == "grblsim":
        port = open_port("grblsim://?time_scale=0.0005", 115200)
        try:
            streamer = stream_program(port, prog, tmp_path / "j.jsonl", options)
        finally:
            port.close()
        sim = port.sim
    else:
        with GrblPty(SimOptions(time_scale=0.0005)) as pty:
            port = serial.Serial(pty.path, 115200, timeout=0.01)
            try:
                streamer = stream_program(port, prog, tmp_path / "j.jsonl", options)
            finally:
                port.close()
            sim = pty.sim
    # then the dwell whose ok says the motion has ended
    assert _received_gcode(sim.record) == [b.text for b in prog.blocks] + ["G4P0"]
    assert sim.overruns == 0
    assert not [e for e in sim.record if e["ev"] == "resp" and e["r"] != "ok"]
    if protocol == "counting":
        assert 40 < streamer.max_inflight_bytes <= 120
    else:
        assert streamer.max_inflight_lines == 1
    events = read_journal(tmp_path / "j.jsonl")
    acks = [e["i"] for e in events if e["ev"] == "ack"]
    assert acks == list(range(len(prog.blocks)))
    # the session names where it went: the emulator's URL, or the pty's device
    assert events[0]["port"] == ("grblsim://?time_scale=0.0005" if link == "grblsim" else pty.path)


def test_error_stops_feed_holds_and_names_line_cli(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    write_job(job, 200)
    prog = load_program(job)
    rec = tmp_path / "rec.jsonl"
    url = f"grblsim://?baud=0&time_scale=0.002&error_at=250&record={rec}"
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", url, "--yes", "--banner-timeout", "0.5"])
    assert exc.value.code == 3
    err = capsys.readouterr().err
    line = prog.blocks[249].lineno
    assert f"job.gcode:{line}: error:20 (unsupported or invalid G-code command" in err
    record = read_record(rec)
    rx = [e for e in record if e["ev"] == "rx" and e["g"]]
    bad = next(k for k, e in enumerate(rx) if e["g"] == 250)
    after = rx[bad + 1 :]
    assert sum(len(e["text"]) + 1 for e in after) <= 128  # within one RX buffer
    t_err = next(e["t"] for e in record if e["ev"] == "resp" and e["g"] == 250)
    holds = [e for e in record if e["ev"] == "rt" and e["ch"] == ord("!")]
    assert holds and holds[0]["t"] >= t_err
    states = [e["state"] for e in record if e["ev"] == "state" and e["t"] >= holds[0]["t"]]
    assert "Hold:0" in states
    assert not any(e["ev"] == "alarm" for e in record)  # held before the reset


def test_error_through_pty(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 60)
    prog = load_program(job)
    with GrblPty(SimOptions(baud=0, time_scale=0.002, error_at=100)) as pty:
        port = serial.Serial(pty.path, 115200, timeout=0.01)
        try:
            with pytest.raises(StreamFault, match=rf"job.gcode:{prog.blocks[99].lineno}: error:20"):
                stream_program(port, prog, tmp_path / "j.jsonl")
        finally:
            port.close()
        record = pty.sim.record
    assert any(e["ev"] == "rt" and e["ch"] == ord("!") for e in record)


@pytest.mark.parametrize("link", ["grblsim", "pty"])
def test_disconnect_then_resume_cuts_every_stroke_at_most_one_twice(tmp_path, link, capsys):
    job = tmp_path / "job.gcode"
    cuts = write_job(job, 120)
    rec1, rec2 = tmp_path / "r1.jsonl", tmp_path / "r2.jsonl"
    common = ["--yes", "--banner-timeout", "0.3"]
    if link == "grblsim":
        with pytest.raises(SystemExit) as exc:
            main(
                [
                    "stream",
                    str(job),
                    "--port",
                    f"grblsim://?baud=0&time_scale=0.002&disconnect_after=301&record={rec1}",
                    *common,
                ]
            )
        assert exc.value.code == 3
    else:
        pty = GrblPty(
            SimOptions(baud=0, time_scale=0.002, disconnect_after=301, record=str(rec1))
        ).start()
        with pytest.raises(SystemExit) as exc:
            main(["stream", str(job), "--port", pty.path, *common])
        assert exc.value.code == 3
        pty.close()
    assert "connection lost" in capsys.readouterr().err
    main(
        [
            "stream",
            str(job),
            "--port",
            f"grblsim://?baud=0&time_scale=0.002&record={rec2}",
            "--resume",
            *common,
        ]
    )
    out = capsys.readouterr().out
    assert "resuming at line" in out
    counts = cut_counts([read_record(rec1), read_record(rec2)], cuts)
    assert min(counts) == 1
    assert max(counts) <= 2 and counts.count(2) <= 1
    first_rx = [e["text"] for e in read_record(rec2) if e["ev"] == "rx" and e["g"]]
    assert first_rx[0].startswith("G21G90")
    assert [t[:3] for t in first_rx[1:5]] == ["G0Z", "M5", "M9", "G0X"]  # Z up first, XY after


def test_usb_powered_disconnect_needs_recut_unsure(tmp_path, capsys):
    """A board that loses power with the cable never runs its queue: only re-cutting the
    unsure lines cuts every stroke, and the default resume says so."""
    job = tmp_path / "job.gcode"
    cuts = write_job(job, 40)
    journal = default_journal_path(job)
    recs = [tmp_path / f"r{k}.jsonl" for k in range(3)]
    common = ["--yes", "--banner-timeout", "0.3"]
    url = "grblsim://?baud=0&time_scale=0.01&disconnect_after=151&usb_powered=1&record="
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", f"{url}{recs[0]}", *common])
    assert exc.value.code == 3
    lost = read_journal(journal)[-1]
    assert lost["ev"] == "lost" and "connection lost" in lost["reason"]
    saved = journal.read_bytes()
    capsys.readouterr()

    def resume(rec, *flags):
        main(["stream", str(job), "--port", f"grblsim://?baud=0&time_scale=0.002&record={rec}",
              "--resume", *flags, *common])  # fmt: skip
        return capsys.readouterr().out

    out = resume(recs[1])
    assert "were acknowledged and count as done" in out and "--recut-unsure" in out
    trusted = cut_counts([read_record(recs[0]), read_record(recs[1])], cuts)
    assert min(trusted) == 0  # the queue that died with the power was skipped
    journal.write_bytes(saved)
    out = resume(recs[2], "--recut-unsure")
    assert "count as not done and are cut again" in out
    counts = cut_counts([read_record(recs[0]), read_record(recs[2])], cuts)
    assert min(counts) == 1 and max(counts) <= 2
    # only the unsure window is cut twice: at most a planner (15 motions) of 4-motion strokes
    assert counts.count(2) <= 5


def test_recut_unsure_needs_resume(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    write_job(job, 2)
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", "grblsim://?baud=0", "--recut-unsure", "--yes"])
    assert exc.value.code == 2
    assert "--recut-unsure only applies with --resume" in capsys.readouterr().err


def test_fresh_stream_over_an_unfinished_journal_warns(tmp_path, capsys):
    """An unfinished stream that had no line accepted: --yes streams from the top, said.
    (One that had: tests/test_stream_restart.py, refused under --yes.)"""
    job = tmp_path / "job.gcode"
    write_job(job, 3)
    journal = default_journal_path(job)
    j = Journal(journal).open()
    j.start(load_program(job), resume=False)
    j.close()
    args = ["stream", str(job), "--port", "grblsim://?baud=0&time_scale=0.001", "--yes"]
    main(args)
    assert "shows an unfinished stream of this file" in capsys.readouterr().err
    main(args)  # the journal's last run finished: no warning
    assert "unfinished" not in capsys.readouterr().err


def test_pipeline_stream_stage_resumes_an_interrupted_stream(tmp_path):
    job = tmp_path / "job"
    gcode = job / "export" / "board.gcode"
    gcode.parent.mkdir(parents=True)
    cuts = write_job(gcode, 60)
    recs = [tmp_path / f"r{k}.jsonl" for k in range(3)]
    said: list[str] = []
    with pytest.raises(StreamFault, match="connection lost"):
        run_stream_job(
            job,
            f"grblsim://?baud=0&time_scale=0.002&disconnect_after=151&record={recs[0]}",
            say=said.append,
        )
    run_stream_job(job, f"grblsim://?baud=0&time_scale=0.002&record={recs[1]}", say=said.append)
    assert any(line.startswith("resuming at line") for line in said)
    counts = cut_counts([read_record(recs[0]), read_record(recs[1])], cuts)
    assert min(counts) == 1 and max(counts) <= 2 and counts.count(2) <= 1
    said.clear()  # a finished stream streamed again (run --force) starts from the top
    run_stream_job(job, f"grblsim://?baud=0&time_scale=0.002&record={recs[2]}", say=said.append)
    assert not any(line.startswith("resuming") for line in said)
    assert min(cut_counts([read_record(recs[2])], cuts)) == 1


def test_ctrl_c_stop_is_safe_and_resume_completes(tmp_path):
    job = tmp_path / "job.gcode"
    cuts = write_job(job, 80)
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"
    calls = {"n": 0}

    def progress(p):
        calls["n"] += 1
        if p.acked > 150 and calls.get("fired") is None:
            calls["fired"] = True
            raise KeyboardInterrupt

    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    try:
        with pytest.raises(StreamStopped):
            stream_program(port, prog, journal, on_progress=progress, ask_interrupt=lambda: "stop")
    finally:
        port.close()
    rec1 = port.sim.record
    hold = next(e for e in rec1 if e["ev"] == "rt" and e["ch"] == ord("!"))
    reset = next(e for e in rec1 if e["ev"] == "rt" and e["ch"] == 0x18)
    states = [e["state"] for e in rec1 if e["ev"] == "state" and hold["t"] <= e["t"] <= reset["t"]]
    assert "Hold:0" in states
    assert not any(e["ev"] == "alarm" for e in rec1)
    done = done_blocks(read_journal(journal), prog.sha256, journal)
    start = resume_point(prog, done)
    port = open_port("grblsim://?baud=0&time_scale=0.002", 115200)
    try:
        stream_program(port, prog, journal, resume_at=start)
    finally:
        port.close()
    counts = cut_counts([rec1, port.sim.record], cuts)
    assert min(counts) == 1 and counts.count(2) <= 1 and max(counts) <= 2


def test_ctrl_c_resume_continues(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 20)
    prog = load_program(job)
    progress = interrupt_after(40)
    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    try:
        stream_program(
            port, prog, tmp_path / "j.jsonl", on_progress=progress, ask_interrupt=lambda: "resume"
        )
    finally:
        port.close()
    assert progress.fired
    assert _received_gcode(port.sim.record) == [b.text for b in prog.blocks] + ["G4P0"]
    chars = [e["ch"] for e in port.sim.record if e["ev"] == "rt" and e["ch"] != ord("?")]
    assert chars == [ord("!"), ord("~")]


def test_stall_watchdog(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 30)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.001&lose_ok_at=50", 115200)
    try:
        # answers pair with lines in order: the lost one leaves the last line unanswered
        with pytest.raises(StreamFault, match="stalled: no answer to the end-of-job G4P0"):
            stream_program(
                port,
                prog,
                tmp_path / "j.jsonl",
                StreamOptions(banner_timeout=0.3, banner_settle=0.02, stall_timeout=0.6),
            )
    finally:
        port.close()


def test_unexpected_banner_aborts(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 30)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.001&reset_after=60", 115200)
    try:
        with pytest.raises(StreamFault, match="reset itself mid-job"):
            stream_program(port, prog, tmp_path / "j.jsonl")
    finally:
        port.close()


def test_alarm_mid_job_reports_meaning(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("G21G90\nG1X-5F1000\nG1X-10\nG1X5\nG1X-1\n")
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.01&soft_limits=1&homed=1", 115200)
    try:
        with pytest.raises(StreamFault, match=r"ALARM:2 \(soft limit"):
            stream_program(port, prog, tmp_path / "j.jsonl")
    finally:
        port.close()
    assert any(e["ev"] == "rt" and e["ch"] == 0x18 for e in port.sim.record)


def test_alarm_state_is_refused_before_sending(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 2)
    port = open_port("grblsim://?baud=0&soft_limits=1", 115200)
    try:
        with pytest.raises(StreamFault, match="Alarm"):
            Streamer(port, FAST).connect()
    finally:
        port.close()
    assert not _received_gcode(port.sim.record)


def test_check_mode_reports_every_error_without_motion(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    job.write_text("G21G90\nG0X1\nM6\nG1X2\nG1X3F100\nG64\n")
    rec = tmp_path / "rec.jsonl"
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "stream",
                str(job),
                "--port",
                f"grblsim://?baud=0&record={rec}",
                "--check",
                "--yes",
                "--banner-timeout",
                "0.3",
            ]
        )
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "job.gcode:3: error:20" in err
    assert "job.gcode:4: error:22" in err
    assert "job.gcode:6: error:20" in err
    assert "found 3 problem(s)" in err
    record = read_record(rec)
    assert not any(e["ev"] == "exec" for e in record)
    assert sum(e["ev"] == "rx" and e["text"] == "$C" for e in record) == 2


def test_confirmation_required_without_yes(tmp_path):
    from click.testing import CliRunner

    from scratchfab.cli import cli

    job = tmp_path / "job.gcode"
    write_job(job, 2)
    rec = tmp_path / "rec.jsonl"
    result = CliRunner().invoke(
        cli,
        [
            "stream",
            str(job),
            "--port",
            f"grblsim://?baud=0&record={rec}",
            "--banner-timeout",
            "0.3",
        ],
        input="n\n",
    )
    assert result.exit_code != 0
    assert "The machine moves: board clamped" in result.output
    assert not _received_gcode(read_record(rec))


def test_refuses_job_outside_soft_limits_cli(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    write_job(job, 5)
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "stream",
                str(job),
                "--port",
                "grblsim://?baud=0&soft_limits=1&homed=1",
                "--yes",
                "--banner-timeout",
                "0.3",
            ]
        )
    assert exc.value.code == 2
    assert "soft limits allow" in capsys.readouterr().err


def test_executed_guess_distances(tmp_path):
    # the hold position lies on the 3rd move: the two before ran, the 3rd did not finish
    job = tmp_path / "job.gcode"
    job.write_text("G21G90\nG1X1F100\nG1X2\nG1X3\nG1X4\n")
    prog = load_program(job).placed_at((0.0, 0.0))  # streamed from work X0 Y0
    s = Streamer.__new__(Streamer)
    s.info = ControllerInfo()
    s._program = prog
    s._acked_blocks = [0, 1, 2, 3, 4]
    s._acks_at_status = 5
    assert s._executed_guess(Status(wpos=(2.5, 0.0, 0.0))) == 2
    assert s._executed_guess(Status(wpos=(4.0, 0.0, 0.0))) == 4
    assert s._executed_guess(None) == -1
    assert math.isclose(prog.total_seconds, 4 / 100 * 60)
    # from a start the sender was not told, (2.5, 0) may lie on the first move
    s._program = load_program(job)
    assert s._executed_guess(Status(wpos=(2.5, 0.0, 0.0))) == 0


def test_executed_guess_does_not_look_past_a_move_whose_path_it_cannot_check(tmp_path):
    # stopped at (15, 5), the top of the arc from (10, 0) to (20, 0) about (15, 0): the
    # move after the arc, (20, 0) to (10, 10), passes there too, but had not run
    job = tmp_path / "job.gcode"
    job.write_text("G21G90\nG0Z1\nG0X0Y0\nG1X10F100\nG2X20Y0I5J0\nG1X10Y10\nG1X0Y10\n")
    prog = load_program(job).placed_at((0.0, 0.0))
    s = Streamer.__new__(Streamer)
    s.info = ControllerInfo()
    s._program = prog
    s._all_ran = False
    s._acked_blocks = list(range(len(prog.blocks)))
    s._acks_at_status = len(prog.blocks)
    # the arc (block 4) may not have run
    assert s._executed_guess(Status(wpos=(15.0, 5.0, 1.0))) == 3
    assert s._executed_guess(Status(wpos=(15.0, 5.0 + 1e-9, 1.0))) == 3
    # past the arc: its path is not checked
    assert s._executed_guess(Status(wpos=(5.0, 10.0, 1.0))) == 3
    assert s._executed_guess(Status(wpos=(5.0, 0.0, 1.0))) == 2  # before it: on the G1 X10


def test_executed_guess_ignores_blocks_acknowledged_after_the_report(tmp_path):
    # 30 one-mm moves, then back over the same line: an old report at X0.5 lies on the 1st
    # move and on the last; only the 1st had been acknowledged when the report came
    job = tmp_path / "job.gcode"
    job.write_text("G21G90\n" + "".join(f"G1X{k}F100\n" for k in range(1, 31)) + "G1X0\n")
    prog = load_program(job)
    s = Streamer.__new__(Streamer)
    s.info = ControllerInfo()
    s._program = prog
    s._acked_blocks = list(range(len(prog.blocks)))
    s._acks_at_status = 2
    window_start = s._executed_guess(None)
    assert window_start < 31
    # no match: the earliest candidate
    assert s._executed_guess(Status(wpos=(0.5, 0.0, 0.0))) == window_start
    s._acks_at_status = len(prog.blocks)  # a fresh report: the return move is the match
    assert s._executed_guess(Status(wpos=(0.5, 0.0, 0.0))) == 30


def test_rapid_time_estimate_per_axis_and_retimed(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("G21G90\nG0X30Y40\nG1X0F600\nG4P0.5\nG0Z-6\nG20\nG0X1\n")
    prog = load_program(job, rapid_mm_min=(600.0, 300.0, 100.0))
    # the slowest axis sets a G0's time: Y 40 mm at 300, Z 6 at 100, X 25.4 - 0 at 600
    assert [round(b.seconds, 6) for b in prog.blocks] == [0.0, 8.0, 3.0, 0.5, 3.6, 0.0, 2.54]
    other = (1000.0, 2000.0, 50.0)
    retimed = prog.at_rapid_rates(other)
    fresh = load_program(job, rapid_mm_min=other)
    assert [b.seconds for b in retimed.blocks] == pytest.approx([b.seconds for b in fresh.blocks])
    assert retimed.blocks[1].seconds == pytest.approx(30 / 1000 * 60)  # now X is slowest
    assert [b.text for b in retimed.blocks] == [b.text for b in prog.blocks]


# --------------------------------------------------------------------------- journal safety

SIM = "grblsim://?baud=0&time_scale=0&$130=300&$131=180&$132=45"


def _no_connection(rec: Path) -> bool:
    """True if the emulator at ``grblsim://...&record=rec`` was never opened (no record)."""
    return not rec.exists()


@pytest.mark.parametrize("resume", [False, True])
@pytest.mark.parametrize("how", ["same", "relative", "hardlink"])
def test_journal_refuses_the_gcode_file(tmp_path, monkeypatch, capsys, how, resume):
    job = tmp_path / "export" / "board.gcode"
    job.parent.mkdir()
    write_job(job, 3)
    before = job.read_bytes()
    journal = {"same": job, "relative": Path("export/../export/board.gcode")}.get(how)
    if how == "hardlink":
        journal = tmp_path / "link.jsonl"
        journal.hardlink_to(job)
    monkeypatch.chdir(tmp_path)
    rec = tmp_path / "rec.jsonl"
    args = ["stream", str(job), "--port", f"{SIM}&record={rec}", "--yes", "--journal"]
    with pytest.raises(SystemExit) as exc:
        main([*args, str(journal), *(["--resume"] if resume else [])])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err == f"error: {journal}: is the G-code file being streamed; refusing to write the " \
        "journal into it (give --journal another file)\n"  # fmt: skip
    assert job.read_bytes() == before
    assert _no_connection(rec)
    assert not (tmp_path / "stream").exists()


@pytest.mark.parametrize(
    "content",
    [
        b"[board]\nwidth_mm = 120.0\nheight_mm = 80.0\n",  # a design TOML
        b"G21 G90\nG0 Z2\n",  # another G-code file
        b'{"ev":"ack","i":0,"line":2}\n{"ev":"start"}\n',  # JSON, but not our first line
        b'{"ev":"start","sha256":"ab"',  # a start line without its end
        b"\x89PNG\r\n\x1a\n\x00\x00",  # binary
        b"\n",
    ],
)
def test_journal_refuses_an_existing_file_that_is_not_a_journal(tmp_path, capsys, content):
    job = tmp_path / "job.gcode"
    write_job(job, 3)
    other = tmp_path / "design.toml"
    other.write_bytes(content)
    rec = tmp_path / "rec.jsonl"
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", f"{SIM}&record={rec}", "--yes",
              "--journal", str(other)])  # fmt: skip
    assert exc.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"error: {other}: exists and is not a stream journal (its first line is not a start "
        "event); refusing to append to it (give --journal a new file or an existing journal)"
    ]
    assert other.read_bytes() == content
    assert _no_connection(rec)
    with pytest.raises(ConfigError, match="is not a stream journal"):
        Journal(other).open()  # the writer itself refuses too
    assert other.read_bytes() == content


def test_journal_appends_to_an_empty_file_or_a_journal(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 3)
    journal = tmp_path / "j.jsonl"
    journal.touch()
    rec = tmp_path / "r.jsonl"
    for k in range(2):
        main(["stream", str(job), "--port", f"{SIM}&record={rec}", "--yes",
              "--journal", str(journal)])  # fmt: skip
        events = read_journal(journal)
        assert [e["ev"] for e in events].count("start") == k + 1
        assert events[-1] == {"ev": "end", "complete": True, "time": events[-1]["time"]}


@pytest.fixture(scope="module")
def interrupted_run(tmp_path_factory):
    """A 40-stroke job whose stream lost its link at block 150, and its journal's bytes."""
    folder = tmp_path_factory.mktemp("interrupted")
    job = folder / "job.gcode"
    write_job(job, 40)
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", f"{SIM}&disconnect_after=150", "--yes"])
    assert exc.value.code == 3
    journal = default_journal_path(job)
    return job, journal.read_bytes()


def _set(key, value):
    def edit(ev):
        ev[key] = value

    edit.__name__ = f"{key}={json.dumps(value)}"  # the test id
    return edit


def _drop(key):
    def edit(ev):
        del ev[key]

    edit.__name__ = f"no-{key}"
    return edit


def _ACK(ev):
    return ev["ev"] == "ack" and ev.get("i") == 20


def _LOST(ev):
    return ev["ev"] == "lost"


def _START(ev):
    return ev["ev"] == "start"


@pytest.mark.parametrize(
    ("which", "edit", "key"),
    [
        (_ACK, _set("i", None), "i"),
        (_ACK, _set("i", "x"), "i"),
        (_ACK, _set("i", "20"), "i"),
        (_ACK, _set("i", -5), "i"),
        (_ACK, _set("i", 1.5), "i"),
        (_ACK, _set("i", 20.0), "i"),
        (_ACK, _set("i", True), "i"),
        (_ACK, _set("i", 203), "i"),  # the job has 203 blocks: 0..202
        (_ACK, _set("i", [20]), "i"),
        (_ACK, _drop("i"), "i"),
        (_ACK, _set("pre", 0), "i"),  # both kinds of ack at once
        (_ACK, _set("ev", "ackk"), "ev"),
        (_ACK, _drop("ev"), "ev"),
        (_LOST, _set("executed_through", "x"), "executed_through"),
        (_LOST, _set("executed_through", 7.5), "executed_through"),
        (_LOST, _set("executed_through", -2), "executed_through"),
        (_LOST, _set("executed_through", 203), "executed_through"),
        (_LOST, _drop("executed_through"), "executed_through"),
        (_LOST, _set("ev", "lsot"), "ev"),
        (_START, _set("blocks", "203"), "blocks"),
        (_START, _set("blocks", 203.5), "blocks"),
        (_START, _set("blocks", -1), "blocks"),
        (_START, _drop("blocks"), "blocks"),
        (_START, _set("resume", "no"), "resume"),
        (_START, _set("sha256", None), "sha256"),
    ],
)
def test_resume_refuses_a_damaged_journal_naming_line_and_key(
    tmp_path, capsys, interrupted_run, which, edit, key
):
    gcode, saved = interrupted_run
    job = tmp_path / "job.gcode"
    job.write_bytes(gcode.read_bytes())
    events = [json.loads(line) for line in saved.decode().splitlines()]
    line = next(k for k, ev in enumerate(events, start=1) if which(ev))
    edit(events[line - 1])
    journal = default_journal_path(job)
    damaged = "".join(json.dumps(ev) + "\n" for ev in events).encode()
    journal.write_bytes(damaged)
    rec = tmp_path / "rec.jsonl"
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", f"{SIM}&record={rec}", "--yes", "--resume"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(f"error: {journal}:{line}: ")
    assert f"'{key}'" in err and "expected" in err
    assert journal.read_bytes() == damaged
    assert _no_connection(rec)


def test_read_journal_checks_only_what_can_still_count(tmp_path):
    """Damage before the last fresh start cannot change a resume; a complete last line
    that is not JSON is damage, a cut-off one is a crash and is skipped."""
    events = [
        {"ev": "start", "sha256": "a", "blocks": 5, "resume": False},
        {"ev": "ack", "i": "damaged"},
        {"ev": "start", "sha256": "a", "blocks": 5, "resume": False},
        {"ev": "ack", "i": 0},
        {"ev": "lost", "reason": "connection lost", "executed_through": None},
    ]
    path = tmp_path / "j.jsonl"
    text = "".join(json.dumps(ev) + "\n" for ev in events)
    path.write_text(text + '{"ev":"ack","i"')
    assert read_journal(path) == events
    assert done_blocks(read_journal(path), "a", path) == {0}
    path.write_text(text + "garbage\n")
    with pytest.raises(ConfigError, match=rf"j.jsonl:{len(events) + 1}: not a journal line"):
        read_journal(path)
    path.write_text(text[text.index("\n") + 1 :])
    with pytest.raises(ConfigError, match=r"j.jsonl:1: 'ev': expected \"start\""):
        read_journal(path)
    events[2]["resume"] = True  # the damaged line now belongs to the runs that count
    path.write_text("".join(json.dumps(ev) + "\n" for ev in events))
    with pytest.raises(ConfigError, match=r"j.jsonl:2: 'i': expected an integer 0\.\.4"):
        read_journal(path)


# --------------------------------------------------------------------------- options


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--stall-timeout", "nan"),
        ("--stall-timeout", "inf"),
        ("--stall-timeout", "-1"),
        ("--stall-timeout", "0"),
        ("--banner-timeout", "0"),
        ("--banner-timeout", "-3"),
        ("--banner-timeout", "nan"),
        ("--baud", "0"),
        ("--baud", "-9600"),
        ("--baud", "115200.5"),
        ("--z-threshold", "nan"),
        ("--z-threshold", "-inf"),
        ("--margin", "-1"),
    ],
)
@pytest.mark.parametrize("resume", [False, True])
def test_stream_refuses_bad_option_values(tmp_path, capsys, interrupted_run, option, value, resume):
    gcode, saved = interrupted_run
    job = tmp_path / "job.gcode"
    job.write_bytes(gcode.read_bytes())
    default_journal_path(job).write_bytes(saved)
    rec = tmp_path / "rec.jsonl"
    args = ["stream", str(job), "--port", f"{SIM}&record={rec}", "--yes", f"{option}={value}"]
    with pytest.raises(SystemExit) as exc:
        main(args + (["--resume"] if resume else []))
    assert exc.value.code == 2
    assert f"Invalid value for '{option}'" in capsys.readouterr().err
    assert _no_connection(rec)
    assert default_journal_path(job).read_bytes() == saved


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--slow", "nan"),
        ("--slow", "-0.5"),
        ("--time-scale", "nan"),
        ("--time-scale", "inf"),
        ("--time-scale", "-1"),
        ("--error-at", "-1"),
        ("--disconnect-after", "-3"),
        ("--baud", "0"),
    ],
)
def test_grbl_sim_refuses_bad_option_values(capsys, option, value):
    with pytest.raises(SystemExit) as exc:
        main(["grbl-sim", "--pty", f"{option}={value}"])
    assert exc.value.code == 2
    err = capsys.readouterr()
    assert f"Invalid value for '{option}'" in err.err and err.out == ""  # no pty path printed


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("$999=1", "grbl-sim: $999: not a Grbl 1.1 setting"),
        ("bot=1", "grbl-sim: unknown key 'bot' (did you mean 'boot'?)"),
        ("$130=-5", "grbl-sim: $130: expected a number at least 0"),
        ("homed", "expected KEY=VALUE, got 'homed'"),
    ],
)
def test_grbl_sim_set_refuses_bad_pairs(capsys, extra, message):
    with pytest.raises(SystemExit) as exc:
        main(["grbl-sim", "--pty", "--set", extra])
    assert exc.value.code == 2
    err = capsys.readouterr()
    assert message in err.err and err.out == "" and "Traceback" not in err.err


def test_grbl_sim_set_reaches_the_emulator(monkeypatch, capsys):
    """--set takes what a grblsim:// URL takes; the options above still apply."""
    seen = []

    class FakePty:
        path = "/dev/pts/fake"
        sim = SimpleNamespace(record=[], overruns=0)

        def __init__(self, options):
            seen.append(options)

        def start(self):
            return self

        def close(self):
            pass

    class Quit:
        def wait(self, timeout):
            raise KeyboardInterrupt

    monkeypatch.setattr("scratchfab.machine.grblsim_pty.GrblPty", FakePty)
    monkeypatch.setattr("scratchfab.cli.stream_cmd.threading.Event", Quit)
    main(["grbl-sim", "--pty", "--slow", "0.25", "--set", "$130=300", "--set", "wco=1,2,3"])
    (options,) = seen
    assert options.settings == {130: 300.0}
    assert options.wco == (1.0, 2.0, 3.0) and options.slow == 0.25 and options.baud == 115200
    assert capsys.readouterr().out == "/dev/pts/fake\n"


def test_resume_refuses_a_z_threshold_that_finds_no_stroke(tmp_path, capsys, interrupted_run):
    gcode, saved = interrupted_run
    job = tmp_path / "job.gcode"
    job.write_bytes(gcode.read_bytes())
    default_journal_path(job).write_bytes(saved)
    rec = tmp_path / "rec.jsonl"
    args = ["stream", str(job), "--port", f"{SIM}&record={rec}", "--yes", "--resume"]
    with pytest.raises(SystemExit) as exc:
        main([*args, "--z-threshold", "-1000"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "no stroke has the tool below the Z threshold -1000 (the job uses Z -0.05..2)" in err
    assert _no_connection(rec)
    # why: without strokes the resume point is the first block not done, inside a cut
    low, normal = load_program(job, z_threshold=-1000), load_program(job)
    assert not low.strokes
    first, last = normal.strokes[10]
    done = set(range(first + 2))  # the plunge and the first cutting move
    assert resume_point(normal, done) == first
    assert resume_point(low, done) == first + 2 <= last
    main([*args, "--z-threshold", "1"])  # between cutting and travel: resumes at a stroke
    assert "resuming at line" in capsys.readouterr().out


# --------------------------------------------------------------------------- work offset


@pytest.mark.parametrize("wco_field", [True, False])
def test_soft_limit_check_reads_the_work_offset(tmp_path, wco_field):
    """The offset comes from $# (not the first report, which may lack WCO:) and is used."""
    job = tmp_path / "job.gcode"
    write_job(job, 5)  # X, Y in -30..30, Z -0.05..2: fits only under a negative offset
    prog = load_program(job)
    lo, hi = job_extent(prog)
    for offset, fits in (("-100,-100,-10", True), ("0,0,0", False)):
        query = f"soft_limits=1&homed=1&wco={offset}&wco_field={int(wco_field)}"
        port = open_port(f"grblsim://?baud=0&time_scale=0&{query}", 115200)
        try:
            streamer = Streamer(port, FAST)
            info = streamer.connect()
            assert info.wco == tuple(float(v) for v in offset.split(","))
            assert info.wco_source == "$#"
            found = compare(info.settings, info.wco, prog)
            journal = Journal(tmp_path / f"{offset}.jsonl").open()
            try:
                streamer.stream(prog, journal)  # the emulator's soft limits are the reference
                alarm = None
            except StreamFault as exc:
                alarm = str(exc)
            finally:
                journal.close()
        finally:
            port.close()
        inside = all(-200 <= lo[k] + info.wco[k] and hi[k] + info.wco[k] <= 0 for k in range(3))
        assert inside == fits
        assert (alarm is None) == fits and (not found.refusals) == fits
        if not fits:
            assert "ALARM:2" in (alarm or "") and "soft limits allow" in found.refusals[0]


class _NoParams:
    """A port to a firmware that refuses ``$#`` (error:3), as a build without it would."""

    def __init__(self, port):
        self.port = port

    def write(self, data: bytes) -> int | None:
        return self.port.write(data.replace(b"$#\n", b"$Y\n"))

    def __getattr__(self, name):
        return getattr(self.port, name)

    def __setattr__(self, name, value):
        if name == "port":
            object.__setattr__(self, name, value)
        else:
            setattr(self.port, name, value)


def test_an_unknown_work_offset_is_refused_under_soft_limits(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 5)
    prog = load_program(job)
    said: list[str] = []
    for wco_field, expect in ((1, (-100.0, -100.0, -10.0)), (0, None)):
        rec = tmp_path / f"rec{wco_field}.jsonl"
        url = f"grblsim://?baud=0&soft_limits=1&homed=1&wco=-100,-100,-10&wco_field={wco_field}"
        port = open_port(f"{url}&record={rec}", 115200)
        try:
            info = Streamer(_NoParams(port), FAST, on_message=said.append).connect()
        finally:
            port.close()
        assert any(e["ev"] == "rx" and e["text"] == "$Y" for e in read_record(rec))
        assert info.wco == expect  # polled from the status reports where they carry WCO:
        found = compare(info.settings, info.wco, prog)
        if expect is None:
            assert any("work offset could not be read" in r for r in found.refusals)
        else:
            assert not found.refusals
    assert any("cannot read the work offsets with $#" in s for s in said)
    # without soft limits there is nothing to check the offset against
    assert not compare({20: 0, 22: 0}, None, prog).refusals


# --------------------------------------------------------------------------- strokes of real jobs


def _profile_job(tmp_path: Path, name, n: int = 30, seed: int = 3, box=None, stem=None):
    """G-code from the exporter for ``n`` random strokes inside profile ``name``'s envelope
    (a bundled name, a file or a loaded profile), 20 mm in from its edges, or in ``box``
    ((lo, hi) corners); written to ``stem``.gcode (default: ``name``)."""
    from scratchfab.export.gcode import gcode_lines
    from scratchfab.toolpath.plan import Toolpath

    profile = load_profile(name)
    env = profile.envelope
    rng = np.random.default_rng(seed)
    lo = np.array([env.x_mm[0], env.y_mm[0]]) + 20.0
    hi = np.array([env.x_mm[1], env.y_mm[1]]) - 20.0
    if box is not None:
        lo, hi = (np.array(corner, float) for corner in box)
    a = rng.uniform(lo, hi, (n, 2))
    strokes = np.stack([a, a + rng.uniform(-5.0, 5.0, (n, 2))], axis=1).round(3)
    outline = np.array([lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]])
    tp = Toolpath(strokes, np.arange(n), (100.0, 100.0), outline, profile, {})
    path = tmp_path / f"{stem or name}.gcode"
    path.write_text("\n".join(gcode_lines(tp)) + "\n")
    return path, tp


@pytest.mark.parametrize("name", ["grbl-3018-diamond", "grbl-plotter-scribe"])
def test_strokes_of_both_profiles_found_without_a_profile(tmp_path, name):
    path, tp = _profile_job(tmp_path, name)
    prog = load_program(path)  # no threshold given: read from the program
    profile = tp.profile
    assert prog.pen_mode == (profile.tool_control.mode == "servo")
    assert len(prog.strokes) == len(tp)
    for (first, last), (a, b) in zip(prog.strokes, tp.strokes, strict=True):
        cuts = [
            blk
            for blk in prog.blocks[first : last + 1]
            if blk.motion
            and blk.modal.motion == "G1"
            and blk.modal.feed == profile.feeds.engrave_mm_min
        ]
        assert len(cuts) == 1  # exactly the stroke's cutting move, from a to b
        assert (cuts[0].modal.x, cuts[0].modal.y) == pytest.approx(tuple(b), abs=1e-9)
        before = prog.blocks[first - 1].modal
        assert (before.x, before.y) == pytest.approx(tuple(a), abs=1e-9)
    if profile.tool_control.mode != "servo":  # the profile's own threshold agrees
        mid = 0.5 * (profile.z.safe_mm + profile.z.engrave_mm)
        assert load_program(path, z_threshold=mid).strokes == prog.strokes
    # resuming after half of stroke 10: at stroke 10, the tool up and travelling as the job does
    first = prog.strokes[10][0]
    assert resume_point(prog, set(range(first + 1))) == first
    pre = resume_preamble(prog, first)
    moves = [t for t in pre if "X" in t or "Z" in t]
    assert moves and moves[-1].endswith(f"X{tp.strokes[10, 0, 0]:g}Y{tp.strokes[10, 0, 1]:g}")
    travel = profile.feeds.travel_mm_min
    if travel is None:
        assert all(t.startswith("G0") for t in moves)
    else:  # the plotter travels with G1 at its travel feed, never G0
        assert all(t.startswith(f"G1F{travel:g}") for t in moves)


def test_resume_outside_a_job_folder_finds_the_stroke_without_machine(tmp_path, capsys):
    path, tp = _profile_job(tmp_path, "grbl-3018-diamond", n=40)
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(path), "--port", f"{SIM}&disconnect_after=100", "--yes"])
    assert exc.value.code == 3
    capsys.readouterr()
    journal = default_journal_path(path)
    saved = journal.read_bytes()
    lines = {}
    for machine in ([], ["--machine", "grbl-3018-diamond"]):
        journal.write_bytes(saved)
        rec = tmp_path / "rec.jsonl"
        main(["stream", str(path), "--port", f"{SIM}&record={rec}", "--yes", "--resume", *machine])
        out = capsys.readouterr().out
        said = next(ln for ln in out.splitlines() if ln.startswith("resuming at line"))
        lines[bool(machine)] = said.split(";")[0]
        prog = load_program(path)
        done = len([s for s in prog.strokes if prog.blocks[s[1]].lineno < int(said.split()[3])])
        assert f"({done} of {len(tp)} strokes done)" in said and done >= 20
    assert lines[False] == lines[True]


def test_a_machine_coordinate_profile_refuses_a_work_offset(tmp_path, capsys):
    """G54 zeroed on the board under the 3018's machine-coordinate profile: refused, with
    soft limits and homing off, before any line of the job is sent."""
    path, _ = _profile_job(tmp_path, "grbl-3018-diamond", n=10)
    first = load_program(path).blocks[0].text
    for wco, refused in (("-220,-150,-30", True), ("0,0,0.002", False)):
        rec = tmp_path / f"rec{refused}.jsonl"
        args = ["stream", str(path), "--machine", "grbl-3018-diamond", "--yes"]
        main_args = [*args, "--port", f"{SIM}&wco={wco}&record={rec}"]
        if refused:
            with pytest.raises(SystemExit) as exc:
                main(main_args)
            assert exc.value.code == 2
        else:
            main(main_args)  # 2 report digits: within the offset tolerance, streamed
        err = capsys.readouterr().err
        sent = [e["text"] for e in read_record(rec) if e["ev"] == "rx"]
        assert ("work offset is X-220 Y-150 Z-30 mm" in err) == refused
        assert (first in sent) == (not refused)
        assert "G10 L2 P0 X0 Y0 Z0 for the work system in use, G92.1, G49" in err or not refused


@pytest.mark.parametrize(
    ("settings", "wco", "refused", "warned"),
    [
        ({20: 0, 22: 1}, (-100.0, -100.0, -10.0), False, False),  # fits the homed travel
        ({20: 0, 22: 1}, (0.0, 0.0, 0.0), True, False),  # positive X, Y, Z: past the ends
        ({20: 0, 22: 0}, (0.0, 0.0, 0.0), False, False),  # not homed: nothing to check against
        ({20: 0, 22: 1}, None, False, True),  # homed, offset unknown: said, not refused
        ({20: 1, 22: 1}, None, True, False),  # soft limits on, offset unknown: refused
    ],
)
def test_the_homed_travel_is_checked_with_soft_limits_off(tmp_path, settings, wco, refused, warned):
    job = tmp_path / "job.gcode"
    write_job(job, 5)  # X, Y in -30..30, Z -0.05..2
    travel = {130: 200.0, 131: 200.0, 132: 200.0}
    found = compare({**settings, **travel}, wco, load_program(job))
    assert bool(found.refusals) == refused
    assert any("not checked against the travel" in w for w in found.warnings) == warned
    if refused and wco is not None:
        assert all("the travel after homing is -200..0" in r for r in found.refusals)


def test_a_machine_coordinate_profile_refuses_an_unknown_offset(tmp_path):
    path, tp = _profile_job(tmp_path, "grbl-3018-diamond", n=5)
    found = compare({20: 0, 22: 0}, None, load_program(path), tp.profile)
    (refusal,) = found.refusals
    assert "written in GRBL machine coordinates" in refusal and "could not be read" in refusal
    work = replace(tp.profile, envelope=replace(tp.profile.envelope, coordinates="work"))
    assert compare({20: 0, 22: 0}, None, load_program(path), work).refusals == []


def test_resume_refuses_when_the_program_does_not_show_which_z_cuts(tmp_path, capsys):
    job = tmp_path / "job.gcode"  # feed moves only, at three Z levels: which one cuts?
    job.write_text("G21G90\nG1Z1F300\nG1X1Y1\nG1Z0\nG1X2\nG1Z-1\nG1X3\nG1Z1\nG1X4\n")
    prog = load_program(job)
    assert prog.z_threshold is None and prog.strokes == [] and not prog.pen_mode
    default_journal_path(job).write_text(
        json.dumps({"ev": "start", "sha256": prog.sha256, "resume": False, "blocks": 9}) + "\n"
    )
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", SIM, "--yes", "--resume"])
    assert exc.value.code == 2
    assert "cannot tell from the program which Z cuts" in capsys.readouterr().err


def test_stream_help_shows_no_empty_range():
    from click.testing import CliRunner

    from scratchfab.cli import cli

    out = CliRunner().invoke(cli, ["stream", "--help"], terminal_width=200).output
    assert "--z-threshold" in out and "None" not in out


# --------------------------------------------------------------------------- crash safety


class _Tripwire:
    """A port that raises ``exc`` from ``read`` once armed (a Ctrl-C at the worst moment)."""

    def __init__(self, port):
        object.__setattr__(self, "_port", port)
        object.__setattr__(self, "armed", None)

    def read(self, size=1):
        exc = self.armed
        if exc is not None:
            object.__setattr__(self, "armed", None)
            raise exc
        return self._port.read(size)

    def __getattr__(self, name):
        return getattr(self._port, name)

    def __setattr__(self, name, value):
        if name == "armed":
            object.__setattr__(self, name, value)
        else:
            setattr(self._port, name, value)


def _held_then_reset(record) -> None:
    """Feed hold, then a soft reset, and nothing cut after the reset."""
    hold = next(e["t"] for e in record if e["ev"] == "rt" and e["ch"] == ord("!"))
    resets = [e["t"] for e in record if e["ev"] == "reset" and e["t"] >= hold]
    assert resets, "no soft reset after the feed hold"
    assert not [e for e in record if e["ev"] == "exec" and e["t"] > resets[0] + 1e-6]


_fire_after = interrupt_after


@pytest.mark.parametrize("answer", ["abort", "eof", "second_ctrl_c"])
def test_a_failed_prompt_after_ctrl_c_still_stops_safely(tmp_path, answer):
    """click.prompt raises Abort for a second Ctrl-C or a closed stdin: stop, never stay held."""
    import click

    job = tmp_path / "job.gcode"
    write_job(job, 40)
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"

    def ask():
        raise {
            "abort": click.exceptions.Abort(),
            "eof": EOFError(),
            "second_ctrl_c": (KeyboardInterrupt()),
        }[answer]

    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    try:
        with pytest.raises(StreamStopped):
            stream_program(port, prog, journal, on_progress=_fire_after(60), ask_interrupt=ask)
    finally:
        port.close()
    _held_then_reset(port.sim.record)
    assert read_journal(journal)[-1]["ev"] == "stop"


def test_ctrl_c_while_waiting_for_the_hold_still_resets(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"
    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    trip = _Tripwire(port)

    def ask():
        trip.armed = KeyboardInterrupt()  # the next read, in the wait for Hold:0
        return "stop"

    try:
        with pytest.raises(KeyboardInterrupt):
            stream_program(trip, prog, journal, on_progress=_fire_after(60), ask_interrupt=ask)
    finally:
        port.close()
    _held_then_reset(port.sim.record)
    last = read_journal(journal)[-1]
    assert last["ev"] == "stop" and "KeyboardInterrupt" in last["reason"]


class _FullDiskJournal(Journal):
    """A journal whose disk fills after ``room`` writes."""

    room = 80

    def write(self, event, **data):
        if event == "ack":
            self.room -= 1
            if self.room < 0:
                raise OSError(28, "No space left on device")
        super().write(event, **data)


def test_a_journal_write_error_stops_the_machine(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        journal = _FullDiskJournal(tmp_path / "j.jsonl").open()
        with pytest.raises(OSError, match="No space left"):
            streamer.stream(prog, journal)
        journal.close()
    finally:
        port.close()
    assert any(e["ev"] == "rt" and e["ch"] == ord("!") for e in port.sim.record)
    _held_then_reset(port.sim.record)


def test_ctrl_c_in_check_mode_leaves_check_mode(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.02", 115200)
    trip = _Tripwire(port)
    try:
        streamer = Streamer(trip, FAST)
        streamer.connect()
        sent = []
        original = port.write

        def write(data):
            sent.append(data)
            if len(sent) == 30:
                trip.armed = KeyboardInterrupt()
            return original(data)

        trip._port.write = write  # type: ignore[method-assign]
        with pytest.raises(KeyboardInterrupt):
            streamer.check(prog)
        assert streamer._status_now().state == "Idle"
    finally:
        port.close()
    record = port.sim.record
    enabled = next(e["t"] for e in record if e["ev"] == "state" and e["state"] == "Check")
    assert any(e["ev"] == "reset" and e["t"] > enabled for e in record)


class _Killed(Exception):
    pass


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_sigterm_and_sighup_stop_the_stream_safely(tmp_path, signame):
    """An ssh drop (SIGHUP) or a kill (SIGTERM) holds and resets like Ctrl-C's stop."""
    import os
    import signal

    signum = getattr(signal, signame)

    def outer(signum, frame):
        raise _Killed  # what the old sender did: die at once (without killing pytest)

    job = tmp_path / "job.gcode"
    write_job(job, 40)
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"
    asked, fired = [], []
    previous = signal.signal(signum, outer)
    try:
        port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
        try:
            with pytest.raises(StreamStopped, match=f"stopped by {signame} after line"):
                stream_program(
                    port,
                    prog,
                    journal,
                    on_progress=lambda p: (
                        p.acked > 60 and not fired and fired.append(os.kill(os.getpid(), signum))
                    ),
                    ask_interrupt=lambda: asked.append(1) or "resume",
                )
        finally:
            port.close()
        first_record = port.sim.record
        assert signal.getsignal(signum) is outer  # restored after the stream
        # check mode too
        port = open_port("grblsim://?baud=0&time_scale=0.02", 115200)
        try:
            streamer = Streamer(port, FAST)
            streamer.connect()
            streamer.on_message = lambda m: None
            original = port.write
            sent = []

            def write(data):
                sent.append(data)
                if len(sent) == 30:
                    os.kill(os.getpid(), signum)
                return original(data)

            port.write = write
            with pytest.raises(StreamStopped, match=f"check mode stopped by {signame}"):
                streamer.check(prog)
            port.write = original
            assert streamer._status_now().state == "Idle"
        finally:
            port.close()
        assert signal.getsignal(signum) is outer
    finally:
        signal.signal(signum, previous)
    assert not asked  # nobody may be at the terminal: no prompt
    _held_then_reset(first_record)
    assert read_journal(journal)[-1]["ev"] == "stop"


def test_a_stream_in_a_thread_installs_no_signal_handler(tmp_path):
    import threading

    job = tmp_path / "job.gcode"
    write_job(job, 5)
    prog = load_program(job)
    errors = []

    def run():
        port = open_port("grblsim://?baud=0&time_scale=0.001", 115200)
        try:
            stream_program(port, prog, tmp_path / "j.jsonl")
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)
        finally:
            port.close()

    th = threading.Thread(target=run)
    th.start()
    th.join(60)
    assert not errors
    assert read_journal(tmp_path / "j.jsonl")[-1]["ev"] == "end"


def test_a_killed_senders_unsure_acks_are_cut_again(tmp_path, capsys):
    """A session with no closing event (SIGKILL): its last planner-full of acks may never
    have run (the next connection resets the controller), so a resume cuts them again."""
    job = tmp_path / "job.gcode"
    cuts = write_job(job, 60)
    prog = load_program(job)
    journal = default_journal_path(job)
    rec1, rec2 = tmp_path / "r1.jsonl", tmp_path / "r2.jsonl"
    port = open_port(f"grblsim://?baud=0&time_scale=0.01&usb_powered=1&record={rec1}", 115200)
    streamer = Streamer(port, FAST)
    streamer.connect()
    j = Journal(journal).open()

    def die(p):
        if p.acked > 150:
            port.sim.drop_link()  # the host vanished; the reconnect resets the board
            raise SystemExit(137)

    streamer.on_progress = die
    # what SIGKILL leaves: the journal without a closing event
    streamer._stop_on_escape = lambda exc: None  # type: ignore[method-assign]
    with pytest.raises(SystemExit):
        streamer.stream(prog, j)
    j.close()
    port.close()
    events = read_journal(journal)
    assert events[-1]["ev"] == "ack" and events[0]["planner"] == 15
    acked = [e["i"] for e in events if e["ev"] == "ack"]
    done = done_blocks(events, prog.sha256, journal, program=prog)
    assert done < set(acked)
    assert done_blocks(events, prog.sha256, journal, program=prog, recut_unclosed=False) == set(
        acked
    )
    main(["stream", str(job), "--port", f"grblsim://?baud=0&time_scale=0.002&record={rec2}",
          "--resume", "--yes", "--banner-timeout", "0.3"])  # fmt: skip
    out = capsys.readouterr().out
    assert "ended without a stop" in out and "they are cut again" in out
    counts = cut_counts([read_record(rec1), read_record(rec2)], cuts)
    assert min(counts) == 1 and max(counts) <= 2


def test_connect_waits_for_a_controller_still_running_before_resetting(tmp_path):
    """Over a port without DTR reset a killed sender's queue keeps running: no reset mid-move."""
    with GrblPty(SimOptions(baud=0, time_scale=0.25)) as pty:
        first = serial.Serial(pty.path, 115200, timeout=2.0)
        # opening flushes input: the power-up banner may be gone, a soft reset sends another
        first.write(b"\x18")
        assert b"Grbl" in first.read_until(b"help]\r\n")
        # 3.6 s at 100 mm/min, scaled to 0.9 s: still moving on a busy machine's connect
        first.write(b"G21G90\nG1X6F100\n")
        time.sleep(0.3)
        first.close()
        said = []
        port = serial.Serial(pty.path, 115200, timeout=0.01)
        try:
            streamer = Streamer(port, FAST, on_message=said.append)
            info = streamer.connect()
        finally:
            port.close()
        record = pty.sim.record
    assert info.status.state == "Idle"
    assert any("still moving (Run)" in s for s in said)
    done = next(e["t"] for e in record if e["ev"] == "exec" and e["to"][0] == 6.0)
    reset = [e["t"] for e in record if e["ev"] == "reset"][-1]  # the connect's
    assert reset >= done
    assert not any(e["ev"] == "alarm" for e in record)


def test_a_torn_journal_line_is_ended_and_skipped_by_the_next_session(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 3)
    prog = load_program(job)
    path = tmp_path / "j.jsonl"
    j = Journal(path).open()
    j.start(prog, resume=False)
    j.write("ack", i=0, line=2)
    j.close()
    with open(path, "a") as handle:
        handle.write('{"ev":"ack","i":1,"li')  # a full disk tore the line
    for _ in range(2):  # every later resume appends as well
        j = Journal(path).open()
        j.start(prog, resume=True, start=1)
        j.write("ack", i=1, line=3)
        j.close()
    events = read_journal(path)
    assert [e["ev"] for e in events] == ["start", "ack", "start", "ack", "start", "ack"]
    with open(path, "a") as handle:
        handle.write('{"ev":"ack","i":1,"li\n{"ev":"ack","i":2}\n')  # not before a start
    with pytest.raises(ConfigError, match=rf"j.jsonl:{len(events) + 2}: not a journal line"):
        read_journal(path)


class _FullDisk:
    def __init__(self, handle, room):
        self.handle, self.room = handle, room

    def write(self, text):
        self.room -= 1
        if self.room < 0:
            self.handle.write(text[:7])  # a torn line
            raise OSError(28, "No space left on device")
        return self.handle.write(text)

    def __getattr__(self, name):
        return getattr(self.handle, name)


def test_a_full_disk_stops_safely_with_one_line_naming_the_journal(tmp_path, monkeypatch, capsys):
    job = tmp_path / "job.gcode"
    write_job(job, 40)
    journal = default_journal_path(job)
    rec = tmp_path / "r.jsonl"
    real_open = Journal.open

    def open_full(self):
        real_open(self)
        self._handle = _FullDisk(self._handle, 60)
        return self

    monkeypatch.setattr(Journal, "open", open_full)
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", f"grblsim://?baud=0&time_scale=0.01&record={rec}", "--yes",
              "--banner-timeout", "0.3"])  # fmt: skip
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"error: {journal}: cannot write the journal (No space left on device)" in err
    assert "Traceback" not in err
    _held_then_reset(read_record(rec))
    monkeypatch.undo()
    read_journal(journal)  # the torn last line is skipped
    main(["stream", str(job), "--port", "grblsim://?baud=0&time_scale=0.001", "--yes", "--resume",
          "--banner-timeout", "0.3"])  # fmt: skip
    assert read_journal(journal)[-1]["ev"] == "end"


def test_a_second_stream_of_the_same_job_or_port_is_refused(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    write_job(job, 3)
    rec = tmp_path / "r.jsonl"
    held = Journal(default_journal_path(job)).open()
    try:
        with pytest.raises(SystemExit) as exc:
            main(["stream", str(job), "--port", f"grblsim://?baud=0&record={rec}", "--yes"])
        assert exc.value.code == 2
    finally:
        held.close()
    err = capsys.readouterr().err
    assert f"another stream is using {default_journal_path(job)}" in err
    assert not rec.exists()  # refused before connecting
    with GrblPty(SimOptions()) as pty:
        first = open_port(pty.path, 115200)
        try:
            with pytest.raises(ScratchfabError, match=f"cannot open port '{pty.path}'"):
                open_port(pty.path, 115200)
        finally:
            first.close()
        open_port(pty.path, 115200).close()  # free again


def test_grbl_sim_pty_off_posix_is_one_line(monkeypatch, capsys):
    monkeypatch.setattr("scratchfab.cli.stream_cmd.os.name", "nt")
    with pytest.raises(SystemExit) as exc:
        main(["grbl-sim", "--pty"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "needs a POSIX pseudo-terminal" in err and "grblsim://" in err


# --------------------------------------------------------------------------- coverage review


def _feed_cuts(segments) -> list[tuple[float, ...]]:
    """Sorted (x0, y0, x1, y1) of XY feed moves, rounded to the exported decimals."""
    return sorted(tuple(round(v, 3) for v in (*a[:2], *b[:2])) for a, b in segments)


def test_resumed_spindle_job_dwells_before_it_moves(tmp_path):
    """The preamble's M3 is followed by the file's spin-up G4 before any move (the spindle
    is at speed before the plunge), and the resumed job cuts exactly the strokes left."""
    from test_export import spindle_profile

    from scratchfab.export import export
    from scratchfab.model.design import Board
    from scratchfab.model.scratches import ScratchSet
    from scratchfab.toolpath import plan_toolpath

    profile = spindle_profile()
    centres = np.random.default_rng(0).uniform(-15, 15, (6, 2))
    scratches = ScratchSet.from_arrays(centres - 1, centres + 1, 0.1, 0.01)
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    job = tmp_path / "spindle.gcode"
    export(plan_toolpath(scratches, board, profile), None, job)
    z_cut = 0.5 * (profile.z.safe_mm + profile.z.engrave_mm)
    prog = load_program(job, z_threshold=z_cut)
    assert len(prog.strokes) == 6
    dwells = [b for b in prog.blocks if b.text.startswith("G4")]
    assert [b.text for b in dwells] == [f"G4P{profile.tool_control.dwell_s:g}"]
    start = prog.strokes[2][0]
    pre = resume_preamble(prog, start)
    spindle_on = next(k for k, t in enumerate(pre) if t.startswith("M3"))
    dwell = pre.index(dwells[0].text)
    moves = [k for k, t in enumerate(pre) if t.startswith(("G0", "G1")) and ("X" in t or "Z" in t)]
    z_up = pre.index(f"G0Z{profile.z.safe_mm:g}")
    assert moves and min(moves) == z_up  # Z up first: the bit may be in the board
    moves = [k for k in moves if k != z_up]
    assert moves and z_up < spindle_on < dwell < min(moves)

    port = open_port("grblsim://?baud=0&time_scale=0.001", 115200)
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        journal = Journal(tmp_path / "j.jsonl").open()
        streamer.stream(prog, journal, start=start, preamble=pre, resume=True)
        journal.close()
    finally:
        port.close()
    record = port.sim.record
    received = _received_gcode(record)
    assert (
        received.index("M3S8000") < received.index(dwells[0].text) < received.index(pre[min(moves)])
    )
    cut = [
        (e["frm"], e["to"])
        for e in record
        if e["ev"] == "exec"
        and not e["rapid"]
        and max(e["frm"][2], e["to"][2]) < z_cut
        and e["frm"][:2] != e["to"][:2]
    ]
    expected = [
        ((prog.blocks[i - 1].modal.x, prog.blocks[i - 1].modal.y), (b.modal.x, b.modal.y))
        for first, last in prog.strokes[2:]
        for i, b in enumerate(prog.blocks[first : last + 1], start=first)
        if b.motion
        and b.modal.z is not None
        and b.modal.z < z_cut
        and (b.modal.x, b.modal.y) != (prog.blocks[i - 1].modal.x, prog.blocks[i - 1].modal.y)
    ]
    assert len(expected) == 4 and _feed_cuts(cut) == _feed_cuts(expected)


@pytest.mark.parametrize(
    ("setup", "dwell"),
    [
        (["M3 S12000", "M8", "G4 P2.25"], "G4P2.25"),  # the dwell need not follow M3 at once
        (["M3 S12000", "G0 X1", "G4 P2"], None),  # a dwell after a move is not a spin-up
        (["M4 S900"], None),  # the file did not dwell: neither does the resume
        (["M3 S100", "G4 P1", "M5"], None),  # spindle off again before the stroke
    ],
)
def test_resume_preamble_dwells_as_the_file_did(tmp_path, setup, dwell):
    job = tmp_path / "sp.gcode"
    strokes = ["G0 Z5", "G0 X1 Y1", "G1 Z-0.1 F200", "G1 X5 Y1 F600", "G0 Z5"]
    job.write_text("\n".join(["G21 G90", *setup, *strokes, *strokes[1:], "M5", "M2"]) + "\n")
    prog = load_program(job)
    pre = resume_preamble(prog, prog.strokes[1][0])
    dwells = [t for t in pre if t.startswith("G4")]
    assert dwells == ([dwell] if dwell else [])
    if dwell:
        assert pre[pre.index(dwell) - 1].startswith("M3")


def _executed_in_emulator(record, prog) -> int:
    """The last program block the emulator finished moving before its first reset."""
    reset = next(e["t"] for e in record if e["ev"] == "rt" and e["ch"] == 0x18)
    done = executed_blocks(record, until=reset)
    last = max(done)
    assert sorted(done) == list(range(1, last + 1))  # block 0 (G21 G90 ...) does not move
    return last


@pytest.mark.parametrize(
    "query",
    [
        "$13=0",
        "$13=1",  # GRBL reports inches
        "wco=5,7,1&wco_field=1",  # under a G54 offset, with status reports' WCO: field
        "wco=5,7,1&wco_field=0",  # a build without it: the $# offset read at connect
    ],
)
def test_stop_position_matches_the_emulator(tmp_path, query):
    """The hold position finds the interrupted block whatever the reports say, so the
    journal's executed-through is what the emulator ran (not the planner bound, which
    re-cuts finished strokes)."""
    from scratchfab.machine.sender_journal import last_surely_run

    job = tmp_path / "job.gcode"
    write_job(job, 40)
    prog = load_program(job)
    url = f"grblsim://?baud=0&time_scale=0.01&{query}"
    events, record = stopped_after(tmp_path / "j.jsonl", prog, 60, url)
    stop = events[-1]
    truth = _executed_in_emulator(record, prog)
    acked = [e["i"] for e in events if e["ev"] == "ack" and "i" in e]
    assert last_surely_run(prog.blocks, acked, 15) < truth  # the position decides here
    assert stop["executed_through"] == truth


_CLI = "import sys; from scratchfab.cli import main; main(sys.argv[1:])"


def _stream_on_a_terminal(args, interrupt_at=None, timeout=60.0):
    """``scratchfab stream ARGS`` with stdin, stdout and stderr on a pty; (exit code, text).

    ``interrupt_at``: once the output shows this many progress bars, Ctrl-C (SIGINT to the
    process group), then answer the prompt with ``s``.
    """
    import os
    import pty
    import select
    import signal
    import subprocess
    import sys

    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-c", _CLI, "stream", *args],
        stdin=slave,
        stdout=slave,
        stderr=slave,
        start_new_session=True,
    )
    os.close(slave)
    out = b""
    interrupted = answered = False
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.05)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # the slave side closed: the process ended
                    break
                if not data:
                    break
                out += data
            elif proc.poll() is not None:
                break
            if interrupt_at is not None and not interrupted and out.count(b"\r[") >= interrupt_at:
                os.killpg(proc.pid, signal.SIGINT)
                interrupted = True
            if interrupted and not answered and b"[r]esume or [s]top" in out:
                os.write(master, b"s\n")
                answered = True
        proc.wait(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    return proc.returncode, out.decode("ascii", "replace")


def _shown_lines(text: str) -> list[str]:
    """The lines a terminal ends up showing: each line's last redraw (after its last CR)."""
    shown = []
    for line in text.replace("\r\n", "\n").split("\n")[:-1]:
        parts = [p for p in line.split("\r") if p]
        shown.append(parts[-1].rstrip() if parts else "")
    return shown


def _assert_clean_lines(shown: list[str]) -> None:
    for line in shown:
        assert line, "an empty line"
        if line.startswith("["):  # a progress bar: nothing glued after its position
            assert re.fullmatch(
                r"\[[#.]{28}\] .* lines  elapsed \S+  ETA \S+  \S+( X\S+ Y\S+ Z-?\d+\.\d\d)?",
                line,
            )
        else:
            assert "lines  elapsed" not in line


def test_on_a_terminal_the_bar_ends_before_each_message(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 3)
    rc, text = _stream_on_a_terminal(
        [
            str(job),
            "--port",
            "grblsim://?baud=0&time_scale=0.001",
            "--yes",
            "--banner-timeout",
            "0.3",
        ]
    )
    assert rc == 0, text
    shown = _shown_lines(text)
    _assert_clean_lines(shown)
    assert shown[-1].startswith("done: 18 lines acknowledged")
    assert shown[-2].startswith("[") and " 100.0% 18/18 lines " in shown[-2]


def test_on_a_terminal_ctrl_c_asks_on_its_own_line_and_stops(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 400)  # about 4 s at this time scale: a loaded machine still interrupts it
    rc, text = _stream_on_a_terminal(
        [
            str(job),
            "--port",
            "grblsim://?baud=0&time_scale=0.02",
            "--yes",
            "--banner-timeout",
            "0.3",
        ],
        interrupt_at=3,
    )
    assert rc == 130, text
    shown = _shown_lines(text)
    _assert_clean_lines(shown)
    prompt = next(k for k, line in enumerate(shown) if "[r]esume or [s]top" in line)
    assert shown[prompt].startswith("machine held: ") and shown[prompt].endswith(": s")
    assert shown[prompt - 1] == "feed hold sent" and shown[prompt - 2].startswith("[")
    assert shown[-1].startswith("stopped by the user after line ")


def test_check_then_stream_ends_with_the_final_position(tmp_path, capsys):
    """Off a terminal the 100 % line waits for the end: the controller Idle where the job
    ended, not an earlier report's position."""
    job = tmp_path / "job.gcode"
    write_job(job, 20)
    main(
        [
            "stream",
            str(job),
            "--port",
            "grblsim://?baud=0&time_scale=0.01",
            "--yes",
            "--check",
            "--banner-timeout",
            "0.3",
        ]
    )
    err = capsys.readouterr().err.splitlines()
    assert "check mode: 103 lines, no errors" in err
    full = [line for line in err if "100.0%" in line]
    end = load_program(job).blocks[-1].modal
    where = f"  ETA 00:00  Idle X{end.x:.2f} Y{end.y:.2f} Z{end.z:.2f}"
    assert len(full) == 1 and re.fullmatch(
        r"100\.0% 103/103 lines  elapsed \d\d:\d\d" + re.escape(where), full[0]
    ), full
    assert err[-1] == full[0]


def test_declining_the_confirmation_sends_nothing(tmp_path):
    from click.testing import CliRunner

    job = tmp_path / "job.gcode"
    write_job(job, 2)
    rec = tmp_path / "rec.jsonl"
    with CliRunner().isolation(input="n\n") as (_, stderr, _):
        with pytest.raises(SystemExit) as exc:
            main(
                [
                    "stream",
                    str(job),
                    "--port",
                    f"grblsim://?baud=0&record={rec}",
                    "--banner-timeout",
                    "0.3",
                ]
            )
        err = stderr.getvalue().decode()
    assert exc.value.code == 2  # as `run` declining its stream stage; 130 is Ctrl-C's
    assert err.rstrip().endswith("error: not confirmed; nothing was sent")
    assert "aborted" not in err
    assert not _received_gcode(read_record(rec))
    assert not default_journal_path(job).exists()


def test_sigterm_stops_the_cli_stream_and_resume_finishes(tmp_path, capsys):
    """A kill (SIGTERM) of `scratchfab stream`: exit 130, one line naming the signal and the
    line, a stop in the journal; --resume then finishes every stroke."""
    import signal
    import subprocess
    import sys

    job = tmp_path / "job.gcode"
    cuts = write_job(job, 40)
    recs = [tmp_path / "r1.jsonl", tmp_path / "r2.jsonl"]
    journal = default_journal_path(job)
    common = ["--yes", "--banner-timeout", "0.3"]
    proc = subprocess.Popen(
        [sys.executable, "-c", _CLI, "stream", str(job), "--port",
         f"grblsim://?baud=0&time_scale=0.01&record={recs[0]}", *common],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and proc.poll() is None:
            if journal.is_file() and journal.read_text().count('"ev":"ack"') >= 30:
                break
            time.sleep(0.02)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert re.search(
        r"^stopped by SIGTERM after line \d+ \(the last one GRBL accepted; [^)]*\); machine held",
        err,
        re.M,
    )
    events = read_journal(journal)
    assert events[-1]["ev"] == "stop" and "SIGTERM" in events[-1]["reason"]
    main(["stream", str(job), "--port", f"grblsim://?baud=0&time_scale=0.001&record={recs[1]}",
          "--resume", *common])  # fmt: skip
    out = capsys.readouterr().out
    assert "resuming at line" in out and "done:" in out
    last = read_journal(journal)[-1]
    assert last["ev"] == "end" and last["complete"] is True
    counts = cut_counts([read_record(recs[0]), read_record(recs[1])], cuts)
    assert min(counts) == 1 and max(counts) <= 2


@pytest.mark.parametrize(
    ("content", "args", "message"),
    [
        (None, ["--resume"], "no journal to resume from (stream without --resume first)"),
        (b"", [], "job.gcode: no G-code lines to send"),
        (b"(only a comment)\n; and another\n%\n", [], "job.gcode: no G-code lines to send"),
        (b"G21\nG0 X1 (caf\xc3\xa9)\n", [], "job.gcode:2: non-ASCII byte in G-code"),
    ],
)
def test_refusals_before_connecting(tmp_path, capsys, content, args, message):
    job = tmp_path / "job.gcode"
    if content is None:
        write_job(job, 2)
    else:
        job.write_bytes(content)
    rec = tmp_path / "rec.jsonl"
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", f"grblsim://?baud=0&record={rec}", "--yes", *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and len(err.splitlines()) == 1
    assert not rec.exists()  # refused before connecting
    assert not default_journal_path(job).exists()


def test_a_jobs_gcode_is_checked_against_the_jobs_machine(tmp_path, capsys):
    from scratchfab.model.job import JobLayout

    layout = JobLayout(tmp_path / "job")
    gcode, tp = _profile_job(tmp_path, "grbl-3018-diamond", n=3)
    layout.export_file("gcode").parent.mkdir(parents=True)
    layout.toolpath_json.parent.mkdir(parents=True)
    gcode.replace(layout.export_file("gcode"))
    tp.save(layout.toolpath_json)
    main(["stream", str(layout.export_file("gcode")), "--port", SIM, "--yes"])
    err = capsys.readouterr().err
    assert f"checking against machine '{tp.profile.name}' of {layout.toolpath_json}" in err


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("G0 X1 ; see notes\x0b$RST=*\n", "control character '\\x0b'"),  # one line to GRBL
        ("G0 X1\nM3 S100\x18\n", "control character '\\x18'"),
        ("G0 X1\x0c\n", "control character '\\x0c'"),
        ("G21\n$RST=*\n", "'$RST=*': a GRBL system command"),
        ("G21\n$J=G91 X-500 F1000\n", "'$J=G91X-500F1000': a GRBL system command"),
        ("G21\n$H\n", "'$H': a GRBL system command"),
        ("G21\n$130=5\n", "'$130=5': a GRBL system command"),
        ("G21\n$N0=G0X0\n", "'$N0=G0X0': a GRBL system command"),
    ],
)
def test_lines_that_act_beyond_the_job_are_refused_before_connecting(tmp_path, text, message):
    job = tmp_path / "job.gcode"
    job.write_bytes(text.encode("ascii"))
    with pytest.raises(ConfigError) as err:
        load_program(job)
    assert str(err.value).startswith(f"{job}:") and message in str(err.value)


def test_lines_end_where_grbl_ends_them(tmp_path):
    """LF, CR or CRLF end a line, as in GRBL; read-only $ reports may stay in a job."""
    job = tmp_path / "job.gcode"
    job.write_bytes(b"G21 G90\r\nG0 X1\rG1 X2 F100\n$G\n\tG1 X3 (tab indented)\n")
    prog = load_program(job)
    assert [b.text for b in prog.blocks] == ["G21G90", "G0X1", "G1X2F100", "$G", "G1X3"]
    assert [b.lineno for b in prog.blocks] == [1, 2, 3, 4, 5]


_SCRIBE_RATES = "$110=5000&$111=5000&$112=500&$120=500&$121=500&$122=100&$130=300&$131=200&$132=2"
_3018_RATES = "$110=2000&$111=2000&$112=600&$120=100&$121=100&$122=50&$130=300&$131=180&$132=45"


def test_a_resumed_spindle_job_starts_the_spindle_only_above_the_board(tmp_path):
    """A stop can leave the bit in the board: the preamble raises Z to the safe height
    before M3 and its spin-up dwell, and moves in XY only after them."""
    from test_export import spindle_profile

    from scratchfab.export import export
    from scratchfab.model.design import Board
    from scratchfab.model.scratches import ScratchSet
    from scratchfab.toolpath import plan_toolpath

    profile = spindle_profile()
    centres = np.random.default_rng(1).uniform(-15, 15, (4, 2))
    scratches = ScratchSet.from_arrays(centres - 1, centres + 1, 0.1, 0.01)
    job = tmp_path / "spindle.gcode"
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    export(plan_toolpath(scratches, board, profile), None, job)
    prog = load_program(job, z_threshold=0.5 * (profile.z.safe_mm + profile.z.engrave_mm))
    start = prog.strokes[2][0]
    pre = resume_preamble(prog, start)
    # the stop left the bit at cutting depth, mid-stroke
    stuck = tmp_path / "stuck.gcode"
    stuck.write_text(f"G21 G90\nG1 Z{profile.z.engrave_mm:g} F200\n")
    rec = tmp_path / "rec.jsonl"
    port = open_port(f"grblsim://?baud=0&time_scale=0.001&record={rec}", 115200)
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        for program, kwargs in [
            (load_program(stuck), {}),
            (prog, {"start": start, "preamble": pre, "resume": True}),
        ]:
            journal = Journal(tmp_path / f"{program.path.stem}.jsonl").open()
            streamer.stream(program, journal, **kwargs)
            journal.close()
    finally:
        port.close()
    record = read_record(rec)
    z_at = None
    spindle_on = []
    for e in record:
        if e["ev"] in ("exec", "partial"):
            z_at = e["to"][2]
        elif e["ev"] == "spindle" and e["spindle"] == "M3":
            spindle_on.append((z_at, e["t"]))
    assert spindle_on and z_at is not None
    assert spindle_on[0][0] == pytest.approx(profile.z.safe_mm)  # not engrave_mm
    stuck_at = next(
        k for k, e in enumerate(record) if e["ev"] == "exec" and e["to"][2] == profile.z.engrave_mm
    )
    first_xy = next(
        e["t"]
        for e in record[stuck_at:]
        if e["ev"] in ("exec", "partial") and e["frm"][:2] != e["to"][:2]
    )
    assert first_xy >= spindle_on[0][1]


def test_a_resumed_servo_job_lifts_the_pen_before_any_move(tmp_path):
    job, _ = _profile_job(tmp_path, "grbl-plotter-scribe", n=6, seed=2)
    prog = load_program(job)
    assert prog.pen_mode and prog.strokes
    pre = resume_preamble(prog, prog.strokes[3][0])
    moves = [k for k, t in enumerate(pre) if t.startswith(("G0", "G1")) and "X" in t]
    assert moves and "M5" in pre[: min(moves)]
    assert not [t for t in pre if t.startswith(("M3", "M4"))]


def test_a_second_ctrl_c_while_stopping_after_an_error_still_resets(tmp_path, monkeypatch):
    """Ctrl-C in the wait for Hold:0 after error:N: the stop still ends with a soft reset
    (spindle off, queue flushed) and a ``stop`` in the journal, then reports the stop."""
    job = tmp_path / "job.gcode"
    write_job(job, 60)
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"
    port = open_port("grblsim://?baud=0&time_scale=0.01&error_at=120", 115200)
    trip = _Tripwire(port)
    original = Streamer._stop_after_fault

    def stop_after_fault(self, fault):
        trip.armed = KeyboardInterrupt()  # the next read: the wait for Hold:0
        original(self, fault)

    monkeypatch.setattr(Streamer, "_stop_after_fault", stop_after_fault)
    try:
        with pytest.raises(StreamStopped, match=r"error:20 .*Ctrl-C while stopping"):
            stream_program(trip, prog, journal)
    except KeyboardInterrupt:
        pytest.fail("the Ctrl-C escaped the stop")
    finally:
        port.close()
    assert trip.armed is None  # the Ctrl-C did come during the stop
    _held_then_reset(port.sim.record)
    last = read_journal(journal)[-1]
    assert last["ev"] == "stop" and "error:20" in last["reason"]


def test_a_brown_out_flushes_the_lines_already_on_the_way(tmp_path):
    """The controller resets itself mid-job: on its banner the sender stops writing and
    soft-resets it, so no line sent before it saw the banner runs from the lost position."""
    job, _ = _profile_job(tmp_path, "grbl-3018-diamond", n=40, seed=11)
    prog = load_program(job)
    rec = tmp_path / "rec.jsonl"
    # at the line's speed (not baud=0): what the sender wrote last may still be on the wire
    url = f"grblsim://?time_scale=0.01&{_3018_RATES}&reset_after=133&record={rec}"
    port = open_port(url, 115200)
    try:
        with pytest.raises(StreamFault, match="reset itself mid-job"):
            stream_program(port, prog, tmp_path / "j.jsonl")
    finally:
        port.close()
    record = read_record(rec)
    brown_out = next(k for k, e in enumerate(record) if e["ev"] == "reset")
    assert not record[brown_out]["command"]
    # a line that reached the controller before the banner reached the sender may have
    # started; the sender's reset cuts it short, and nothing runs to its end
    assert not [e for e in record[brown_out:] if e["ev"] == "exec"]
    flush = next(e["t"] for e in record[brown_out:] if e["ev"] == "reset" and e["command"])
    assert all(e["t"] == flush for e in record[brown_out:] if e["ev"] == "partial")
    assert read_journal(tmp_path / "j.jsonl")[-1]["ev"] == "stop"


def _laser_job(path: Path, strokes: int, seed: int = 5) -> None:
    """A laser job that powers each cut with its own S (no M3/M5 between cuts)."""
    rng = np.random.default_rng(seed)
    lines = ["G21 G90 G94", "M4 S0", "G1 F3000"]
    for k in range(strokes):
        x, y = np.round(rng.uniform(-30, 30, 2), 3)
        lines += [f"G0 X{x:.3f} Y{y:.3f}", f"G1 X{x + 4:.3f} S{700 + 100 * (k % 2)}"]
    lines += ["M5", "M2"]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("laser", [1, 0])
def test_laser_mode_s_changes_are_not_taken_as_sync_points(tmp_path, laser):
    """GRBL in laser mode ($32=1) moves on through an S change in a motion block, so a
    killed sender's journal may count as run only what surely ran: every motion block
    counted done was executed by the emulator, which models $32."""
    job = tmp_path / "laser.gcode"
    _laser_job(job, 40)
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"
    port = open_port(
        f"grblsim://?baud=0&time_scale=0.05&usb_powered=1&$32={laser}&$110=5000&$111=5000", 115200
    )
    streamer = Streamer(port, FAST)
    streamer.connect()
    assert streamer.info.laser_mode is bool(laser)
    j = Journal(journal).open()

    def die(p):
        if p.acked > 45:
            port.sim.drop_link()  # the board loses power with the cable
            raise SystemExit(137)

    streamer.on_progress = die
    streamer._stop_on_escape = lambda exc: None  # type: ignore[method-assign]  # SIGKILL
    with pytest.raises(SystemExit):
        streamer.stream(prog, j)
    j.close()
    port.close()
    events = read_journal(journal)
    assert events[0]["laser"] is bool(laser)
    done = done_blocks(events, prog.sha256, journal, program=prog)
    ran = executed_blocks(port.sim.record)
    assert {i for i in done if prog.blocks[i].motion} <= ran
    acked = [e["i"] for e in events if e["ev"] == "ack"]
    if not laser:  # every cut syncs, but only for the moves before it: its own is unsure,
        # so at most the last acked cut, the travel before it and the cut before that
        assert len(set(acked) - done) <= 3


@pytest.mark.parametrize("laser", [0, 1])
def test_sync_blocks_are_the_ones_the_emulator_waits_at(tmp_path, laser):
    """A block counted as a sync point must make GRBL wait for the moves before it: its
    ``ok`` comes after the previous move ran. With ``$32=0`` the two agree exactly; in
    laser mode the sender counts no S change (GRBL moves through those in moving blocks)."""
    tests = ["M3 S100", "M3", "S200", "G1 X3 S300", "M8", "M8", "M9", "M9", "M1", "G4 P0",
             "M4", "M5", "M5", "S50", "M7", "M9"]  # fmt: skip
    lines = ["G21 G90 G1 F600"]
    for k, text in enumerate(tests):
        lines += [f"G1 X{10 * (k % 2) + 5}", text]
    job = tmp_path / "sync.gcode"
    job.write_text("\n".join(lines) + "\n")
    prog = load_program(job)
    from scratchfab.machine.grblsim import GrblSim

    sim = GrblSim(SimOptions(baud=0, time_scale=0.05, settings={32: laser}))
    sim.start()
    deadline = time.monotonic() + 20
    for b in prog.blocks:  # send-response: the RX buffer never overflows
        sim.host_write(b.text.encode() + b"\n")
        while time.monotonic() < deadline and sum(e["ev"] == "resp" for e in sim.record) <= b.index:
            time.sleep(0.002)
    sim.close()
    resp = [e["t"] for e in sim.record if e["ev"] == "resp"]
    done = {e["n"]: e["t"] for e in sim.record if e["ev"] == "exec"}
    assert len(resp) == len(prog.blocks) and len(done) == len(tests) + 1
    for b in prog.blocks[2::2]:
        waited = resp[b.index] >= done[b.index]  # rx n is 1-based: n == index of the move
        counted = b.sync or (laser == 0 and b.speed_sync)
        assert not counted or waited, b.text
        if laser == 0:
            assert counted == waited, b.text


_PLUNGE = "G21 G90\nG0 Z5\nG0 X10 Y10\nG1 Z-0.1 F100\n"


@pytest.mark.parametrize(
    ("text", "line", "where"),
    [
        (_PLUNGE, 4, "Z -0.1 mm, below its travel height 5"),  # cut at its first plunge
        (_PLUNGE + "M5\nM2\n", 6, "Z -0.1 mm (line 4), below its travel height 5"),
        ("G21 G90\nG1 Z5 F500\nG1 X10 Y10\nG1 Z-0.1\n", 4, "below its travel height 5"),
        ("G21 G91\nG0 Z3\nG0 X10\nG1 Z-3.1 F100\n", 4, "Z -0.1 mm, below its travel"),
        ("G21 G90\nM5\nG0 X1 Y1\nM3 S1000\n", 4, "tool down (spindle output M3)"),  # a servo
    ],
)
def test_a_file_cut_off_at_a_plunge_is_refused_before_connecting(
    tmp_path, capsys, text, line, where
):
    """Without --machine such a file shows no cutting height (no stroke); it is refused all
    the same, naming the file's last line, and nothing is sent."""
    job = tmp_path / "job.gcode"
    job.write_text(text)
    rec = tmp_path / "rec.jsonl"
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", f"grblsim://?baud=0&record={rec}", "--yes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {job}:{line}: the program ends ") and len(err.splitlines()) == 1
    assert where in err
    assert not rec.exists() and not default_journal_path(job).exists()


@pytest.mark.parametrize(
    "text",
    [
        _PLUNGE + "G0 Z5\n",  # lifted
        _PLUNGE + "G1 Z1\n",  # lifted, though below the travel height
        _PLUNGE + "G1 X20 Y10\nG0 Z5\n",  # cut, then lifted
        "G21 G90\nG0 Z5\nG0 X10 Y10\nG1 Z6 F100\n",  # a feed move up
        "G21 G90\nG1 X10 Y10 F100\nG1 Z-1\n",  # no travel height known: nothing to judge by
        "G21 G90\nM5\nG0 X1 Y1\nM3 S1000\nG1 X5 F600\nM5\n",  # a servo job, pen lifted
        # three feed levels, no rapid: no cutting height shown, and the last move goes in
        # XY too, so it is no plunge
        "G21 G90\nG1 Z5 F500\nG1 X10 Y10\nG1 X20 Z3\nG1 X0 Y0 Z0\n",
        "G21 G90\nG0 Z10\nM3 S500\nG1 X5 F600\nM5\nG1 Z2 F100\n",  # laser off, refocused
    ],
)
def test_a_file_that_ends_lifted_is_streamed(tmp_path, text):
    job = tmp_path / "job.gcode"
    job.write_text(text)
    main(["stream", str(job), "--port", "grblsim://?baud=0&time_scale=0", "--yes"])
    assert read_journal(default_journal_path(job))[-1]["ev"] == "end"


@pytest.mark.parametrize(("zero", "kept"), [("G92X5Y-3", False), ("G10L20P1X5Y-3", True)])
def test_check_mode_refuses_when_its_reset_clears_the_work_zero(tmp_path, zero, kept):
    """Leaving check mode soft-resets GRBL, which clears G92 (not G54): a zero set with
    G92 would be gone and the job would run elsewhere."""
    job = tmp_path / "job.gcode"
    write_job(job, 2)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0", 115200)
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        streamer._command(zero)
        streamer._read_work_offset()
        assert streamer.info.wco == pytest.approx((-5.0, 3.0, 0.0))  # MPos 0 is work X5 Y-3
        if kept:
            assert streamer.check(prog).errors == []
        else:
            with pytest.raises(StreamFault, match=r"job\.gcode: leaving check mode .* G92") as exc:
                streamer.check(prog)
            # the advice sets the system the job runs in (it selects none), as every stream
            # message words it, with axis words (G10 L20 P0 alone is error:26)
            text = str(exc.value)
            assert "`G10 L20 P0 X0 Y0 Z0` there (P0: the work system in use" in text
            assert "P1" not in text
            # and it names the command that sets the same zero again: sent, it does
            restore = re.search(r"`(G21 G10 L2 P0 [^`]*)`", text)
            assert restore is not None, text
            streamer._command(restore[1])
            streamer._read_work_offset()
            assert streamer.info.wco == pytest.approx((-5.0, 3.0, 0.0))
            kept = True  # the emulator runs at it again
        with port.sim._cond:
            wco = port.sim._wco()
        assert (wco == pytest.approx((-5.0, 3.0, 0.0))) is kept  # what the emulator runs at
    finally:
        port.close()


@pytest.mark.parametrize(
    ("zero", "rezero", "resumed"),
    [
        ("G92X5Y-3", "", False),
        ("G10L20P1X5Y-3", "", True),
        # zeroed again by hand after the stop, as the refusal asks: never to the hundredth
        ("G92X5Y-3", "G10L20P0X5.02Y-3", True),
    ],
)
def test_resume_refuses_when_a_reset_cleared_the_g92_zero(tmp_path, monkeypatch, capsys, zero,
                                                          rezero, resumed):  # fmt: skip
    """The stop's soft reset clears G92 (not G54): resuming a run zeroed with G92 would cut
    the rest of the strokes elsewhere, so it is refused until the zero is set again."""
    job = tmp_path / "job.gcode"
    write_job(job, 12)
    prog = load_program(job)
    journal = default_journal_path(job)
    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    streamer = Streamer(port, FAST, ask_interrupt=lambda: "stop")
    streamer.connect()
    streamer._command(zero)
    streamer._read_work_offset()

    def stop(p):
        if p.acked > 20:
            raise KeyboardInterrupt

    streamer.on_progress = stop
    j = Journal(journal).open()
    with pytest.raises(StreamStopped):
        streamer.stream(prog, j)
    j.close()
    assert read_journal(journal)[0]["wco"] == [-5.0, 3.0, 0.0]
    if rezero:
        streamer._command(rezero)
    sent = len(_received_gcode(port.sim.record))

    class _Kept:
        """The port, left open by a stream that ends: the next one finds it as it was."""

        def __getattr__(self, name):
            return getattr(port, name)

        def close(self):
            pass

    # the refused stream leaves the port open for the zero named and the resume after it
    kept = resumed is False
    monkeypatch.setattr(
        "scratchfab.machine.stream_job.open_port",
        lambda name, baud: _Kept() if kept else port,
    )
    args = ["stream", str(job), "--port", "grblsim://?baud=0", "--resume", "--yes"]
    if resumed:
        main([*args, "--banner-timeout", "0.3"])
        assert read_journal(journal)[-1]["ev"] == "end"
        changed = "warning: the work offset changed since the interrupted run"
        said = capsys.readouterr()
        assert (changed in said.out + said.err) is bool(rezero)
        return
    with pytest.raises(SystemExit) as exc:
        main([*args, "--banner-timeout", "0.3"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.splitlines()[-1]
    assert err.startswith(f"error: {journal}: the interrupted run's work zero included a G92")
    assert "`G10 L20 P0 X0 Y0 Z0` there (P0: the work system in use" in err
    assert "P1" not in err
    assert len(_received_gcode(port.sim.record)) == sent  # nothing was sent
    # the exact command it names sets the same zero again: the resume goes on
    restore = re.search(r"set the same zero again with `(G21 G10 L2 P0 [^`]*)`", err)
    assert restore is not None, err
    streamer._command(restore[1])
    kept = False  # the resume closes it
    main([*args, "--banner-timeout", "0.3"])
    assert read_journal(journal)[-1]["ev"] == "end"


def test_a_dwell_longer_than_the_stall_timeout_is_not_a_stall(tmp_path):
    """GRBL answers G4 only when the dwell ends and reports Idle meanwhile: a spin-up
    dwell longer than the stall timeout must not stop the job (a lost ok still does)."""
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z2\nM3 S1000\nG4 P4\nG0 X1\nG1 Z-0.1 F600\nG1 X2 F600\n"
                   "G0 Z2\nM5\nM2\n")  # fmt: skip
    prog = load_program(job)
    options = StreamOptions(banner_timeout=0.3, banner_settle=0.02, stall_timeout=0.5)
    for query, fault in (
        ("", None),
        ("&lose_ok_at=4", "stalled: no answer to the end-of-job G4P0"),
    ):
        port = open_port(f"grblsim://?baud=0&time_scale=0.25{query}", 115200)  # the dwell: 1 s
        try:
            if fault is None:
                stream_program(port, prog, tmp_path / "j.jsonl", options)
                assert [e["n"] for e in port.sim.record if e["ev"] == "exec"]
            else:
                with pytest.raises(StreamFault, match=fault):
                    stream_program(port, prog, tmp_path / "k.jsonl", options)
        finally:
            port.close()


class _Deaf:
    """A port whose controller's banner and ``[MSG:...]`` lines (the lines starting with
    one of ``lost``) are lost on the line."""

    def __init__(self, port, lost=(b"Grbl", b"[MSG")):
        self._port = port
        self._lost = tuple(lost)
        self._held = b""
        self._ready = b""

    def read(self, size=1):
        if not self._ready:
            self._held += self._port.read(max(size, self._port.in_waiting))
            done, _, self._held = self._held.rpartition(b"\n")
            lines = [ln for ln in done.split(b"\n") if not ln.strip().startswith(self._lost)]
            self._ready = b"".join(ln + b"\n" for ln in lines if ln.strip())
        out, self._ready = self._ready[:size], self._ready[size:]
        return out

    @property
    def in_waiting(self):
        return len(self._ready) + self._port.in_waiting

    def __getattr__(self, name):
        return getattr(self._port, name)


def test_an_alarm_whose_message_was_lost_stops_the_job_instead_of_waiting(tmp_path):
    """A brown-out with homing on ($22=1) leaves GRBL locked in Alarm; if its banner is
    lost on the line, the status reports still say Alarm: the job stops (no hang) and no
    block counts as run on the strength of the position after the reset."""
    job = tmp_path / "job.gcode"
    write_job(job, 30)
    prog = load_program(job)
    url = "grblsim://?baud=0&time_scale=0.01&soft_limits=1&homed=1&wco=-100,-100,-10&reset_after=60"
    port = open_port(url, 115200)
    streamer = Streamer(port, FAST)
    streamer.connect()
    streamer.port = _Deaf(port)
    journal = tmp_path / "j.jsonl"
    j = Journal(journal).open()
    t0 = time.monotonic()
    try:
        # whichever comes first: a report saying Alarm, or GRBL's error:9 to the next line
        alarm = r"reports Alarm after line|came after line \d+, so the controller is in Alarm"
        with pytest.raises(StreamFault, match=alarm):
            streamer.stream(prog, j)
    finally:
        j.close()
        port.close()
    assert time.monotonic() - t0 < 20
    stop = read_journal(journal)[-1]
    assert stop["ev"] == "stop"
    ran = executed_blocks(port.sim.record)
    assert all(i in ran for i in range(stop["executed_through"] + 1) if prog.blocks[i].motion)


def test_a_reset_during_check_mode_stops_before_anything_moves(tmp_path):
    """A controller that resets itself in check mode has left it: the lines that follow
    would run for real (the whole job did). The banner stops the check with a soft reset:
    no move runs to its end; one sent before the banner arrived may start and is cut."""
    job = tmp_path / "job.gcode"
    write_job(job, 10)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.01&reset_after=8", 115200)
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        with pytest.raises(StreamFault, match="reset itself during check mode"):
            streamer.check(prog)
    finally:
        port.close()
    record = port.sim.record
    assert not [e for e in record if e["ev"] == "exec"]
    cut = [e for e in record if e["ev"] == "partial"]
    ours = [e["t"] for e in record if e["ev"] == "reset" and e["command"]]
    assert len(cut) <= 1 and all(e["t"] in ours for e in cut)


def test_check_mode_is_entered_or_nothing_is_sent(tmp_path):
    """``$C`` toggles: on a controller already in check mode it leaves it, and the job
    would then run for real. Only ``[MSG:Enabled]`` lets the check send lines."""
    job = tmp_path / "job.gcode"
    write_job(job, 5)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        streamer._command("$C")  # left in check mode by someone else
        with pytest.raises(StreamFault, match="did not enter check mode"):
            streamer.check(prog)
    finally:
        port.close()
    assert not _received_gcode(port.sim.record)


def test_a_lost_link_warns_that_the_machine_may_still_move(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 20)
    port = open_port("grblsim://?baud=0&time_scale=0.02&disconnect_after=40", 115200)
    try:
        with pytest.raises(StreamFault, match="connection lost.*goes on running the lines"):
            stream_program(port, load_program(job), tmp_path / "j.jsonl")
    finally:
        port.close()
    record = port.sim.record
    lost = next(e["t"] for e in record if e["ev"] == "disconnect")
    assert [e for e in record if e["ev"] == "exec" and e["t"] > lost]  # it did go on


def test_report_lines_that_need_idle_wait_for_it(tmp_path):
    """GRBL answers $#, $$, $I and $N with error:8 while moving: a job holding one (they
    are allowed: they move nothing) must not stop there."""
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z2\nG0 X5 Y5\n$#\nG0 X0\n$G\n$$\nG0 Y0\n$I\n$N\nG0 Z3\n")
    port = open_port("grblsim://?baud=0&time_scale=0.05", 115200)
    try:
        stream_program(port, load_program(job), tmp_path / "j.jsonl")
    finally:
        port.close()
    assert [e["r"] for e in port.sim.record if e["ev"] == "resp"].count("ok") > 11
    assert not [e for e in port.sim.record if e["ev"] == "resp" and e["r"] != "ok"]


def test_a_grbl_0_9_controller_is_refused(monkeypatch):
    """Grbl 0.9 reports ``<Idle,MPos:...>``: Idle and Hold:0 would never be recognised, so
    a job would never be seen to end and a stop would wait out its timeout."""
    import scratchfab.machine.grblsim as grblsim

    monkeypatch.setattr(grblsim, "BANNER", "\r\nGrbl 0.9j ['$' for help]\r\n")
    port = open_port("grblsim://?baud=0&time_scale=0", 115200)
    try:
        with pytest.raises(StreamFault, match=r"Grbl 0\.9j, whose status reports"):
            Streamer(port, FAST).connect()
    finally:
        port.close()
    assert not _received_gcode(port.sim.record)


def test_a_reset_while_held_at_the_prompt_is_not_resumed(tmp_path):
    """The controller resets itself while the user decides after Ctrl-C: its Idle is not
    a completed hold, so "resume" must not go on streaming into the lost position; the
    journal trusts no position from after the reset."""
    job = tmp_path / "job.gcode"
    write_job(job, 30)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    sim = port.sim

    def brown_out_then_resume():
        with sim._cond:
            sim._reset_at = sim._clock()
            sim._cond.notify_all()
        time.sleep(0.2)
        return "resume"

    journal = tmp_path / "j.jsonl"
    try:
        with pytest.raises(StreamFault, match="reset itself while held"):
            stream_program(port, prog, journal, on_progress=_fire_after(40),
                    ask_interrupt=brown_out_then_resume)  # fmt: skip
    finally:
        port.close()
    brown_out = next(e["t"] for e in sim.record if e["ev"] == "reset" and not e["command"])
    assert not [e for e in sim.record if e["ev"] == "rt" and e["ch"] == ord("~")]
    assert not [e for e in sim.record if e["ev"] == "exec" and e["t"] > brown_out]
    stop = read_journal(journal)[-1]
    ran = executed_blocks(sim.record)
    assert stop["ev"] == "stop"
    assert all(i in ran for i in range(stop["executed_through"] + 1) if prog.blocks[i].motion)


@pytest.mark.parametrize(
    ("header", "first"),
    [
        ("G21 G90", "G21G90G17G94"),  # our exports: the controller's own system stays
        ("G21 G90 G54", "G21G90G17G94G54"),  # the file chose G54: the resume does too
    ],
)
def test_resume_preamble_selects_a_work_system_only_where_the_file_did(tmp_path, header, first):
    """A controller put in G55 by a startup line runs a file that names none in G55; a
    resume that sent G54 would cut the rest of the board elsewhere."""
    job = tmp_path / "j.gcode"
    write_job(job, 3)
    job.write_text(job.read_text().replace("G21 G90", header, 1))
    assert header in job.read_text()
    prog = load_program(job)
    pre = resume_preamble(prog, prog.strokes[1][0])
    assert pre[0] == first
