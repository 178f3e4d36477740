"""The stop's executed-through on a machine with coarse steps (``$100``-``$102``).

GRBL reports its position in whole steps: its targets are rounded to steps (``lround``)
and its Bresenham steps stay within half a step of the line between them, so a reported
position lies up to a step off the sender's line on each axis. The positions here are
the steps Grbl's own stepper takes (counted below, as its ``st_prep_buffer`` and
``stepper_pulse`` do), not the sender's arithmetic.
"""

from __future__ import annotations

import math

import pytest
from grbl_planner_sim import steps_taken

from scratchfab.machine.sender import ControllerInfo, Streamer
from scratchfab.machine.sender_program import load_program

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


def _grbl_steps(start, end, spm: float) -> list[tuple[float, float]]:
    """Every position (mm) Grbl's Bresenham stepper passes from ``start`` to ``end`` (X, Y)."""
    a = [_lround(v * spm) for v in start]
    b = [_lround(v * spm) for v in end]
    n = [abs(q - p) for p, q in zip(a, b, strict=True)]
    sign = [1 if q >= p else -1 for p, q in zip(a, b, strict=True)]
    events = max(n)
    # Grbl (AMASS on, its default): the block's counts scaled by 8 (<< MAX_AMASS_LEVEL),
    # st.counter_x = st.exec_block->step_event_count >> 1
    scaled = events << 3
    counter = [scaled >> 1] * 2
    pos = list(a)
    out = [(pos[0] / spm, pos[1] / spm)]
    for _ in range(events):
        for k in range(2):
            counter[k] += n[k] << 3
            if counter[k] > scaled:
                counter[k] -= scaled
                pos[k] += sign[k]
        out.append((pos[0] / spm, pos[1] / spm))
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
        assert s._executed_guess((x, y, -0.1)) <= CUT - 1, (x, y)
    assert s._executed_guess((*path[-1], -0.1)) <= CUT
    for z in range(400, -41, -1):  # the plunge's steps, Z at 400 steps/mm: it may not end
        assert s._executed_guess((0.0, 0.0, z / 400.0)) <= CUT - 2, z


def test_a_stop_a_step_short_of_the_cuts_end_is_not_taken_for_its_end(tmp_path):
    # the last acknowledged block, stopped a step short (within the match's tolerance of
    # its end): it counts as interrupted, so a resume cuts it again
    s = _streamer(tmp_path, STEPS_PER_MM)
    s._acked_blocks = list(range(CUT + 1))
    s._acks_at_status = CUT + 1
    short = _cut_path()[-2]
    assert short == (799 / STEPS_PER_MM, 399 / STEPS_PER_MM)
    assert s._executed_guess((*short, -0.1)) == CUT - 1


def test_a_move_ended_within_less_than_half_a_step_counts_as_run(tmp_path):
    # at 40 steps/mm Grbl's end of the cut (10, 5) lies 0.0085 mm from the sender's, less
    # than the 0.0115 mm a stop a step short cannot come nearer than: the cut ran; at 80
    # steps/mm it is as far, more than the 0.00525 mm there: taken as interrupted
    s = _streamer(tmp_path, 40.0)
    assert s._executed_guess((10.0, 5.0, -0.1)) == CUT
    s = _streamer(tmp_path, STEPS_PER_MM)
    assert s._executed_guess((10.0, 5.0, -0.1)) == CUT - 1


def test_a_move_that_ended_on_whole_steps_counts_as_run(tmp_path):
    # precision kept: at the exact end of a move (on the step grid) the move ran, and so
    # did the blocks up to the next move
    s = _streamer(tmp_path, STEPS_PER_MM)
    assert s._executed_guess((0.0, 2.5, 1.0)) == 6  # the end of G0X0Y2.5
    assert s._executed_guess((10.0, 2.5, -0.1)) == 8  # the end of the second cut
    s._acked_blocks = list(range(9))
    s._acks_at_status = 9
    assert s._executed_guess((10.0, 2.5, -0.1)) == 8  # the last acknowledged one


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
    assert s._executed_guess((20.0, 0.0, -0.1)) <= CUT - 1
    # a job resumed at the cut: the plunge is not a candidate, only the cut's start tells
    s._acked_blocks = list(range(CUT, len(s._program.blocks)))
    s._acks_at_status = len(s._acked_blocks)
    assert s._executed_guess((20.0, 0.0, -0.1)) == CUT - 1


def test_without_steps_only_a_position_within_the_reports_rounding_is_an_end(tmp_path):
    # steps unknown: 0.002 mm (a report's rounding) counts as the end, 0.005 mm short not
    s = _streamer(tmp_path, None)
    s._acked_blocks = list(range(CUT + 1))
    s._acks_at_status = CUT + 1
    assert s._executed_guess((9.9945, 5.0055, -0.1)) == CUT
    assert s._executed_guess((9.99, 5.004, -0.1)) == CUT - 1


def test_a_stop_on_the_next_move_is_not_taken_for_one_short_of_the_end(tmp_path):
    # the cut ended at Grbl's (10, 5), too far from the sender's end to tell it ran; Grbl
    # then went 8 Z steps up the G0Z1: the cut ran, the G0Z1 did not end
    s = _streamer(tmp_path, STEPS_PER_MM)
    assert s._executed_guess((10.0, 5.0, -0.1 + 8 / 400.0)) == CUT
    # 1 Z step up lies within Z's rounding: maybe the cut stopped short, it is cut again
    assert s._executed_guess((10.0, 5.0, -0.1 + 1 / 400.0)) == CUT - 1


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
    assert s._executed_guess((10.0, 0.0, -0.1)) == through
    assert s._executed_guess((10.0, 0.0, -0.1 + 4 / 400.0)) == through  # 4 Z steps up
    s._acked_blocks = list(range(CUT + 1))  # the cut acknowledged last
    s._acks_at_status = CUT + 1
    assert s._executed_guess((10.0, 0.0, -0.1)) == through


def test_a_position_off_every_acknowledged_move_trusts_only_the_planner_bound(tmp_path):
    # at the cut's end in X and Y but 0.6 mm above it: on no acknowledged move (an old
    # or garbled report), so nothing after the blocks the planner bound says ran counts
    s = _streamer(tmp_path, STEPS_PER_MM)
    s._acked_blocks = list(range(CUT + 1))
    s._acks_at_status = CUT + 1
    assert s._executed_guess((9.994, 5.006, 0.5)) == -1


def test_a_move_on_an_axis_of_unknown_position_never_counts_as_ended(tmp_path):
    # streamed from a start the sender was not told: X counts from an assumed start, so
    # the machine may stand anywhere along G91 X5 (Z known, resumed there): it is the
    # interrupted move, whichever of the later ones passes where it stands
    text = "G21G90\nG0Z2\nG0Z1\nG91G0X5\nG90\nG0X-5Y0\nG0X10\n"
    s = _streamer(tmp_path, STEPS_PER_MM, text)
    s._program = load_program(tmp_path / "job.gcode")  # not placed
    s._acked_blocks = list(range(3, len(s._program.blocks)))
    s._acks_at_status = len(s._acked_blocks)
    assert s._executed_guess((2.0, 0.0, 1.0)) == 2
    assert s._executed_guess((5.0, 0.0, 1.0)) == 2  # X5 read from an unknown start


def test_an_increment_from_an_unknown_z_never_counts_as_ended(tmp_path):
    # G91 Z1 from a Z the sender does not know (the machine stands at work Z 7): the
    # move's Z is unknown at both ends, yet it moves: a stop at its start is on it
    text = "G21G91\nG0Z1\nG90G0X1Y1\nG1X5F100\n"
    s = _streamer(tmp_path, STEPS_PER_MM, text)
    assert s._executed_guess((0.0, 0.0, 7.0)) == 0
    assert s._executed_guess((0.0, 0.0, 8.0)) == 0  # or at its end: unknown, it may not be


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
        assert s._executed_guess((x, y, -0.1)) <= CUT - 1, (x, y)


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
    assert s._executed_guess((x, 0.0, -0.1)) == CUT - 1
    s.info.settings[13] = 0.0  # in mm reports that X cannot be a step short: the cut ran
    assert s._executed_guess((x, 0.0, -0.1)) == CUT
