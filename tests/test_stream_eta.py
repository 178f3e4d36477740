"""The sender's time estimate (its ETA) against a model of Grbl 1.1's planner.

``Program.timed_for`` times a parsed G-code file with the controller's ``$$`` settings;
``grbl_planner_sim`` runs the same lines with the same settings and shares no code with it.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from grbl_planner_sim import Settings, simulate
from test_export import random_scratches

from scratchfab.export import export
from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender_checks import compare
from scratchfab.machine.sender_program import load_program
from scratchfab.model.design import Board
from scratchfab.toolpath import plan_toolpath

ORIGIN = (0.0, 0.0, 0.0)  # where the sender's parse starts (it cannot know the machine's place)


def grbl(settings: dict[int, float]) -> Settings:
    return Settings(
        tuple(settings[110 + k] for k in range(3)),  # type: ignore[arg-type]
        tuple(settings[120 + k] for k in range(3)),  # type: ignore[arg-type]
        settings.get(11, 0.01),
        laser_mode=bool(settings.get(32, 0)),
    )


def write(tmp_path: Path, lines: list[str]) -> Path:
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("name", ["grbl-3018-diamond", "grbl-plotter-scribe"])
@pytest.mark.parametrize("junction_mm", [0.01, 0.05])
def test_eta_of_an_exported_job_matches_the_planner(name, junction_mm, tmp_path):
    profile = load_profile(name)
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    tp = plan_toolpath(random_scratches(np.random.default_rng(3), 150), board, profile)
    out = tmp_path / "board.gcode"
    export(tp, profile, out)
    m = profile.motion
    settings = {110 + k: m.max_rate_mm_min[k] for k in range(3)}
    settings |= {120 + k: m.acceleration_mm_s2[k] for k in range(3)}
    settings[11] = junction_mm
    want = simulate(out.read_text().splitlines(), grbl(settings), ORIGIN).seconds
    program = load_program(out)
    got = program.timed_for(settings).total_seconds
    assert got == pytest.approx(want, rel=2e-3)
    # distance / feed alone (the former ETA) is far off: the check can tell
    assert abs(
        program.at_rapid_rates([settings[110 + k] for k in range(3)]).total_seconds - want
    ) > (0.05 * want)


def test_eta_stops_where_grbl_empties_its_planner(tmp_path):
    settings = {110: 3000.0, 111: 3000.0, 112: 600.0, 120: 50.0, 121: 50.0, 122: 20.0, 32: 0}
    lines = [
        "G21 G90 G94",
        "G1 X10 F1200",
        "G1 X20 Y3",  # a corner GRBL passes without stopping
        "G4 P0.25",  # a dwell empties the planner
        "G0 X30",
        "M3 S100",
        "G1 X40 F900",
        "S200 G1 X50",  # an S change with the spindle on: a stop with $32=0 only
        "G1 X60 Y-4",
        "M5",
        "G0 Z5",
        "G0 X0 Y0",
    ]
    path = write(tmp_path, lines)
    program = load_program(path)
    for laser in (0, 1):
        settings[32] = laser
        want = simulate(lines, grbl(settings), ORIGIN)
        assert program.timed_for(settings).total_seconds == pytest.approx(want.seconds, rel=1e-6)
    stopped = program.timed_for({**settings, 32: 0}).total_seconds
    joined = program.timed_for({**settings, 32: 1}).total_seconds
    assert stopped > joined + 0.05  # the S change's stop costs a deceleration and a start


def test_eta_without_accelerations_keeps_distance_over_feed(tmp_path):
    lines = ["G21 G90", "G0 X10 Y5", "G1 X20 F600", "G1 Y20", "G0 X0 Y0"]
    program = load_program(write(tmp_path, lines))
    rates = {110: 1000.0, 111: 800.0, 112: 300.0}
    assert program.timed_for({}) is program
    assert program.timed_for(rates).total_seconds == pytest.approx(
        program.at_rapid_rates([1000.0, 800.0, 300.0]).total_seconds
    )
    # G1 distance / feed: 10 mm + 15 mm at 600 mm/min
    g1 = sum(b.seconds for b in program.timed_for(rates).blocks if b.modal.motion == "G1")
    assert g1 == pytest.approx(25.0 / 10.0)


def test_eta_of_a_laser_job_stops_at_an_s_change_without_motion(tmp_path):
    """In laser mode an S change joins only in a block that moves; alone it empties the planner."""
    settings = {110: 3000.0, 111: 3000.0, 112: 600.0, 120: 50.0, 121: 50.0, 122: 20.0, 32: 1}
    lines = ["G21 G90 G94", "M3 S100", "G1 X10 F1200", "S300", "G1 X20 Y3", "G1 X30"]
    program = load_program(write(tmp_path, lines))
    want = simulate(lines, grbl(settings), ORIGIN)
    assert want.syncs == 2  # the lone S300 and the end (M3 came with the planner empty)
    assert program.timed_for(settings).total_seconds == pytest.approx(want.seconds, rel=1e-6)


def test_eta_of_inch_and_inverse_time_programs_matches_their_mm_twin(tmp_path):
    """G20 coordinates and feeds, G93 inverse-time feeds and M30 after a block's motion,
    against the planner model running the same moves written in mm at G94 feeds."""
    settings = {110: 2000.0, 111: 1500.0, 112: 500.0, 120: 80.0, 121: 60.0, 122: 30.0}
    inch = ["G20 G90 G94", "G1 X0.5 F40", "G1 X1 Y0.2", "G0 Y1", "G1 X0 Y1.5 F20 M30"]
    mm = ["G21 G90 G94", "G1 X12.7 F1016", "G1 X25.4 Y5.08", "G0 Y25.4", "G1 X0 Y38.1 F508"]
    twin = simulate(mm, grbl(settings), ORIGIN).seconds
    got = load_program(write(tmp_path, inch)).timed_for(settings).total_seconds
    assert got == pytest.approx(twin, rel=1e-9)
    # G93: F is 1 / minutes for the block; 10 mm in 1/6 min is 60 mm/min, 5 mm in 1/4 min 20
    inverse = ["G21 G90 G93", "G1 X10 F6", "G1 X10 Y5 F4", "G94 G1 X20 Y5 F900"]
    per_min = ["G21 G90 G94", "G1 X10 F60", "G1 X10 Y5 F20", "G1 X20 Y5 F900"]
    twin = simulate(per_min, grbl(settings), ORIGIN).seconds
    got = load_program(write(tmp_path, inverse)).timed_for(settings).total_seconds
    assert got == pytest.approx(twin, rel=1e-9)
    # M30 (after its block's motion) stops the machine before the next move
    ended = ["G21 G90 G94", "G1 X10 F1200 M30", "G1 X20"]
    twin = simulate(["G21 G90 G94", "G1 X10 F1200", "M30", "G1 X20 F1200"], grbl(settings))
    got = load_program(write(tmp_path, ended)).timed_for(settings).total_seconds
    assert got == pytest.approx(twin.seconds, rel=1e-9)
    assert got > simulate(["G21 G90 G94", "G1 X20 F1200"], grbl(settings)).seconds + 0.1


@pytest.mark.parametrize("end", ["M2", "M30"])
def test_eta_stops_at_a_program_end_on_a_line_of_its_own(end, tmp_path):
    """A bare M2/M30 between two moves in line empties the planner: the next starts from rest."""
    settings = {110: 2000.0, 111: 1500.0, 112: 500.0, 120: 80.0, 121: 60.0, 122: 30.0}
    lines = ["G21 G90 G94", "G1 X10 F1200", end, "G1 X20 F1200"]
    want = simulate(lines, grbl(settings), ORIGIN)
    assert want.syncs == 2  # at the end line and at the end of the file
    got = load_program(write(tmp_path, lines)).timed_for(settings).total_seconds
    assert got == pytest.approx(want.seconds, rel=1e-9)
    assert got > simulate(["G21 G90 G94", "G1 X20 F1200"], grbl(settings)).seconds + 0.1


def test_eta_stays_finite_for_a_feed_move_without_a_feed(tmp_path):
    """GRBL refuses a G1 without a feed (error:22, no motion): no infinite ETA from it."""
    settings = {110: 3000.0, 111: 3000.0, 112: 600.0, 120: 50.0, 121: 50.0, 122: 20.0}
    for first in ("G1 X10", "G93 G1 X10 F0"):
        lines = ["G21 G90", first, "G94 G1 X20 F600"]
        timed = load_program(write(tmp_path, lines)).timed_for(settings)
        assert math.isfinite(timed.total_seconds)
        # the move after it runs from rest: 10 mm at 10 mm/s with 50 mm/s^2 ramps
        assert timed.total_seconds == pytest.approx(10 / 10 + 10 / 50)


# Where Grbl 1.1h empties its planner (protocol_buffer_synchronize), read from gnea/grbl
# grbl/gcode.c gc_execute_line, whose STEP 4 runs a block in this order: [4] S change
# (spindle_sync while the spindle is on; in laser mode not when GC_PARSER_LASER_ISMOTION:
# axis words driving a motion mode; under M3, LASER_FORCE_SYNC when a block without motion
# switches between G1/G2/G3 and another motion mode), [7] spindle state change (synced
# "even in laser mode"), [8] coolant change (coolant_sync), [10] G4 (mc_dwell), [14]-[15],
# [19] work offset changes (system_flag_wco_change under the default
# FORCE_BUFFER_SYNC_DURING_WCO_CHANGE: G54-G59, G92, G92.1, G10) and EEPROM writes
# (settings_write_coord_data under FORCE_BUFFER_SYNC_DURING_EEPROM_WRITE: G10, G28.1,
# G30.1; G28/G30 only read), [20] the motion, [21] M0/M2/M30 (after it). M1 is ignored.
# ``$`` lines run at once in protocol_main_loop (system_execute_line), outside the planner.
ON = ["M3 S1000"]  # spindle on (the state before the block)
SYNC_TABLE = [
    # (state, block, before with $32=0, before with $32=1, after)
    ([], "M3 S1000", True, True, False),
    (ON, "M3", False, False, False),  # not a change
    (ON, "M5", True, True, False),
    (ON, "M4", True, True, False),
    (ON, "S500", True, True, False),  # an S change alone
    (ON + ["G1 X1 F100"], "G1 X5 S500", True, False, False),  # moves: laser passes it
    (ON, "G0 X5 S500", True, False, False),
    (ON, "G28 X1 S500", True, True, False),  # G28's axis words drive no motion mode
    (ON, "S1000", False, False, False),  # the same S
    ([], "S500", False, False, False),  # spindle off
    (ON + ["G1 X1 F100"], "G0", False, True, False),  # laser M3: leaves G1 without motion
    (ON + ["G0 X1"], "G1", False, True, False),  # laser M3: enters G1 without motion
    (ON + ["G0 X1"], "G1 X5 F100", False, False, False),  # ... with motion: no
    (["M4 S1000", "G1 X1 F100"], "G0", False, False, False),  # M4: no forced sync
    ([], "M8", True, True, False),
    ([], "M7", True, True, False),  # (a build with ENABLE_M7; error:20 without)
    (["M8"], "M9", True, True, False),
    ([], "M9", False, False, False),  # coolant already off
    ([], "G4 P0.5", True, True, False),
    ([], "G1 X5 F100", False, False, False),
    ([], "M1", False, False, False),
    ([], "M0", False, False, True),
    ([], "G1 X5 F100 M0", False, False, True),
    ([], "M2", False, False, True),
    ([], "M30", False, False, True),
    (ON, "G1 X5 F100 S200 M30", True, False, True),  # the S change first, M30 after
    ([], "G28", False, False, False),
    ([], "G30 X1", False, False, False),
    ([], "G28.1", True, True, False),
    ([], "G30.1", True, True, False),
    ([], "G10 L2 P1 X0", True, True, False),
    ([], "G10 L20 P0 X0", True, True, False),
    ([], "G92 X0", True, True, False),
    ([], "G92.1", True, True, False),
    ([], "G55", True, True, False),
    ([], "G54", False, False, False),  # already G54
    ([], "G90 G21 G17 G94", False, False, False),
    ([], "$G", False, False, False),
    ([], "$#", False, False, False),
]


@pytest.mark.parametrize(("state", "block", "plain", "laser", "after"), SYNC_TABLE)
def test_each_block_records_where_grbl_empties_its_planner(
    tmp_path, state, block, plain, laser, after
):
    program = load_program(write(tmp_path, ["G21 G90 G94", *state, block]))
    b = program.blocks[-1]
    assert (b.syncs_before(False), b.syncs_before(True), b.sync_after) == (plain, laser, after)
    assert b.sync == (b.sync_before or after)
    assert b.sync_before == (plain and laser)  # whatever $32 says


def test_program_end_resets_the_modes_after_its_blocks_motion(tmp_path):
    """``G91 G1 X5 M30`` moves 5 mm relative, then M30 restores G90 (and G54, M5, M9)."""
    lines = ["G21 G90 G94", "G0 X10", "G91 G1 X5 F100 M30", "G1 X2 F100"]
    blocks = load_program(write(tmp_path, lines)).blocks
    assert blocks[2].modal.x == pytest.approx(15.0)
    assert not blocks[2].modal.relative
    assert blocks[3].modal.x == pytest.approx(2.0)


def _exported_job(name: str, tmp_path: Path, n: int = 150) -> tuple[Path, dict[int, float]]:
    """An exported job of ``n`` scratches and the $$ of a machine set up as its profile says
    ($11 apart)."""
    profile = load_profile(name)
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    tp = plan_toolpath(random_scratches(np.random.default_rng(3), n), board, profile)
    out = tmp_path / f"{name}.gcode"
    export(tp, profile, out)
    m = profile.motion
    settings = {110 + k: m.max_rate_mm_min[k] for k in range(3)}
    settings |= {120 + k: m.acceleration_mm_s2[k] for k in range(3)}
    return out, settings


def _spoken_seconds(text: str) -> tuple[float, float]:
    """``"11 s"``, ``"3 min"``, ``"1 h 2 min"`` as (seconds, the unit it was rounded to)."""
    found = re.fullmatch(r"(?:(\d+) h )?(\d+) (s|min)", text)
    assert found, text
    hours, value, unit = found.groups()
    if unit == "s":
        assert hours is None, text
        return float(value), 1.0
    return 3600.0 * int(hours or 0) + 60.0 * int(value), 60.0


@pytest.mark.parametrize(("junction_mm", "n"), [(0.002, 150), (0.05, 150), (0.05, 40)])
def test_stream_warns_when_grbls_junction_deviation_moves_the_time(junction_mm, n, tmp_path):
    """The warning says by how much GRBL's $11 moves the job's time from the profile's; the
    figure agrees with the planner model running the G-code at both. (40 scratches: about
    5 s, which the warning once wrote with a tenth, unlike every other time it says.)"""
    profile = load_profile("grbl-3018-diamond")
    job, settings = _exported_job("grbl-3018-diamond", tmp_path, n)
    program = load_program(job)
    grbl_run = simulate(job.read_text().splitlines(), grbl({**settings, 11: junction_mm}))
    profile_run = simulate(job.read_text().splitlines(), grbl({**settings, 11: 0.01}))
    change = grbl_run.seconds - profile_run.seconds
    assert abs(change) > 0.01 * profile_run.seconds
    (warning,) = [
        w
        for w in compare({**settings, 11: junction_mm}, None, program, profile).warnings
        if "$11" in w
    ]
    found = re.search(r"passed (slower|faster), the job takes (.+?) (longer|less) "
                      r"\(([-+][\d.]+) %\)", warning)  # fmt: skip
    assert found, warning
    assert found.group(1) == ("slower" if change > 0 else "faster")
    assert found.group(3) == ("longer" if change > 0 else "less")
    # as console.duration_text says a time: whole seconds, or whole minutes from a minute on
    shown, unit = _spoken_seconds(found.group(2))
    assert abs(shown - abs(change)) <= unit / 2 + 0.05, (found.group(2), change)
    assert float(found.group(4)) == pytest.approx(100 * change / profile_run.seconds, abs=0.15)
    assert warning.startswith(f"GRBL $11={junction_mm:g} mm is not the junction deviation 0.01")


def test_no_junction_warning_where_11_does_not_move_the_time(tmp_path):
    """The same $11, one a hair off, no $11, no accelerations to time with, or a servo job
    (which stops at every stroke): no warning."""
    job, settings = _exported_job("grbl-3018-diamond", tmp_path)
    program = load_program(job)
    profile = load_profile("grbl-3018-diamond")
    no_accel = {k: v for k, v in settings.items() if k < 120}
    for s in ({**settings, 11: 0.01}, {**settings, 11: 0.0101}, settings, {**no_accel, 11: 0.0}):
        assert not [w for w in compare(s, None, program, profile).warnings if "$11" in w], s
    job, settings = _exported_job("grbl-plotter-scribe", tmp_path)
    servo = compare(
        {**settings, 11: 0.0}, None, load_program(job), load_profile("grbl-plotter-scribe")
    )
    assert not [w for w in servo.warnings if "$11" in w]


def test_a_tool_length_offset_is_not_a_move(tmp_path):
    """G43.1's Z word is the offset (Grbl: AXIS_COMMAND_TOOL_LENGTH_OFFSET, no motion). A
    change of the offset shifts work Z (the machine stands still): Z is unknown after it
    until a block gives Z in absolute mode, and the block is not followed. G49 cancels an
    offset the file set (Grbl then empties its planner: the offset is known to change);
    G49 in a header, with no offset set by the file, is taken as GRBL's reset state."""
    lines = ["G21 G90 G94", "G0 Z5", "G43.1 Z1.5", "G49", "G17 G21 G40 G49 G80 G90", "G0 Z4"]
    blocks = load_program(write(tmp_path, lines)).blocks
    assert not any(b.motion for b in blocks[2:5])
    assert blocks[1].modal.z == 5.0 and [b.modal.z for b in blocks[2:5]] == [None] * 3
    assert blocks[2].unfollowed == "G43.1 changes the tool length offset (work Z)"
    assert blocks[3].unfollowed == "G49 cancels the tool length offset (work Z)"
    assert [b.sync for b in blocks[2:5]] == [False, True, False]  # the first: not known
    assert not blocks[4].unfollowed
    assert blocks[5].motion and blocks[5].modal.z == 4.0


def _stream_timing(tmp_path, monkeypatch, grbl_11, profile_11, drop_11=False):
    """Stream the exported 3018 job to the emulator with ``$11=grbl_11`` (the firmware not
    reporting it with ``drop_11``) against the profile at ``profile_11``; returns the
    ``$11`` of each timing of the job, and the progress reports."""
    import dataclasses

    from scratchfab.machine import sender_program
    from scratchfab.machine.sender import Streamer
    from scratchfab.machine.stream_job import StreamCallbacks, StreamRequest, stream_file

    base = load_profile("grbl-3018-diamond")
    profile = dataclasses.replace(
        base, motion=dataclasses.replace(base.motion, junction_deviation_mm=profile_11)
    )
    job, settings = _exported_job("grbl-3018-diamond", tmp_path)
    travel = {130 + k: t for k, t in enumerate(base.envelope.max_travel_mm) if t is not None}
    timed = []
    time_it = sender_program.Program.timed_for

    def counted(self, settings):
        timed.append(settings.get(11))
        return time_it(self, settings)

    monkeypatch.setattr(sender_program.Program, "timed_for", counted)
    if drop_11:
        connect = Streamer.connect

        def without_11(self):
            info = connect(self)
            del info.settings[11]
            return info

        monkeypatch.setattr(Streamer, "connect", without_11)
    url = "grblsim://?baud=0&time_scale=0.0005&" + "&".join(
        f"${k}={v:g}" for k, v in {**settings, **travel, 11: grbl_11}.items()
    )
    reports = []
    said = []
    req = StreamRequest(job, url, machine=profile, banner_timeout=0.3)
    stream_file(req, StreamCallbacks(reports.append, said.append, lambda: "stop", lambda _: True))
    return timed, reports, said, job, settings


@pytest.mark.parametrize(("grbl_11", "want"), [(0.01, [0.01]), (0.05, [0.05, 0.01])])
def test_connect_times_the_job_once_per_distinct_junction_deviation(
    grbl_11, want, tmp_path, monkeypatch
):
    """The ETA's timing at GRBL's $11 is the $11 check's too; the profile's $11 is timed
    only where it differs. (Before: three timings, GRBL's $11 twice.)"""
    timed, _, said, _, _ = _stream_timing(tmp_path, monkeypatch, grbl_11, 0.01)
    assert timed == want
    assert bool([s for s in said if "$11" in s]) == (grbl_11 != 0.01)  # the check still runs


def test_eta_takes_the_profiles_junction_deviation_where_grbl_does_not_report_it(
    tmp_path, monkeypatch
):
    """Firmware without $11 in its $$: the ETA times corners at the profile's 0.05 mm, not
    at GRBL's default 0.01; the first report's ETA is the rest of that timing from the
    block the machine is on (less the part of it already run)."""
    timed, reports, _, job, settings = _stream_timing(
        tmp_path, monkeypatch, 0.01, 0.05, drop_11=True
    )
    assert timed == [0.05]
    first = reports[0]
    remaining = [
        simulate(job.read_text().splitlines(), grbl({**settings, 11: j})).seconds
        for j in (0.05, 0.01)
    ]
    program = load_program(job).timed_for({**settings, 11: 0.05})
    assert first.ran is not None and first.ran <= first.acked
    done = sum(b.seconds for b in program.blocks[: first.ran])
    running = program.blocks[first.ran].seconds
    assert first.eta_s + done <= remaining[0] * (1 + 2e-3)
    assert first.eta_s + done + running >= remaining[0] * (1 - 2e-3)
    assert abs(first.eta_s + done - remaining[1]) > 0.02 * remaining[1]  # default $11: far off


def test_a_resumed_streams_progress_starts_at_its_resume_line(tmp_path):
    """Resumed at a stroke k: the first report (sent before anything is acknowledged, while
    the preamble travels back) already counts the k lines before as done and gives the time
    of the rest, as the reports after it do; not 0 lines and the whole job's time."""
    from stream_helpers import FAST
    from test_stream_lift import z_job

    from scratchfab.machine.sender import Streamer, open_port
    from scratchfab.machine.sender_journal import Journal
    from scratchfab.machine.sender_program import resume_preamble

    job = tmp_path / "job.gcode"
    z_job(job, strokes=3)
    prog = load_program(job)
    start = prog.strokes[2][0]
    rest = sum(b.seconds for b in prog.blocks[start:])
    reports = []
    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    try:
        streamer = Streamer(port, FAST, on_progress=reports.append)
        streamer.connect()
        # answers now come 0.2 s after their line: the first report precedes every ack
        port.sim.options = replace(port.sim.options, latency=0.1)
        journal = Journal(tmp_path / "j.jsonl").open()
        streamer.stream(prog, journal, start, resume_preamble(prog, start), resume=True)
        journal.close()
    finally:
        port.close()
    assert reports[-1].final and reports[-1].acked == len(prog.blocks)
    assert all(r.acked >= start for r in reports), [r.acked for r in reports[:3]]
    assert reports[0].acked == start  # nothing acknowledged yet at the first report
    assert reports[0].eta_s == pytest.approx(rest)
    assert all(r.eta_s <= rest + 1e-9 for r in reports)
