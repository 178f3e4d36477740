"""The machining-time estimate against a model of Grbl 1.1's planner running the G-code.

``grbl_planner_sim`` reads the exported G-code line by line (junction deviation, per-axis
limits, 15-block look-ahead, synchronising M3/M5/G4); ``estimate_time`` builds the moves
from the strokes. They share no code, so agreement checks the estimate's model of the
writer's output as well as its arithmetic.
"""

from __future__ import annotations

import math
from functools import cache
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from conftest import FULL
from grbl_planner_sim import Settings, block_seconds, simulate
from scipy.integrate import quad

import scratchfab
from scratchfab.cli import main
from scratchfab.export.gcode import gcode_lines
from scratchfab.machine.profile import MachineProfile, load_profile, profile_from_mapping
from scratchfab.model.design import load_design
from scratchfab.model.scratches import load_scratches
from scratchfab.toolpath import Toolpath, estimate_time, plan_toolpath
from scratchfab.toolpath.timing import path_times

DEMO = Path(scratchfab.__file__).parent / "data" / "pipelines" / "demo.toml"


def _variant(name: str, **changes: dict) -> MachineProfile:
    table = load_profile(name).to_table()
    for key, values in changes.items():
        table[key] = {**table.get(key, {}), **values}
    return profile_from_mapping(table, f"<{name} variant>")


PROFILES = {
    "3018-z": lambda: load_profile("grbl-3018-diamond"),
    "plotter-servo": lambda: load_profile("grbl-plotter-scribe"),
    "3018-spindle": lambda: _variant(
        "grbl-3018-diamond", tool_control={"mode": "spindle", "power": 8000, "dwell_s": 1.5}
    ),
    "3018-g1-travel": lambda: _variant("grbl-3018-diamond", feeds={"travel_mm_min": 1500.0}),
    "plotter-no-dwell": lambda: _variant("grbl-plotter-scribe", tool_control={"dwell_s": 0.0}),
}


def grbl_settings(profile: MachineProfile, junction_deviation_mm: float = 0.01) -> Settings:
    """The $-settings of a machine set up as the profile says (GRBL's default $11)."""
    m = profile.motion
    return Settings(m.max_rate_mm_min, m.acceleration_mm_s2, junction_deviation_mm)


def simulated(tp: Toolpath, profile: MachineProfile, junction_deviation_mm: float = 0.01):
    """Run the exported G-code from the start position, tool up."""
    z = profile.z.safe_mm if profile.tool_control.mode != "servo" else 0.0
    start = (*profile.start_mm, z)
    return simulate(gcode_lines(tp, profile), grbl_settings(profile, junction_deviation_mm), start)


def toolpath(strokes: np.ndarray, profile: MachineProfile) -> Toolpath:
    strokes = np.asarray(strokes, dtype=np.float64).reshape(-1, 2, 2)
    stats = {"estimated_time_s": estimate_time(strokes, profile)}
    outline = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return Toolpath(strokes, np.arange(len(strokes)), (1.0, 1.0), outline, profile, stats)


def rest_to_rest(tp: Toolpath, profile: MachineProfile) -> float:
    """The former estimate: every move of the G-code from rest to rest, plus the dwells."""
    strokes = tp.strokes
    n = len(strokes)
    start = np.asarray(profile.start_mm)
    travel = np.zeros((n + 1, 3))
    travel[:, :2] = np.vstack([strokes[:, 0], start]) - np.vstack([start, strokes[:, 1]])
    cut = np.zeros((n, 3))
    cut[:, :2] = strokes[:, 1] - strokes[:, 0]
    m = profile.motion
    limits = (m.max_rate_mm_min, m.acceleration_mm_s2)

    def move_times(moves: np.ndarray, feed: float | list[float], *limits: tuple) -> np.ndarray:
        """Each move from rest to rest: a stop before every one."""
        return path_times(moves, feed, *limits, rest_before=np.ones(len(moves), dtype=bool))

    total = move_times(travel, profile.feeds.travel_mm_min or math.inf, *limits).sum()
    total += move_times(cut, profile.feeds.engrave_mm_min, *limits).sum()
    if profile.tool_control.mode == "servo":
        return float(total + (2 * n + 1) * profile.tool_control.dwell_s)
    dz = profile.z.safe_mm - profile.z.engrave_mm
    zs = move_times(
        np.array([[0, 0, -dz], [0, 0, dz]]), [profile.feeds.plunge_mm_min, math.inf], *limits
    )
    spindle = profile.tool_control.dwell_s if profile.tool_control.mode == "spindle" else 0.0
    return float(total + n * zs.sum() + spindle)


# --- the reference itself -------------------------------------------------------------


def test_block_seconds_matches_quadrature():
    rng = np.random.default_rng(3)
    for _ in range(20):
        vmax, accel, length = rng.uniform(5, 40), rng.uniform(20, 500), rng.uniform(0.2, 30)
        v0 = rng.uniform(0, vmax)
        v1 = min(rng.uniform(0, vmax), math.sqrt(v0 * v0 + 2 * accel * length))
        v0 = min(v0, math.sqrt(v1 * v1 + 2 * accel * length))

        def slowness(x, v0=v0, v1=v1, vmax=vmax, accel=accel, length=length):
            return 1.0 / min(
                vmax,
                math.sqrt(v0 * v0 + 2 * accel * x),
                math.sqrt(v1 * v1 + 2 * accel * (length - x)),
            )

        # Split where the limit that binds changes: end of speed-up, start of braking, their meeting.
        kinks = [
            (vmax * vmax - v0 * v0) / (2 * accel),
            length - (vmax * vmax - v1 * v1) / (2 * accel),
            (v1 * v1 - v0 * v0 + 2 * accel * length) / (4 * accel),
        ]
        edges = sorted({0.0, length, *(x for x in kinks if 0 < x < length)})
        want = sum(quad(slowness, a, b, limit=400)[0] for a, b in pairwise(edges))
        assert block_seconds(length, v0, v1, vmax, accel) == pytest.approx(want, rel=1e-6)


def test_simulator_corners_by_hand():
    s = Settings((6000.0, 6000.0, 600.0), (100.0, 100.0, 50.0), 0.01, (1000.0, 1000.0, 1000.0))
    lines = ["G21 G90", "G1 X50 F3000", "G1 Y50"]
    run = simulate(lines, s, buffer_blocks=None)
    # 90 degrees in XY: the bisector (-1, 1)/sqrt(2) allows 100 sqrt(2) mm/s^2, sin(45) = 1/sqrt(2).
    half = math.sqrt(0.5)
    want = math.sqrt(100.0 * math.sqrt(2.0) * 0.01 * half / (1.0 - half))
    assert run.junction_speeds == [pytest.approx(want, rel=1e-9)]
    v = 50.0
    expect = 2 * (50.0 / v + v / 100.0) - 2 * (want / 100.0 - want * want / (2 * 100.0 * v))
    assert run.seconds == pytest.approx(expect, rel=1e-9)
    # Straight on: ten pieces cost what one line does; a reversal stops; G4 stops and waits.
    pieces = ["G1 F3000", *(f"G1 X{5 * k}" for k in range(1, 11))]
    assert simulate(pieces, s).seconds == pytest.approx(simulate(["G1 X50 F3000"], s).seconds)
    back = simulate(["G1 X50 F3000", "G1 X0"], s)
    assert back.junction_speeds == [0.0]
    assert back.seconds == pytest.approx(2 * (50.0 / v + v / 100.0))
    paused = simulate(["G1 X50 F3000", "G4 P0.5", "G1 Y50"], s)
    assert paused.syncs == 2 and paused.junction_speeds == []
    assert paused.seconds == pytest.approx(2 * (50.0 / v + v / 100.0) + 0.5)
    # Z joins XY at 90 degrees; M5 with the spindle already off changes nothing.
    z = simulate(["G1 X50 F3000", "M5", "G0 Z5"], s)
    assert z.syncs == 1 and z.junction_speeds[0] > 0
    assert simulate(["G1 X50 F3000", "M3 S100", "G0 Z5"], s).syncs == 2
    # The 15-block buffer: many tiny collinear pieces cannot reach the speed one line does.
    tiny = ["G1 F3000", *(f"G1 X{0.05 * k:.2f}" for k in range(1, 201))]
    assert simulate(tiny, s).seconds > 1.5 * simulate(tiny, s, buffer_blocks=None).seconds


def test_path_times_agree_with_the_simulator_on_random_corners():
    rng = np.random.default_rng(5)
    s = Settings((2000.0, 1500.0, 600.0), (100.0, 80.0, 50.0), 0.02, (1000.0, 1000.0, 1000.0))
    points = np.round(rng.uniform(0, 20, (60, 3)), 3)
    points[5::9, :2] = points[4::9, :2]  # Z-only moves
    points[8::13] = points[7:-1:13]  # moves of no length (dropped, joining nothing)
    feeds = rng.choice([np.inf, 300.0, 900.0, 3000.0], len(points) - 1)
    rest = rng.uniform(size=len(points) - 1) < 0.1
    lines = ["G21 G90", "M3 S1"]
    for k in range(1, len(points)):
        if rest[k - 1]:
            lines.append("G4 P0")
        x, y, z = points[k]
        move = "G0" if np.isinf(feeds[k - 1]) else f"G1 F{feeds[k - 1]:g}"
        lines.append(f"{move} X{x:.3f} Y{y:.3f} Z{z:.3f}")
    want = simulate(lines, s, start=points[0], buffer_blocks=None).seconds
    got = path_times(
        np.diff(points, axis=0), feeds, s.max_rate_mm_min, s.acceleration_mm_s2, rest, 0.02
    ).sum()
    assert got == pytest.approx(want, rel=1e-9)


# --- the estimate against the reference -----------------------------------------------


@cache
def demo_toolpaths() -> dict[str, Toolpath]:
    """The bundled demo's design (its layout, fewer scratches unless FULL), planned per profile."""
    import tempfile

    out = Path(tempfile.mkdtemp(prefix="scratchfab-time-"))
    count = [] if FULL else ["--count", "500"]
    main(["design", str(DEMO), "--out", str(out), *count])
    design = load_design(out / "design" / "design.toml")
    scratches = load_scratches(out / "design" / "scratches.csv", design.scratch, design.board)
    return {
        name: plan_toolpath(scratches, design.board, make(), design.scratch)
        for name, make in PROFILES.items()
    }


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_estimate_matches_grbl_on_the_demo_job(name):
    tp = demo_toolpaths()[name]
    profile = tp.profile
    run = simulated(tp, profile)
    ratio = tp.stats["estimated_time_s"] / run.seconds
    assert ratio == pytest.approx(1.0, abs=0.002), f"estimate / GRBL = {ratio:.4f}"
    # Servo jobs stop at every M3/M5, so rest-to-rest is exact there; a Z job passes its
    # 90-degree corners at about 1.3 mm/s, which the former rest-to-rest estimate missed.
    old = rest_to_rest(tp, profile) / run.seconds
    if profile.tool_control.mode == "servo":
        assert old == pytest.approx(1.0, abs=1e-4)  # the G-code is rounded to whole steps
    else:
        assert old > 1.03


def _inside(profile: MachineProfile, margin: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    env = profile.envelope
    lo = np.array([env.x_mm[0], env.y_mm[0]]) + margin
    hi = np.array([env.x_mm[1], env.y_mm[1]]) - margin
    return lo, hi


def worst_case(case: str, profile: MachineProfile) -> np.ndarray:
    lo, hi = _inside(profile)
    rng = np.random.default_rng(11)
    if case == "tiny-strokes":  # 0.5 mm strokes 0.6 mm apart: Z moves and corners dominate
        grid = np.stack(np.meshgrid(np.arange(15), np.arange(15)), -1).reshape(-1, 2) * 0.6
        a = lo + 10 + grid
        return np.stack([a, a + [0.5, 0.0]], 1)
    if case == "long-travels":  # short cuts in opposite corners of the envelope
        a = np.where((np.arange(40) % 2)[:, None] == 1, hi - 5, lo + 5) + rng.uniform(
            -2, 2, (40, 2)
        )
        return np.stack([a, a + [2.0, 1.0]], 1)
    if case == "diagonal-45":  # strokes and travels at 45 degrees: both axes at their limit
        t = np.arange(60)[:, None] * 3.0
        a = lo + 5 + t * [1.0, 1.0]
        a = np.minimum(a, hi - 10)
        return np.stack([a, a + [2.0, 2.0]], 1)
    if case == "touching":  # each stroke starts where the last ended: no travel at all
        pts = lo + 10 + np.cumsum(rng.uniform(0.5, 3.0, (80, 2)) * [1, -1] * [1, 0.3], axis=0)
        pts = np.clip(pts, lo, hi)
        return np.stack([pts[:-1], pts[1:]], 1)
    raise AssertionError(case)


CASES = ["tiny-strokes", "long-travels", "diagonal-45", "touching"]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("name", sorted(PROFILES))
def test_estimate_matches_grbl_on_worst_cases(case, name):
    profile = PROFILES[name]()
    tp = toolpath(worst_case(case, profile), profile)
    run = simulated(tp, profile)
    ratio = tp.stats["estimated_time_s"] / run.seconds
    assert ratio == pytest.approx(1.0, abs=0.002), f"{case}: estimate / GRBL = {ratio:.4f}"


def test_dwells_count_once_per_lift_and_lowering_and_the_return_counts():
    profile = PROFILES["plotter-servo"]()
    strokes = worst_case("long-travels", profile)[:5]
    tp = toolpath(strokes, profile)
    run = simulated(tp, profile)
    assert run.dwell_s == pytest.approx((2 * len(strokes) + 1) * profile.tool_control.dwell_s)
    quiet = PROFILES["plotter-no-dwell"]()
    diff = estimate_time(strokes, profile) - estimate_time(strokes, quiet)
    assert diff == pytest.approx(run.dwell_s, rel=1e-12)
    # Dropping the final travel home from the G-code takes off exactly its own time.
    lines = gcode_lines(tp, profile)
    home = [k for k, line in enumerate(lines) if line.startswith("G1 X")][-1]
    short = simulate(
        lines[:home] + lines[home + 1 :], grbl_settings(profile), (*profile.start_mm, 0.0)
    )
    back = np.zeros((1, 3))
    back[0, :2] = np.subtract(profile.start_mm, strokes[-1, 1])
    m = profile.motion
    alone = path_times(back, profile.feeds.travel_mm_min, m.max_rate_mm_min, m.acceleration_mm_s2)
    assert run.seconds - short.seconds == pytest.approx(alone[0], rel=1e-3)


@pytest.mark.parametrize("deviation", [0.0, 0.02, 0.05])
def test_other_junction_deviations_bound_the_estimate(deviation):
    """$11 = 0 (exact stops) is the only setting that runs slower than the estimate."""
    tp = demo_toolpaths()["3018-z"]
    ratio = tp.stats["estimated_time_s"] / simulated(tp, tp.profile, deviation).seconds
    if deviation == 0.0:
        assert 0.93 < ratio < 1.0
        assert rest_to_rest(tp, tp.profile) == pytest.approx(
            simulated(tp, tp.profile, 0.0).seconds, rel=1e-4
        )
    else:
        assert 1.0 < ratio < 1.08


def test_path_times_agree_with_the_simulator_on_a_straight_line_of_changing_feeds():
    """Collinear moves join at the lower of their nominal speeds (no corner limits them),
    and a short last piece makes stopping at the end bind."""
    s = Settings((3000.0, 3000.0, 600.0), (100.0, 80.0, 50.0), 0.01, (1000.0, 1000.0, 1000.0))
    xs = np.array([0.0, 10.0, 12.0, 30.0, 31.0, 50.0, 50.04])
    feeds = np.array([600.0, 3000.0, np.inf, 300.0, 2400.0, np.inf])
    lines = ["G21 G90"]
    for x, f in zip(xs[1:], feeds, strict=True):
        lines.append(("G0" if np.isinf(f) else f"G1 F{f:g}") + f" X{x:g} Y{x / 2:g}")
    want = simulate(lines, s, buffer_blocks=None)
    assert max(want.junction_speeds) > 10.0  # the pieces do join at speed
    delta = np.zeros((len(feeds), 3))
    delta[:, 0] = np.diff(xs)
    delta[:, 1] = np.diff(xs) / 2
    got = path_times(delta, feeds, s.max_rate_mm_min, s.acceleration_mm_s2, None, 0.01).sum()
    assert got == pytest.approx(want.seconds, rel=1e-9)


@pytest.mark.parametrize("deviation", [0.0, 0.05])
def test_the_profiles_junction_deviation_sets_the_estimate_and_the_header(deviation):
    """``[motion] junction_deviation_mm`` is the ``$11`` the estimate plans corners with."""
    base = PROFILES["3018-z"]()
    profile = _variant("grbl-3018-diamond", motion={"junction_deviation_mm": deviation})
    strokes = worst_case("touching", profile)
    tp = toolpath(strokes, profile)
    run = simulated(tp, profile, deviation)
    ratio = tp.stats["estimated_time_s"] / run.seconds
    assert ratio == pytest.approx(1.0, abs=0.002), f"estimate / GRBL = {ratio:.4f}"
    default = estimate_time(strokes, base)
    assert abs(default - run.seconds) > 0.01 * run.seconds  # $11 = 0.010 would be off
    header = next(line for line in gcode_lines(tp, profile) if " min" in line)
    assert f"about {run.seconds / 60:.1f} min" in header
    assert f"about {default / 60:.1f} min" not in header


def test_exit_speed_over_the_blocks_queued_agrees_with_the_simulator():
    """The emulator's planner step: a move's exit speed from what is queued behind it
    (entry limits by corner and cruise speeds, the newest ending at rest), against the
    simulator's junction speeds over windows of 1 to 15 blocks."""
    from scratchfab.toolpath.timing import corner_speed_sq, exit_speed_sq, move_limits

    rng = np.random.default_rng(11)
    s = Settings((2000.0, 1500.0, 600.0), (100.0, 80.0, 50.0), 0.02, (1000.0, 1000.0, 1000.0))
    points = np.round(rng.uniform(0, 20, (40, 3)), 3)
    points[5::9, :2] = points[4::9, :2]  # Z-only moves
    feeds = rng.choice([np.inf, 300.0, 900.0, 3000.0], len(points) - 1)
    lines = ["G21 G90"] + [
        ("G0" if np.isinf(f) else f"G1 F{f:g}") + " X{:.3f} Y{:.3f} Z{:.3f}".format(*p)
        for p, f in zip(points[1:], feeds, strict=True)
    ]
    length, unit, cruise, accel = move_limits(
        np.diff(points, axis=0), feeds, s.max_rate_mm_min, s.acceleration_mm_s2
    )
    corner = corner_speed_sq(unit[:-1], unit[1:], s.acceleration_mm_s2, 0.02)
    entry_max = np.minimum(corner, np.minimum(cruise[1:], cruise[:-1]) ** 2)
    gain = 2.0 * accel * length
    for window in (1, 2, 5, 15):
        want = simulate(lines, s, start=points[0], buffer_blocks=window).junction_speeds
        entry_sq = 0.0
        for i in range(len(length) - 1):
            later = list(zip(entry_max[i : i + window - 1], gain[i + 1 : i + window], strict=True))
            exit_sq = exit_speed_sq(entry_sq, gain[i], later)
            assert math.sqrt(exit_sq) == pytest.approx(want[i], rel=1e-9, abs=1e-9)
            entry_sq = exit_sq
