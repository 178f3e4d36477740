"""The stop's executed-through on a machine with coarse steps (``$100``-``$102``).

GRBL reports its position in whole steps: its targets are rounded to steps (``lround``)
and its Bresenham steps stay within half a step of the line between them, so a reported
position lies up to a step off the sender's line on each axis. The positions here are
the steps Grbl's own stepper takes (counted below, as its ``st_prep_buffer`` and
``stepper_pulse`` do), not the sender's arithmetic.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from grbl_planner_sim import steps_taken

from scratchfab.machine.sender import ControllerInfo, Status, Streamer, steps_counted_until
from scratchfab.machine.sender_program import TimeLeft, load_program, resume_preamble

STEPS_PER_MM = 80.0  # a belt-driven X/Y: 0.0125 mm a step

# Z up, to (-0.006, 0.006), down, then a cut to (9.994, 5.006): Grbl rounds both ends
# to whole steps, (0, 0) and (800, 400); later a second cut along Y2.5 crosses the
# first one's middle (block 8)
JOB = (
    "G21G90\nG0Z1\nG0X-0.006Y0.006\nG1Z-0.1F100\nG1X9.994Y5.006\n"
    "G0Z1\nG0X0Y2.5\nG1Z-0.1\nG1X10Y2.5\nG0Z1\n"
)
CUT = 4  # the index of G1X9.994Y5.006 (block 0 is G21G90)


def _lround(v: float) -> int:
    """C's lround: halves away from zero."""
    return int(v + 0.5) if v >= 0 else -int(-v + 0.5)


def _grbl_steps(start, end, spm: float) -> list[tuple[float, ...]]:
    """Every position (mm) Grbl's Bresenham stepper passes from ``start`` to ``end``."""
    zero, k = (0.0,) * len(start), (spm,) * len(start)
    path = _stepper(_machine_steps(start, zero, k), _machine_steps(end, zero, k))
    return [_work_at(q, zero, k) for q in path]


def _stepper(a, b, level: int = 0) -> list[tuple[int, ...]]:
    """Every step position (counts) Grbl's stepper passes from step ``a`` to step ``b``.

    Grbl (AMASS on, its default): the block's counts scaled by 8 (<< MAX_AMASS_LEVEL),
    st.counter_x = st.exec_block->step_event_count >> 1; at AMASS ``level`` the interrupt
    ticks 2**level times a step event, adding the counts >> level (a minor axis may step
    between two steps of the major one): every tick's position.
    """
    n = [abs(q - p) for p, q in zip(a, b, strict=True)]
    sign = [1 if q >= p else -1 for p, q in zip(a, b, strict=True)]
    events = max(n)
    scaled = events << 3
    counter = [scaled >> 1] * len(a)
    pos = list(a)
    out = [tuple(pos)]
    for _ in range(events << level):
        for k in range(len(a)):
            counter[k] += (n[k] << 3) >> level
            if counter[k] > scaled:
                counter[k] -= scaled
                pos[k] += sign[k]
        if tuple(pos) != out[-1]:
            out.append(tuple(pos))
    return out


def _streamer(tmp_path, spm: float | None, text: str = JOB) -> Streamer:
    """A Streamer whose every block was acknowledged before the stop's position report."""
    job = tmp_path / "job.gcode"
    job.write_text(text)
    prog = load_program(job).placed_at((0.0, 0.0))
    s = Streamer.__new__(Streamer)
    settings = {} if spm is None else {100: spm, 101: spm, 102: 400.0}
    s.info = ControllerInfo(settings=settings)
    s._program = prog
    s._all_ran = False
    s._acked_blocks = list(range(len(prog.blocks)))
    s._acks_at_status = len(prog.blocks)
    return s


def _guess(s: Streamer, wpos, wco=None) -> int:
    """The stop's executed-through at work position ``wpos``; ``wco``: the report's offset
    (None: not known, matched by mm), its ``MPos`` given."""
    return s._executed_guess(Status(wpos=tuple(wpos), wco=wco, mpos_given=True))


def _cut_path() -> list[tuple[float, float]]:
    return _grbl_steps((-0.006, 0.006), (9.994, 5.006), STEPS_PER_MM)


def test_the_cut_crosses_a_later_one_where_grbl_stands_off_the_senders_line(tmp_path):
    # the setting of the tests below: Grbl at step (401, 200) on the cut, off its line
    # by more than 0.01 mm, and on the later cut along Y2.5
    path = _cut_path()
    assert path[0] == (0.0, 0.0) and path[-1] == (10.0, 5.0)
    assert (401 / STEPS_PER_MM, 200 / STEPS_PER_MM) in path
    a, b = (-0.006, 0.006), (9.994, 5.006)
    p = (5.0125, 2.5)
    cross = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
    assert abs(cross) / ((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2) ** 0.5 > 0.013


@pytest.mark.parametrize("spm", [STEPS_PER_MM, 40.0])
def test_a_stop_anywhere_on_the_cut_is_not_taken_for_a_later_block(tmp_path, spm):
    """Safety: stopped on any step Grbl takes along the cut before its end, the journal
    never trusts the cut nor any block after it, although the later cut along Y2.5
    passes through some of them; at its end (Grbl's, in whole steps) the cut ran."""
    s = _streamer(tmp_path, spm)
    path = _grbl_steps((-0.006, 0.006), (9.994, 5.006), spm)
    for x, y in path[:-1]:
        assert _guess(s, (x, y, -0.1)) <= CUT - 1, (x, y)
    assert _guess(s, (*path[-1], -0.1)) <= CUT
    for z in range(400, -41, -1):  # the plunge's steps, Z at 400 steps/mm: it may not end
        assert _guess(s, (0.0, 0.0, z / 400.0)) <= CUT - 2, z


def test_a_stop_a_step_short_of_the_cuts_end_is_not_taken_for_its_end(tmp_path):
    # the last acknowledged block, stopped a step short (within the match's tolerance of
    # its end): it counts as interrupted, so a resume cuts it again
    s = _streamer(tmp_path, STEPS_PER_MM)
    s._acked_blocks = list(range(CUT + 1))
    s._acks_at_status = CUT + 1
    short = _cut_path()[-2]
    assert short == (799 / STEPS_PER_MM, 399 / STEPS_PER_MM)
    assert _guess(s, (*short, -0.1)) == CUT - 1


def test_a_move_ended_within_less_than_half_a_step_counts_as_run(tmp_path):
    # at 40 steps/mm Grbl's end of the cut (10, 5) lies 0.0085 mm from the sender's, less
    # than the 0.0115 mm a stop a step short cannot come nearer than: the cut ran; at 80
    # steps/mm it is as far, more than the 0.00525 mm there: taken as interrupted
    s = _streamer(tmp_path, 40.0)
    assert _guess(s, (10.0, 5.0, -0.1)) == CUT
    s = _streamer(tmp_path, STEPS_PER_MM)
    assert _guess(s, (10.0, 5.0, -0.1)) == CUT - 1


def test_a_move_that_ended_on_whole_steps_counts_as_run(tmp_path):
    # precision kept: at the exact end of a move (on the step grid) the move ran, and so
    # did the blocks up to the next move
    s = _streamer(tmp_path, STEPS_PER_MM)
    assert _guess(s, (0.0, 2.5, 1.0)) == 6  # the end of G0X0Y2.5
    assert _guess(s, (10.0, 2.5, -0.1)) == 8  # the end of the second cut
    s._acked_blocks = list(range(9))
    s._acks_at_status = 9
    assert _guess(s, (10.0, 2.5, -0.1)) == 8  # the last acknowledged one


def test_a_stop_at_a_corner_rounded_off_both_moves_is_not_taken_for_a_later_block(tmp_path):
    # the plunge ends at (20.006, -0.006), Grbl's step (1600, 0); there the tool stands
    # past the plunge's end and before the cut's start along its line (10, 5), on
    # neither; the later cut along Y0 passes there
    text = (
        "G21G90\nG0Z1\nG0X20.006Y-0.006\nG1Z-0.1F100\nG1X30.006Y4.994\n"
        "G0Z1\nG0X15Y0\nG1Z-0.1\nG1X25Y0\nG0Z1\n"
    )
    s = _streamer(tmp_path, STEPS_PER_MM, text)
    assert _lround(20.006 * STEPS_PER_MM) == 1600 and _lround(-0.006 * STEPS_PER_MM) == 0
    assert _guess(s, (20.0, 0.0, -0.1)) <= CUT - 1
    # a job resumed at the cut: the plunge is not a candidate, only the cut's start tells
    s._acked_blocks = list(range(CUT, len(s._program.blocks)))
    s._acks_at_status = len(s._acked_blocks)
    assert _guess(s, (20.0, 0.0, -0.1)) == CUT - 1


def test_without_steps_only_a_position_within_the_reports_rounding_is_an_end(tmp_path):
    # steps unknown: 0.002 mm (a report's rounding) counts as the end, 0.005 mm short not
    s = _streamer(tmp_path, None)
    s._acked_blocks = list(range(CUT + 1))
    s._acks_at_status = CUT + 1
    assert _guess(s, (9.9945, 5.0055, -0.1)) == CUT
    assert _guess(s, (9.99, 5.004, -0.1)) == CUT - 1


def test_a_stop_on_the_next_move_is_not_taken_for_one_short_of_the_end(tmp_path):
    # the cut ended at Grbl's (10, 5), too far from the sender's end to tell it ran; Grbl
    # then went 8 Z steps up the G0Z1: the cut ran, the G0Z1 did not end
    s = _streamer(tmp_path, STEPS_PER_MM)
    assert _guess(s, (10.0, 5.0, -0.1 + 8 / 400.0)) == CUT
    # 1 Z step up lies within Z's rounding: maybe the cut stopped short, it is cut again
    assert _guess(s, (10.0, 5.0, -0.1 + 1 / 400.0)) == CUT - 1


@pytest.mark.parametrize(
    ("x", "spm", "through"),
    [
        (10.006, 40.0, CUT),
        (10.006, STEPS_PER_MM, CUT - 1),
        (9.994, 40.0, CUT),
        (9.994, STEPS_PER_MM, CUT),
    ],
)
def test_a_move_grbl_ended_off_the_senders_end_counts_as_run_unless_a_step_short_may_be_there(
    tmp_path, x, spm, through
):
    # Grbl ends G1X10.006 and G1X9.994 on X 10 (steps rounded). 0.006 mm before the
    # sender's end: at 40 steps/mm a stop a step short stands 0.0115 mm behind it at
    # least, so there the cut ran; at 80 steps/mm 0.00525 mm: it may not have. Past the
    # end no stop on the move stands: it ran
    text = f"G21G90\nG0Z1\nG0X0Y0\nG1Z-0.1F100\nG1X{x}\nG0Z1\n"
    s = _streamer(tmp_path, spm, text)
    assert _lround(x * spm) / spm == 10.0
    assert _guess(s, (10.0, 0.0, -0.1)) == through
    assert _guess(s, (10.0, 0.0, -0.1 + 4 / 400.0)) == through  # 4 Z steps up
    s._acked_blocks = list(range(CUT + 1))  # the cut acknowledged last
    s._acks_at_status = CUT + 1
    assert _guess(s, (10.0, 0.0, -0.1)) == through


def test_a_position_off_every_acknowledged_move_trusts_only_the_planner_bound(tmp_path):
    # at the cut's end in X and Y but 0.6 mm above it: on no acknowledged move (an old
    # or garbled report), so nothing after the blocks the planner bound says ran counts
    s = _streamer(tmp_path, STEPS_PER_MM)
    s._acked_blocks = list(range(CUT + 1))
    s._acks_at_status = CUT + 1
    assert _guess(s, (9.994, 5.006, 0.5)) == -1


def test_a_move_on_an_axis_of_unknown_position_never_counts_as_ended(tmp_path):
    # streamed from a start the sender was not told: X counts from an assumed start, so
    # the machine may stand anywhere along G91 X5 (Z known, resumed there): it is the
    # interrupted move, whichever of the later ones passes where it stands
    text = "G21G90\nG0Z2\nG0Z1\nG91G0X5\nG90\nG0X-5Y0\nG0X10\n"
    s = _streamer(tmp_path, STEPS_PER_MM, text)
    s._program = load_program(tmp_path / "job.gcode")  # not placed
    s._acked_blocks = list(range(3, len(s._program.blocks)))
    s._acks_at_status = len(s._acked_blocks)
    assert _guess(s, (2.0, 0.0, 1.0)) == 2
    assert _guess(s, (5.0, 0.0, 1.0)) == 2  # X5 read from an unknown start


def test_an_increment_from_an_unknown_z_never_counts_as_ended(tmp_path):
    # G91 Z1 from a Z the sender does not know (the machine stands at work Z 7): the
    # move's Z is unknown at both ends, yet it moves: a stop at its start is on it
    text = "G21G91\nG0Z1\nG90G0X1Y1\nG1X5F100\n"
    s = _streamer(tmp_path, STEPS_PER_MM, text)
    assert _guess(s, (0.0, 0.0, 7.0)) == 0
    assert _guess(s, (0.0, 0.0, 8.0)) == 0  # or at its end: unknown, it may not be


@pytest.mark.parametrize("real_spm", [STEPS_PER_MM, 40.0])
def test_without_steps_a_stop_anywhere_on_the_cut_of_a_coarse_machine_is_not_taken_for_later(
    tmp_path, real_spm
):
    """Safety where ``$100``-``$102`` are not known: Grbl's steps on a coarse machine stand
    off the cut's line by more than a report's rounding (at step (401, 200), 0.013 mm), on
    the later cut along Y2.5; the journal still never trusts the cut nor a later block."""
    s = _streamer(tmp_path, None)
    path = _grbl_steps((-0.006, 0.006), (9.994, 5.006), real_spm)
    for x, y in path[:-1]:
        assert _guess(s, (x, y, -0.1)) <= CUT - 1, (x, y)


def test_the_step_reference_is_grbls_amass_stepper():
    # an odd count of events (3, the minor axis 2 steps): Grbl's AMASS-scaled counters
    # step the minor axis at the first event, as grbl_planner_sim's stepper does
    spm = 40.0
    end = (3 / spm, 2 / spm)
    path = _grbl_steps((0.0, 0.0), end, spm)
    length = math.hypot(*end)
    want = [
        steps_taken((0.0, 0.0, 0.0), (*end, 0.0), length * k / 3, (spm, spm, spm))[:2]
        for k in range(4)
    ]
    assert path == want
    assert path[1] == (1 / spm, 1 / spm)


def _inch_report(mm: float) -> float:
    """A coordinate as GRBL prints it under ``$13=1`` (4 decimals of an inch), in mm."""
    return round(mm / 25.4, 4) * 25.4


def test_under_inch_reports_a_stop_a_step_short_is_not_taken_for_the_end(tmp_path):
    # G1X9.99385 ends on Grbl's step 800 (799.508 rounded); a step short, X 9.9875, lies
    # 0.00635 mm behind the sender's end. Inch reports round MPos and WCO to 0.00254 mm
    # each: at the worst offset the reported X comes 0.0025 mm nearer, within the 0.00525
    # mm (half a step, less a mm report's rounding) a stop can no longer be short by
    text = "G21G90\nG0Z1\nG0X0Y0\nG1Z-0.1F100\nG1X9.99385\nG0Z1\n"
    s = _streamer(tmp_path, STEPS_PER_MM, text)
    s.info.settings[13] = 1.0
    assert _lround(9.99385 * STEPS_PER_MM) == 800
    short = 799 / STEPS_PER_MM
    wco = max(
        (k / 1000.0 for k in range(-30000, 0)),
        key=lambda w: _inch_report(short + w) - _inch_report(w),
    )
    x = _inch_report(short + wco) - _inch_report(wco)
    assert 9.99385 - x < STEPS_PER_MM**-1 / 2 - 0.001
    assert _guess(s, (x, 0.0, -0.1)) == CUT - 1
    s.info.settings[13] = 0.0  # in mm reports that X cannot be a step short: the cut ran
    assert _guess(s, (x, 0.0, -0.1)) == CUT


# ------------------------------------------------------------------ in whole steps


def _report(work, wco, spm_xyz, digits: int = 3, wpos_given: bool = False):
    """Grbl's hold report at work position ``work`` (its steps) under offset ``wco``: MPos
    and WCO each rounded to the report's digits; the sender's work position is their
    difference (as ``parse_status`` computes it). ``wpos_given`` (``$10=0``): WPos
    rounded instead, MPos counted from it."""
    wco_r = tuple(round(o, digits) for o in wco)
    if wpos_given:
        wpos = tuple(round(w, digits) for w in work)
        mpos = tuple(w + o for w, o in zip(wpos, wco_r, strict=True))
        return Status(state="Hold:0", mpos=mpos, wpos=wpos, wco=wco_r, wco_printed=True)
    mpos = tuple(round(w + o, digits) for w, o in zip(work, wco, strict=True))
    wpos = tuple(m - o for m, o in zip(mpos, wco_r, strict=True))
    return Status(
        state="Hold:0", mpos=mpos, wpos=wpos, wco=wco_r, mpos_given=True, wco_printed=True
    )


def _machine_steps(work, wco, spm_xyz) -> tuple[int, ...]:
    """Grbl's whole steps for a work target: lround((work + offset) * steps/mm) per axis."""
    return tuple(_lround((w + o) * k) for w, o, k in zip(work, wco, spm_xyz, strict=True))


def _work_at(steps, wco, spm_xyz) -> tuple[float, ...]:
    return tuple(n / k - o for n, o, k in zip(steps, wco, spm_xyz, strict=True))


def _streamer_spm(tmp_path, text: str, spm_xyz) -> Streamer:
    s = _streamer(tmp_path, None, text)
    s.info = ControllerInfo(settings={100 + k: v for k, v in enumerate(spm_xyz)})
    return s


# the rapid ends 0.48 step (Y) from Grbl's end at 80 steps/mm, then the plunge starts
_RAPID = "G21G90\nG0Z2\nG0X7.741Y-0.163\nG0X-29.292Y-18.456\nG1Z-0.05F200\nG1X-28.524Y-19.654\n"


def test_a_move_grbl_ended_half_a_step_off_the_senders_end_ran_by_its_steps(tmp_path):
    # Grbl's end of G0X-29.292Y-18.456 is step (-2343, -1476): Y -18.450, 0.006 mm (0.48
    # step) short of the sender's; a stop a step down the plunge. By mm the rapid may have
    # stopped short (cut again); in steps X, the axis with the most steps, is at its end
    spm = (80.0, 80.0, 80.0)
    s = _streamer_spm(tmp_path, _RAPID, spm)
    wco = (0.0, 0.0, 0.0)
    end = _machine_steps((-29.292, -18.456, 2.0), wco, spm)
    assert end == (-2343, -1476, 160)
    plunge = _stepper(end, _machine_steps((-29.292, -18.456, -0.05), wco, spm))
    report = _report(_work_at(plunge[1], wco, spm), wco, spm)
    assert _guess(s, report.wpos) == 2  # by mm (no offset known): the rapid is cut again
    assert s._executed_guess(report) == 3
    at_end = _report(_work_at(end, wco, spm), wco, spm)  # before the plunge's first step
    assert s._executed_guess(at_end) == 3
    # a step short of it on X: not run, although within the mm match of its end
    short = _stepper(_machine_steps((7.741, -0.163, 2.0), wco, spm), end)[-2]
    assert s._executed_guess(_report(_work_at(short, wco, spm), wco, spm)) == 2


_WCOS = [(0.0, 0.0, 0.0), (5.0125, 7.33337, 1.00045), (-3.2, 11.118, -7.5)]


@pytest.mark.parametrize("spm", [250.0, 800.0])
@pytest.mark.parametrize("wco", _WCOS)
@pytest.mark.parametrize("cut", ["X10Y5.003", "X5.001Y10.002"])
def test_in_whole_steps_a_stop_a_step_short_never_passes_for_the_end(tmp_path, spm, wco, cut):
    """Steps of 0.004 and 0.00125 mm, under the 0.01 mm the match allows: by whole steps
    (Grbl's lround of the target plus the offset; the report's MPos and WCO rounded to
    3 decimals) no step before the cut's end passes for it, and its end does where every
    offset the report's WCO may stand for puts it on one step."""
    spm_xyz = (spm, spm, spm)
    text = f"G21G90\nG0Z1\nG0X0Y0\nG1Z-0.1F100\nG1{cut}\nG0Z1\n"
    s = _streamer_spm(tmp_path, text, spm_xyz)
    s._acked_blocks = list(range(CUT + 1))
    s._acks_at_status = CUT + 1
    x, y = (float(v) for v in cut[1:].split("Y"))
    path = _stepper(
        _machine_steps((0.0, 0.0, -0.1), wco, spm_xyz), _machine_steps((x, y, -0.1), wco, spm_xyz)
    )
    for n, q in enumerate(path[:-1]):
        guess = s._executed_guess(_report(_work_at(q, wco, spm_xyz), wco, spm_xyz))
        # near its start it may be on the first G0Z1 too (from an unknown Z, at X0 Y0)
        assert guess == CUT - 1 or (n < 10 and guess < CUT), q
    end = s._executed_guess(_report(_work_at(path[-1], wco, spm_xyz), wco, spm_xyz))
    k, v = (0, x) if x > y else (1, y)  # the axis with the most steps
    told = round(wco[k], 3)  # each offset the report's WCO may stand for, its end's step:
    ends = {_lround((v + told + d / 1e5) * spm) for d in range(-50, 51)}
    assert end == CUT if len(ends) == 1 else end in (CUT - 1, CUT)


def test_whole_steps_tell_most_ends_at_250_and_800_steps(tmp_path):
    # the test above is not vacuous: with the offset 0 the X cut's end is one step (2500,
    # 8000) and the Y cut's a half at 250 steps/mm (10.002: 2500.5)
    assert {_lround((10.0 + d / 1e5) * k) for d in range(-50, 51) for k in (250, 800)} == {
        2500,
        8000,
    }
    assert {_lround((10.002 + d / 1e5) * 250) for d in range(-50, 51)} == {2500, 2501}


def _random_job(rng) -> tuple[str, list[tuple[float, float, float]]]:
    """A job of straight moves: retraces, sub-step and collinear moves, plunges; its text
    and each move's work end (the first line sets units, the first move Z only)."""
    pts: list[tuple[float, float, float]] = [(0.0, 0.0, 1.0)]
    lines = ["G21G90", "G0Z1"]
    for _ in range(24):
        x, y, z = pts[-1]
        kind = rng.integers(6)
        if kind == 0 and len(pts) > 2:
            p = pts[int(rng.integers(len(pts) - 1))]  # back to an earlier point
        elif kind == 1:
            p = (x + float(rng.choice([-1, 1])) * 0.001, y, z)  # under a step
        elif kind == 2:
            p = (x, y, round(float(rng.uniform(-0.2, 1.0)), 3))  # up or down
        elif kind == 3 and len(pts) > 1:  # on along the last move's line
            a = pts[-2]
            p = tuple(round(v + 0.5 * (v - u), 3) for u, v in zip(a, pts[-1], strict=True))
        else:
            p = (round(float(rng.uniform(-6, 6)), 3), round(float(rng.uniform(-6, 6)), 3), z)
        pts.append(p)
        lines.append(f"G1X{p[0]:.3f}Y{p[1]:.3f}Z{p[2]:.3f}F300")
    return "\n".join(lines) + "\n", pts


@pytest.mark.parametrize("seed", range(8))
def test_fuzz_random_jobs_never_trust_a_move_that_had_not_run(tmp_path, seed):
    """Random jobs, steps/mm and offsets (below a report's digit too): stopped on any step
    Grbl passes on a move (lround targets, AMASS Bresenham, MPos or WPos and WCO rounded
    to 3 decimals, a planner's worth acknowledged past it), the executed-through never counts
    that move; at its last step it counts it where the steps tell (most of them)."""
    rng = np.random.default_rng(seed)
    text, pts = _random_job(rng)
    spm = float(rng.choice([40.0, 80.0, 250.0, 800.0]))
    spm_xyz = (spm, spm, float(rng.choice([spm, 400.0])))
    wco = tuple(round(float(v), 5) for v in rng.uniform(-20, 20, 3))
    given = bool(seed % 2)  # WPos reported ($10=0): the machine position to two digits

    def report(q):
        return _report(_work_at(q, wco, spm_xyz), wco, spm_xyz, wpos_given=given)

    s = _streamer_spm(tmp_path, text, spm_xyz)
    machine = [_machine_steps((0.0, 0.0, 5.0), wco, spm_xyz)]  # Z where the job starts
    machine += [_machine_steps(p, wco, spm_xyz) for p in pts]
    ends = total = 0
    for k in range(1, len(machine)):  # block k moves from machine[k - 1] to machine[k]
        s._acked_blocks = list(range(min(len(machine), k + 12)))
        s._acks_at_status = len(s._acked_blocks)
        path = _stepper(machine[k - 1], machine[k], level=seed % 4)
        inside = path[1:-1]  # on the move, its first step taken: it had not ended
        for q in inside[:: max(1, len(inside) // 16)] + inside[-3:]:
            assert s._executed_guess(report(q)) <= k - 1, (k, q)
        if len(path) > 1:
            ran = k  # and the moves after it Grbl drops (no step: nothing to run)
            while ran + 1 < len(machine) and machine[ran + 1] == machine[k]:
                ran += 1
            got = s._executed_guess(report(path[-1]))
            assert got <= ran, (k, path[-1])
            ends += got >= k
            total += 1
    # not vacuous: most ends count, but where the reports leave its step open (an offset
    # under a report's digit) or the job came back to a point an earlier candidate passes
    assert ends >= total // 3, (ends, total)


def test_the_time_left_takes_a_corner_rounded_off_both_moves_for_the_next_ones_start(tmp_path):
    # the corner of the test above: Grbl at step (1600, 0), past the plunge's end and
    # before the cut's start along their lines; the ETA's run point goes to the cut's
    # start, as the stop's match takes it (it stayed at the job's start)
    text = (
        "G21G90\nG0Z1\nG0X20.006Y-0.006\nG1Z-0.1F100\nG1X30.006Y4.994\n"
        "G0Z1\nG0X15Y0\nG1Z-0.1\nG1X25Y0\nG0Z1\n"
    )
    s = _streamer(tmp_path, STEPS_PER_MM, text)
    corner = (_lround(20.006 * STEPS_PER_MM) / STEPS_PER_MM, 0.0, -0.1)
    last = len(s._program.blocks) - 1
    left = TimeLeft(s._program, tol=s._step_tol(), step_mm=s._step_mm())
    left.update(last, last, corner)
    assert left.ran == CUT
    assert math.isclose(left.seconds, sum(b.seconds for b in s._program.blocks[CUT:]))


@pytest.mark.parametrize(
    ("line", "counted"),
    [
        ("G1X2", 4),  # no change of the frame: every block
        ("G92X0", 2),  # a work offset set: a report's WCO may be the old frame's
        ("G92.1", 2),
        ("G10L20P1X0", 2),
        ("G55", 2),
        ("G43.1Z0.5", 2),
        ("G49", 4),  # no offset set before: GRBL's own 0 after a reset, no change
        ("G91G1X1", 2),  # increments summed in single precision
        ("G54G1X2", 4),  # the system already in use
        ("G1X2(G92)", 4),  # a comment is no block
    ],
)
def test_steps_are_matched_until_the_first_change_of_the_work_offset(tmp_path, line, counted):
    job = tmp_path / "job.gcode"
    job.write_text(f"G21G90\nG0Z1X1\n{line}\nG1X3F100\n")
    assert steps_counted_until(load_program(job).blocks) == counted


def test_an_offset_summed_from_the_parameters_is_not_taken_for_grbls_own(tmp_path):
    """Safety: before any report printed ``WCO:`` (a build without the field, or early in
    a job) the sender's offset is ``$#``'s G54 plus G92, each rounded to a digit: here
    0.000 + 0.000 for Grbl's 0.0008 mm. At 800 steps/mm Grbl's X for the cut along Y at
    X0 is step 1 (lround(0.64)); stopped on it, the cut is never taken for a move the
    machine is off (which would skip it for the later cut through the same point)."""
    text = "G21G90\nG0Z1\nG0X0Y0\nG1Z-0.1F100\nG1X0Y10\nG0Z1\nG0X-5Y5\nG1Z-0.1\nG1X5Y5\nG0Z1\n"
    spm = (800.0, 800.0, 800.0)
    s = _streamer_spm(tmp_path, text, spm)
    g54, g92 = (0.0004, 0.0, 0.0), (0.0004, 0.0, 0.0)
    grbl = tuple(a + b for a, b in zip(g54, g92, strict=True))
    summed = tuple(round(a, 3) + round(b, 3) for a, b in zip(g54, g92, strict=True))
    for y in (0.5, 5.0, 9.5):  # stopped on the cut (block 4)
        q = _machine_steps((0.0, y, -0.1), grbl, spm)
        assert q[0] == 1
        mpos = tuple(round(n / k, 3) for n, k in zip(q, spm, strict=True))
        wpos = tuple(m - o for m, o in zip(mpos, summed, strict=True))
        report = Status(state="Hold:0", mpos=mpos, wpos=wpos, wco=summed, mpos_given=True)
        assert s._executed_guess(report) <= CUT - 1, y
    # the same offset as a report printed it (WCO:0.001): matched in whole steps
    printed = tuple(round(o, 3) for o in grbl)
    end = _machine_steps((0.0, 10.0, -0.1), grbl, spm)
    report = _report(_work_at(end, grbl, spm), grbl, spm)
    assert report.wco == printed and s._executed_guess(report) == CUT


def test_a_reports_wco_is_marked_printed_and_kept_so_for_later_reports():
    s = Streamer.__new__(Streamer)
    s.info = ControllerInfo(settings={})
    s._wco, s._wco_printed, s._acked_blocks = (1.0, 2.0, 3.0), False, []
    s._hold_unseen = False
    s._note_status("<Idle|MPos:1.000,2.000,3.000|FS:0,0>")
    assert s.status.wco == (1.0, 2.0, 3.0) and not s.status.wco_printed  # $#'s sum
    s._note_status("<Idle|MPos:1.000,2.000,3.000|FS:0,0|WCO:1.001,2.000,3.000>")
    assert s.status.wco_printed
    s._note_status("<Idle|MPos:1.000,2.000,3.000|FS:0,0>")
    assert s.status.wco == (1.001, 2.0, 3.0) and s.status.wco_printed


def test_a_resumed_sessions_first_move_starts_where_the_preamble_left_the_machine(tmp_path):
    """Safety: a resume preamble writes its numbers to 4 decimals, so X0.00006 becomes
    X0.0001. Under Grbl's offset 0.00049 (printed WCO:0.000) at 850 steps/mm that is
    step 1, while the file's X is step 0: the resumed plunge also steps X back. Stopped
    on it before that step, the machine stands a step beyond where the file's numbers put
    the plunge on X; the plunge is still the interrupted move (not one the machine is
    off), although a later plunge passes there."""
    text = "G21G90\nG0Z1\nG0X0.00006Y0\nG1Z-0.1F100\nG1Y10\nG0Z1\nG0X0.001Y0\nG1Z-0.1\nG1X5\nG0Z1\n"
    spm = (850.0, 850.0, 800.0)
    s = _streamer_spm(tmp_path, text, spm)
    plunge = 3
    preamble = resume_preamble(s._program, plunge)
    assert "G0X0.0001Y0" in preamble
    s._acked_blocks = list(range(plunge, len(s._program.blocks)))
    s._acks_at_status = len(s._acked_blocks)
    wco = (0.00049, 0.0, 0.0)
    left = _machine_steps((0.0001, 0.0, 1.0), wco, spm)  # the preamble's end
    end = _machine_steps((0.00006, 0.0, -0.1), wco, spm)
    assert left[0] == 1 and end[0] == 0
    path = _stepper(left, end)
    assert path[1][0] == 1  # Z steps first
    for q in path[1:-1]:
        report = _report(_work_at(q, wco, spm), wco, spm)
        assert s._executed_guess(report) <= plunge - 1, q
    # resumed at a block that moves nothing (M3 before the plunge): the plunge is still
    # the session's first move, started where the preamble left the machine
    s = _streamer_spm(tmp_path, text.replace("G1Z-0.1F100\n", "M3S1000\nG1Z-0.1F100\n"), spm)
    s._acked_blocks = list(range(plunge, len(s._program.blocks)))
    s._acks_at_status = len(s._acked_blocks)
    for q in path[1:-1]:
        report = _report(_work_at(q, wco, spm), wco, spm)
        assert s._executed_guess(report) <= plunge, q


def test_a_resumed_sessions_later_moves_keep_the_preambles_numbers_on_axes_not_given_again(
    tmp_path,
):
    """Safety: after the resume preamble's X0.0001 (the file's X0.00006 to 4 decimals) the
    machine stays on X step 1 through every block that does not give X again: Grbl keeps
    the preamble's X for the plunge and the cut along Y (G1Y10), not the file's (step 0).
    Stopped at the plunge's end, before the cut's first step, or a few steps into the
    cut, the cut has not run: it is never taken for a move the machine is off, which let
    the later plunge at X0.001 (step 1) and the cut along Y0 claim the stop and skip it."""
    text = "G21G90\nG0Z1\nG0X0.00006Y0\nG1Z-0.1F100\nG1Y10\nG0Z1\nG0X0.001Y0\nG1Z-0.1\nG1X5\nG0Z1\n"
    spm = (850.0, 850.0, 800.0)
    s = _streamer_spm(tmp_path, text, spm)
    plunge, cut = 3, 4
    s._acked_blocks = list(range(plunge, len(s._program.blocks)))
    s._acks_at_status = len(s._acked_blocks)
    wco = (0.00049, 0.0, 0.0)
    left = _machine_steps((0.0001, 0.0, -0.1), wco, spm)  # the plunge's end on Grbl
    assert left[0] == 1 and _machine_steps((0.00006, 0.0, -0.1), wco, spm)[0] == 0
    cut_end = _machine_steps((0.0001, 10.0, -0.1), wco, spm)
    path = _stepper(left, cut_end)
    assert all(q[0] == 1 for q in path)  # the cut keeps the preamble's X step
    for q in path[:-1]:
        report = _report(_work_at(q, wco, spm), wco, spm)
        assert s._executed_guess(report) <= cut - 1, q


def test_a_stop_on_the_resume_preambles_rapid_is_not_taken_for_a_later_move(tmp_path):
    """Safety: the resume preamble's moves (Z up, the rapid back to the stroke's start)
    are no move of the file, and with the spindle off no line of it waits for them, so
    GRBL acknowledges the stroke and the moves after it while the rapid still runs. The
    earlier session stopped on the cut at X6 and lifted; stopped again on the rapid back
    to X0 Y0 at Z1, the machine stands on the later travel along Y0 (block 6): that is
    never taken for the stroke having run (its cut from X6 on would be skipped). Once
    the plunge stands at its end, the match goes on: a stop on the next stroke's cut."""
    text = "G21G90\nG0Z1\nG0X0Y0\nG1Z-0.1F100\nG1X10Y0\nG0Z1\nG0X3Y0\nG1Z-0.1\nG1X3Y8\nG0Z1\n"
    spm = (80.0, 80.0, 400.0)
    s = _streamer_spm(tmp_path, text, spm)
    plunge, travel = 3, 6
    assert s._program.strokes[0] == (plunge, 5)
    preamble = resume_preamble(s._program, plunge)
    assert preamble[-1] == "G0X0Y0" and not any(p.startswith(("M3", "G4")) for p in preamble)
    s._acked_blocks = list(range(plunge, len(s._program.blocks)))
    s._acks_at_status = len(s._acked_blocks)
    wco = (0.0, 0.0, 0.0)
    rapid = _stepper(_machine_steps((6.0, 0.0, 1.0), wco, spm), _machine_steps((0, 0, 1), wco, spm))
    on_travel = 0
    for q in rapid[1:-1]:
        report = _report(_work_at(q, wco, spm), wco, spm)
        on_travel += s._program.blocks[travel].modal.x <= report.wpos[0]
        assert s._executed_guess(report) <= plunge - 1, q
    assert on_travel > 100  # not vacuous: much of the rapid lies on the later travel
    cut = _stepper(_machine_steps((3, 0, -0.1), wco, spm), _machine_steps((3, 8, -0.1), wco, spm))
    for q in cut[1:-1]:
        assert s._executed_guess(_report(_work_at(q, wco, spm), wco, spm)) == 7, q
