"""The sender's time left counts the moves GRBL has queued but not run (``TimeLeft``).

GRBL acknowledges a motion line when it enters its 15-block planner, so the lines not yet
acknowledged are not all the machine has left to do. The references here are the blocks'
own seconds summed in the test, the share of a move's length at a point placed on it, and,
against the emulator, its own clock: when its last move ended.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from stream_helpers import FAST
from test_stream import write_job

from scratchfab.machine.sender import Streamer, open_port, parse_status
from scratchfab.machine.sender_journal import Journal
from scratchfab.machine.sender_program import Program, TimeLeft, load_program
from scratchfab.machine.stream_job import progress_text


def _program(tmp_path: Path, lines: list[str]) -> Program:
    """The program as streamed from work X0 Y0."""
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(lines) + "\n")
    return load_program(path).placed_at((0.0, 0.0))


def _row(n: int = 30, zero_after: tuple[int, ...] = ()) -> list[str]:
    """``n`` 1 mm moves along X at 600 mm/min (0.1 s each), each move in ``zero_after``
    followed by a repeat of its point (a move GRBL drops)."""
    lines = ["G21 G90 G94", "G0 Z1", "G0 X0 Y0"]
    for k in range(1, n + 1):
        lines.append(f"G1 X{k} F600")
        if k in zero_after:
            lines.append(f"G1 X{k}")
    return lines


def _rest(program: Program, first: int) -> float:
    """The seconds of the blocks from ``first`` on, summed here."""
    return sum(b.seconds for b in program.blocks[first:])


@pytest.mark.parametrize(("move", "share"), [(3, 0.0), (10, 0.25), (16, 0.5), (17, 0.9)])
def test_a_position_on_a_queued_move_leaves_the_rest_of_it_and_everything_after(
    tmp_path, move, share
):
    """All 30 moves acknowledged (the old ETA: 0); the machine at ``share`` of move
    ``move`` (X from move-1 to move)."""
    program = _program(tmp_path, _row())
    block = 2 + move  # the header's three blocks, the first move is X1
    assert program.blocks[block].text == f"G1X{move}F600"
    left = TimeLeft(program)
    last = len(program.blocks) - 1
    # the planner bound alone would put the machine at the 15th-last move
    got = left.update(last, last, (move - 1 + share, 0.0, 1.0))
    want = (1 - share) * program.blocks[block].seconds + _rest(program, block + 1)
    if block < last - 14:
        want = _rest(program, last - 14)
    assert got == pytest.approx(want)
    assert left.ran == max(block, last - 14)
    assert 0 < got


def test_without_a_position_the_15_last_moves_acknowledged_are_still_to_run(tmp_path):
    """No position yet: GRBL's planner holds at most 15 of the moves acknowledged; a
    repeated point (GRBL plans nothing for it) takes no place in it."""
    plain = _program(tmp_path, _row())
    left = TimeLeft(plain, planner_blocks=15)
    assert left.update(-1, -1, None) == pytest.approx(_rest(plain, 0))
    assert left.update(10, -1, None) == pytest.approx(_rest(plain, 0))  # 8 moves: all may wait
    last = len(plain.blocks) - 1
    assert left.update(last, -1, None) == pytest.approx(_rest(plain, last - 14))
    zeros = _program(tmp_path, _row(zero_after=(25, 27, 29)))
    left = TimeLeft(zeros, planner_blocks=15)
    last = len(zeros.blocks) - 1
    assert zeros.blocks[last - 1].text == "G1X29"  # the repeat, after X29F600
    # 15 moves with a length: back to X16 (three repeats among the blocks after it)
    first = next(b.index for b in zeros.blocks if b.text == "G1X16F600")
    assert left.update(last, -1, None) == pytest.approx(_rest(zeros, first))
    assert left.ran == first


def test_the_planner_blocks_free_tell_how_many_moves_still_wait(tmp_path):
    """Arcs (their path is not matched): the report's ``Bf:`` says 3 of 15 planner blocks
    are taken, so all but the 3 last moves acknowledged before it ran; 15 free: all ran.
    Moves acknowledged after the report do not count as run."""
    lines = ["G21 G90 G94", "G0 Z1 X0 Y0", "G1 X5 F600"]
    lines += [
        f"G{2 + k % 2} X{5 if k % 2 else -5} Y0 I{-5 if k % 2 == 0 else 5} J0" for k in range(20)
    ]
    program = _program(tmp_path, lines)
    last = len(program.blocks) - 1
    left = TimeLeft(program, planner_blocks=15)
    assert left.update(last, last, (0.0, 5.0, 1.0)) == pytest.approx(_rest(program, last - 14))
    assert left.update(last, last - 1, (0.0, 5.0, 1.0), planner_free=12) == pytest.approx(
        _rest(program, last - 3)
    )
    assert left.ran == last - 3
    assert left.update(last, last - 1, (0.0, 5.0, 1.0), planner_free=15) == pytest.approx(
        _rest(program, last)
    )


def test_a_block_answered_after_the_planner_emptied_means_everything_before_it_ran(tmp_path):
    """M3, G4 and M5 are answered once the moves before them ran (and G4 once it dwelt)."""
    lines = _row(4) + ["M3 S1000", "G4 P0.5", "G1 X5", "G1 X6", "M5", "G1 X7"]
    program = _program(tmp_path, lines)
    index = {b.text: b.index for b in program.blocks}
    left = TimeLeft(program)
    assert left.update(index["G1X4F600"], -1, None) == pytest.approx(_rest(program, 0))
    assert left.update(index["M3S1000"], -1, None) == pytest.approx(
        _rest(program, index["M3S1000"] + 1)
    )
    assert _rest(program, index["M3S1000"] + 1) < _rest(program, 0) - 0.35  # 4 moves ran
    assert left.update(index["G4P0.5"], -1, None) == pytest.approx(
        _rest(program, index["G4P0.5"] + 1)
    )
    assert program.blocks[index["G4P0.5"]].seconds == pytest.approx(0.5)
    assert left.update(index["M5"], -1, None) == pytest.approx(_rest(program, index["M5"] + 1))
    assert left.ran == index["M5"] + 1


def test_the_time_left_never_grows(tmp_path):
    """An older report (a position behind the run point), a report off the path, or one
    without a position: the time left stays."""
    program = _program(tmp_path, _row())
    left = TimeLeft(program)
    last = len(program.blocks) - 1
    at = left.update(last, last, (20.5, 0.0, 1.0))
    assert left.update(last, last, (18.5, 0.0, 1.0)) == at
    assert left.update(last, last, (20.5, 3.0, 1.0)) == at
    assert left.update(last, last, None) == at
    assert left.update(last, last, (21.5, 0.0, 1.0)) == pytest.approx(at - 0.1)


def test_a_point_the_path_passes_twice_is_read_from_the_run_point_on(tmp_path):
    """X0 -> X10 -> X0: X3 lies on both moves; the time left is read from the first (never
    less than the machine has left), and at X0 after the second, all of it ran."""
    program = _program(tmp_path, ["G21 G90 G94", "G0 Z1", "G1 X10 F600", "G1 X0", "G0 Z5"])
    left = TimeLeft(program)
    got = left.update(3, 3, (3.0, 0.0, 1.0))
    assert got == pytest.approx(0.7 * program.blocks[2].seconds + _rest(program, 3))
    assert left.update(3, 3, (7.0, 0.0, 1.0)) == pytest.approx(
        0.3 * program.blocks[2].seconds + _rest(program, 3)
    )
    # the second pass: X7 is on the first move too, but the machine passed it
    assert left.update(3, 3, (3.0, 0.0, 1.0)) == pytest.approx(
        0.3 * program.blocks[3].seconds + _rest(program, 4)
    )
    # at the end of the last move acknowledged before the report: all of them ran
    assert left.update(3, 3, (0.0, 0.0, 1.0)) == pytest.approx(_rest(program, 4))
    assert left.ran == 4


def test_a_position_at_a_queued_moves_start_is_not_the_end_of_the_job(tmp_path):
    """The machine stands at X0 Y0 with a move from there queued (GRBL reports Idle before
    a block's cycle starts), the job's last point being X0 Y0 too: nothing ran yet."""
    program = _program(tmp_path, ["G21 G90 G94", "G0 Z1", "G1 X10 F600", "G1 Y10", "G1 X0 Y0"])
    left = TimeLeft(program)
    assert left.update(4, 4, (0.0, 0.0, 1.0)) == pytest.approx(_rest(program, 2))


def test_an_arc_between_keeps_the_end_point_rule_off(tmp_path):
    """X0 -> X5, a half circle to X-5, back to X5, all queued: the machine at X5 may not
    have started the arc (its path is not checked), so it is not taken for done."""
    lines = ["G21 G90 G94", "G0 Z1", "G1 X5 F600", "G2 X-5 Y0 I-5 J0", "G1 X5"]
    program = _program(tmp_path, lines)
    left = TimeLeft(program)
    got = left.update(4, 4, (5.0, 0.0, 1.0))
    assert got >= program.blocks[3].seconds + program.blocks[4].seconds > 1.5
    assert left.ran <= 3


def test_a_resumed_job_starts_with_the_blocks_before_as_run(tmp_path):
    program = _program(tmp_path, _row())
    left = TimeLeft(program, start=12)
    assert left.update(11, -1, (0.0, 0.0, 1.0)) == pytest.approx(_rest(program, 12))
    assert left.ran == 12
    assert left.update(11, -1, None, all_ran=True) == pytest.approx(_rest(program, 12))
    last = len(program.blocks) - 1
    assert left.update(last, last, None, all_ran=True) == 0.0
    assert left.ran == len(program.blocks)


def test_a_report_costs_the_blocks_acknowledged_since_the_last_one(tmp_path):
    """80k moves, a report per move with the machine 15 moves behind: a scan over every
    block acknowledged at each report would take about 3e9 block visits (hours); the run
    point's cursor makes it linear (well under a second here)."""
    n = 80_000
    path = tmp_path / "big.gcode"
    path.write_text(
        "G21 G90 G94\nG0 Z1 X0 Y0\n" + "".join(f"G1 X{k} F6000\n" for k in range(1, n + 1))
    )
    program = load_program(path)
    left = TimeLeft(program)
    start = time.perf_counter()
    seconds = []
    for k in range(n):
        acked = min(k + 2 + 14, len(program.blocks) - 1)
        seconds.append(left.update(acked, acked, (k + 0.5, 0.0, 1.0)))
    spent = time.perf_counter() - start
    assert seconds[-1] == pytest.approx(0.5 * program.blocks[-1].seconds)
    assert all(a >= b for a, b in zip(seconds, seconds[1:], strict=False))
    assert spent < 20.0, spent


def test_the_eta_streamed_to_the_emulator_follows_its_clock(tmp_path):
    """Each report's ETA (machine seconds, times the emulator's time_scale) against the
    time the emulator really had left then (its last move's end, by the same clock).

    Tolerance (wall seconds): the share of a move's length run is taken as the share of
    its time, off by at most the move's ramps (here at most 0.25 s of machine time: a
    50 mm/s rapid at 200 mm/s^2); a report comes after its status report, up to 0.25 s
    later on a busy machine (the tests share two cores), which can only raise the ETA.
    The old ETA (the lines not acknowledged) said 0 for the last seconds while up to 15
    moves ran: the check tells it.
    """
    scale = 0.25
    job = tmp_path / "job.gcode"
    write_job(job, 6)
    url = (
        f"grblsim://?baud=115200&time_scale={scale}"
        "&$110=3000&$111=3000&$112=600&$120=200&$121=200&$122=100"
    )
    reports = []
    port = open_port(url, 115200)
    try:
        streamer = Streamer(port, FAST, on_progress=lambda p: reports.append((time.monotonic(), p)))
        info = streamer.connect()
        program = load_program(job).timed_for(info.settings)
        journal = Journal(tmp_path / "j.jsonl").open()
        streamer.stream(program, journal)
        journal.close()
        end = max(r["t"] for r in port.sim.record if r["ev"] == "exec")
    finally:
        port.close()
    assert end - reports[0][0] > 2.0  # the job ran for seconds: enough reports to judge
    tol_model, tol_late = 0.25 * scale, 0.25
    old_error = 0.0
    for t, p in reports[:-1]:
        truth = max(0.0, end - t)
        eta = p.eta_s * scale
        assert -tol_model <= eta - truth <= tol_model + tol_late, (t - reports[0][0], eta, truth)
        assert p.ran is not None and p.ran <= p.acked
        if truth > tol_model + tol_late:
            assert eta > 0.0 and "100.0%" not in progress_text(p, 0.0)
        old_error = max(old_error, truth - _rest(program, p.acked) * scale)
    assert old_error > 1.0  # the former ETA missed by more than a second
    etas = [p.eta_s for _, p in reports]
    assert all(a >= b - 1e-9 for a, b in zip(etas, etas[1:], strict=False))
    last = reports[-1][1]
    assert last.final and last.eta_s == 0.0 and last.ran == last.total == len(program.blocks)


@pytest.mark.parametrize(
    ("line", "free"),
    [
        ("<Run|MPos:1.000,2.000,3.000|Bf:7,120|FS:500,0>", 7),
        ("<Idle|WPos:0.000,0.000,0.000|FS:0,0>", None),  # $10 without value 2: not told
        ("<Run|WPos:0.000,0.000,0.000|Bf:x,1|FS:0,0>", None),  # garbled: not taken
    ],
)
def test_a_status_report_gives_the_planner_blocks_free(line, free):
    assert parse_status(line, None).planner_free == free


@pytest.mark.parametrize(
    ("seconds", "nearest", "left"),
    [
        (0.0, "00:00", "00:00"),
        (0.4, "00:00", "00:01"),
        (1.0, "00:01", "00:01"),
        (59.2, "00:59", "01:00"),
        (3599.5, "1:00:00", "1:00:00"),
        (3600.0001, "1:00:00", "1:00:01"),
        (7322.0 + 3e-9, "2:02:02", "2:02:02"),
    ],  # fmt: skip
)
def test_a_time_left_reads_00_00_only_when_nothing_is_left(seconds, nearest, left):
    """A time taken reads to the nearest second, a time left rounded up (float noise of a
    few nanoseconds over a whole second apart)."""
    from scratchfab.console import clock

    assert clock(seconds) == nearest
    assert clock(seconds, up=True) == left
