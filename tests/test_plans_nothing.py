"""The journal's count of queued moves stays safe with moves of no length (``plans_nothing``).

``last_surely_run`` does not count a straight move the sender calls "of no length" among
the moves that may still be queued in GRBL's planner. Counting a move that GRBL drops
would trust one block too many; not counting one that GRBL plans only looks further back
(safe). The reference is the emulator's own G-code interpreter (Grbl's
``gc_execute_line``: machine coordinates, the stored G28 position, G54-G59 offsets, G92
and the tool length offset): a line takes a planner block when one of its motions changes
a whole step on an axis (Grbl's ``plan_buffer_line`` drops a move of no step,
``PLAN_EMPTY_BLOCK``).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from scratchfab.errors import ConfigError
from scratchfab.machine.grblsim_gcode import ModalState, Settings, interpret
from scratchfab.machine.sender_journal import check_event, done_blocks, last_surely_run
from scratchfab.machine.sender_program import load_program, plans_nothing, strip_block

STEPS_MM = 250.0  # Grbl's default $100-$102
STEP = (1.0 / STEPS_MM,) * 3
SEGMENT_BLOCKS = 6 - 1  # Grbl 1.1h's SEGMENT_BUFFER_SIZE, one slot kept free
START = (3.0, 4.0, -2.0)  # where the machine is when the stream starts (machine mm)
G55 = (10.0, 20.0, -5.0)
G28_AT = (-1.0, -1.0, -1.0)


def _grbl_blocks(lines: list[str]) -> tuple[list[bool], list[bool]]:
    """Per block sent, whether Grbl plans a move of at least one step for it, and whether
    it empties the planner before answering (a sync, dwell, spindle or coolant change)."""
    offsets = [(0.0, 0.0, 0.0), G55, *[(0.0, 0.0, 0.0)] * 4]
    state = ModalState(position=START)
    moved, syncs = [], []
    for raw in lines:
        line = strip_block(raw)
        if not line:
            continue
        out = interpret(line, state, Settings(coord_offsets=offsets, g28=G28_AT))
        at = state.position
        steps = False
        for act in out.actions:
            if act.kind == "motion":
                steps = steps or any(
                    _lround(a * STEPS_MM) != _lround(b * STEPS_MM)
                    for a, b in zip(at, act.target, strict=True)
                )
                at = act.target
        moved.append(steps)
        syncs.append(any(a.kind != "motion" and not a.free for a in out.actions))
        state, offsets = out.state, out.coord_offsets
    return moved, syncs


#: Programs whose blocks return to the position the sender last knew, after something
#: the sender cannot follow (or before it knows where the machine is).
UNKNOWN_START = {
    "first move to the origin": ["G21 G90", "G0 Z5", "G0 X0 Y0", "G1 Z-0.1 F100"],
    "after G53": ["G21 G90", "G0 X1 Y1 Z5", "G53 G0 Z-1", "G0 Z5", "G0 X2"],
    "after G92": ["G21 G90", "G0 X10 Y10 Z5", "G92 X0 Y0", "G0 X10 Y10", "G0 X11"],
    "after G28": ["G21 G90", "G0 X1 Y1 Z5", "G28", "G0 X1 Y1 Z5"],
    "after G28 through a point": ["G21 G90", "G0 X1 Y1 Z5", "G28 Z6", "G0 X1 Y1 Z5"],
    "after a change to G55": ["G21 G90", "G0 X1 Y1 Z5", "G55", "G0 X1 Y1 Z5"],
    "after G10 L20": ["G21 G90", "G0 X1 Y1 Z5", "G10 L20 P1 X0", "G0 X1"],
    "after G43.1": ["G21 G90", "G0 X1 Y1 Z5", "G43.1 Z2", "G0 Z5"],
    "after M30 back to G54": ["G21 G90 G55", "G0 X1 Y1 Z5", "M30", "G0 X1 Y1 Z5"],
    "after G10 L2 to the same offset": ["G21 G90", "G0 X1 Y1 Z5", "G10 L2 P1 X0", "G0 X1"],
    "after G92.1 of no offset": ["G21 G90", "G0 X1 Y1 Z5", "G92 X1 Y1", "G92.1", "G0 X1 Y1"],
    "G91 after G55": ["G21 G90", "G0 X1 Y1 Z5", "G55", "G91 G0 X0.001", "G0 X-0.001"],
}

#: Programs with moves of under a step ($100-$102 = 250: 0.004 mm), which GRBL drops (a
#: move back to X2 after a dropped X2.001 too: GRBL still stands on X2's step).
SUB_STEP = {
    "moves of under a step": [
        "G21 G90", "G0 X1 Y1 Z2", "G1 X2 F100", "G1 X2.001", "G1 X2", "G1 X2.001", "G1 X3",
        "G1 Y1.003", "G1 Y1.006", "G1 Z2.001", "G1 X3.002 Y1.004", "G1 X4",
    ],
}  # fmt: skip

#: Programs whose repeated points are known to the sender: GRBL drops them.
KNOWN = {
    "the exporter's repeated lift": [
        "G21 G90", "G0 Z2", "G0 X1 Y1", "G1 Z-0.1 F100", "G1 X2", "G0 Z2", "G0 Z2", "G0 X3",
    ],
    "G91 of nothing": ["G21 G90", "G0 X1 Y1 Z2", "G91", "G0 X0", "G1 Z0 F100", "G90"],
    "G20 to the same point": ["G21 G90", "G0 X25.4 Y0 Z2", "G20 G0 X1", "G21"],
    "absolute again after G53": ["G21 G90", "G0 X1 Y1 Z5", "G53 G0 Z-1", "G0 X1 Y1 Z5", "G0 Z5"],
}  # fmt: skip


def _blocks(tmp_path: Path, lines: list[str]):
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(lines) + "\n")
    return load_program(path).blocks


def _lround(x: float) -> int:
    """C's lround: halves away from zero (Grbl's steps from mm)."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


@pytest.mark.parametrize("name", sorted(KNOWN))
def test_a_repeated_point_the_sender_knows_is_of_no_length(tmp_path, name):
    """Where the sender knows the position, each move GRBL drops is called of no length."""
    lines = KNOWN[name]
    blocks = _blocks(tmp_path, lines)
    moved, _ = _grbl_blocks(lines)
    assert len(blocks) == len(moved)
    dropped = [i for i, b in enumerate(blocks) if b.motion and not moved[i]]
    assert dropped  # each program holds one
    assert [i for i in dropped if not plans_nothing(blocks, i)] == []


def _surely_run_reference(
    moved: list[bool], syncs: list[bool], acked: list[int], planner: int
) -> int:
    """Block by block: an acked block surely ran when at least ``planner + 5`` blocks that
    GRBL planned were acked after it (the planner full, five more in the stepper's segment
    buffer), or a
    block that empties the planner first was acked after it (or is the block itself, and
    it plans no move after that)."""
    sure = [
        sum(moved[j] for j in acked[p + 1 :]) >= planner + SEGMENT_BLOCKS
        or any(syncs[j] for j in acked[p + 1 :])
        or (syncs[acked[p]] and not moved[acked[p]])
        for p in range(len(acked))
    ]
    unsure = [p for p in range(len(acked)) if not sure[p]]
    if not acked:
        return -1
    return acked[unsure[0]] - 1 if unsure else acked[-1]


@pytest.mark.parametrize(
    ("name", "step"),
    [(n, (0.0, 0.0, 0.0)) for n in sorted(UNKNOWN_START) + sorted(KNOWN)]
    + [(n, STEP) for n in sorted(UNKNOWN_START) + sorted(KNOWN) + sorted(SUB_STEP)],
)
def test_the_journal_never_trusts_a_move_grbl_may_still_hold(tmp_path, name, step):
    """Safety: a return to a point after something the sender cannot follow (or before it
    knows where the machine is) is a real move GRBL plans, called of no length; the count
    then only reaches further back. A move of under a step GRBL drops is not counted
    where the step is known. Every acked prefix, planners of 0 to 3 blocks."""
    lines = {**UNKNOWN_START, **KNOWN, **SUB_STEP}[name]
    blocks = _blocks(tmp_path, lines)
    moved, syncs = _grbl_blocks(lines)
    assert len(blocks) == len(moved)
    for planner in range(4):
        for n in range(len(blocks) + 1):
            acked = list(range(n))
            reference = _surely_run_reference(moved, syncs, acked, planner)
            assert last_surely_run(blocks, acked, planner, None, step) <= reference, (planner, n)


def test_an_unclosed_session_reads_the_steps_its_start_recorded(tmp_path):
    """A session with no closing event (the sender crashed) keeps the acked blocks that
    surely ran, judged with the step recorded at its start: with it, no move GRBL may drop
    is counted and none is trusted past the reference; without it, a move of under a step
    counts and the journal trusts a block GRBL may still hold."""
    lines = SUB_STEP["moves of under a step"]
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(lines) + "\n")
    program = load_program(path)
    moved, syncs = _grbl_blocks(lines)
    acked = list(range(len(program.blocks)))
    reference = _surely_run_reference(moved, syncs, acked, 1)
    for steps in (list(STEP), None):
        start = {"ev": "start", "sha256": program.sha256, "blocks": len(program.blocks)}
        events = [{**start, "resume": False, "planner": 1, "steps": steps}]
        events += [{"ev": "ack", "i": i} for i in acked]
        for ev in events:
            check_event(ev, len(program.blocks), "journal.jsonl:1")
        done = done_blocks(events, program.sha256, "journal.jsonl", program=program)
        through = max(done, default=-1)
        assert done == set(range(through + 1))
        assert (through <= reference) == (steps is not None)


@pytest.mark.parametrize("steps", [[-0.004, 0.004, 0.004], [0.004, 0.004], ["x", 1, 1]])
def test_a_journal_start_with_bad_steps_is_named(steps):
    start = {"ev": "start", "sha256": "ab", "blocks": 3, "resume": False, "steps": steps}
    with pytest.raises(ConfigError, match=r"journal.jsonl:1.*'steps'"):
        check_event(start, None, "journal.jsonl:1")


def test_the_journal_leaves_unsure_what_grbls_planner_and_step_segments_may_hold(tmp_path):
    """Grbl 1.1h holds 15 planner blocks (BLOCK_BUFFER_SIZE 16, one kept free), and its
    stepper (stepper.c, st_prep_buffer) discards a block from the planner once all of its
    steps are in the segment buffer (SEGMENT_BUFFER_SIZE 6, one kept free: 5 segments).
    A move shorter than one segment (10 ms: 0.05 mm at F1000 takes 3 ms) is one segment,
    so 5 such moves can still run after the planner let them go: 20 acked moves unrun,
    and the journal trusts none of them (nor the one before, its margin)."""
    lines = ["G21 G90", "G0 Z1", "G1 X0 Y0 F1000"]
    lines += [f"G1 X{0.05 * k:.2f}" for k in range(1, 60)]
    blocks = _blocks(tmp_path, lines)
    acked = list(range(len(blocks)))
    unrun = 15 + SEGMENT_BLOCKS
    assert last_surely_run(blocks, acked, 15) <= acked[-unrun - 1] - 1
    session = [{"ev": "start", "sha256": "x", "blocks": len(blocks), "resume": False}]
    session += [{"ev": "ack", "i": i} for i in acked]
    assert max(done_blocks(session, "x", "journal.jsonl")) <= acked[-unrun - 1] - 1


def test_a_move_a_little_over_a_step_may_be_dropped_in_grbls_float32_rounding(tmp_path):
    """Grbl rounds ``target * steps_per_mm`` to steps in float32: at X 291 mm and 800
    steps/mm a move of 1.012 steps lands on the step it started on, and Grbl drops it. The
    sender must count it as a move GRBL may drop (counting it as a block would trust one
    too many); a move of 1.2 steps it counts."""
    import numpy as np

    a, b, c = 290.9868739, 290.9881393, 290.9896393
    steps = np.float32(800.0)
    assert np.rint(np.float32(a) * steps) == np.rint(np.float32(b) * steps)  # Grbl drops it
    assert np.rint(np.float32(b) * steps) != np.rint(np.float32(c) * steps)
    assert 1.0 < (b - a) * 800.0 < 1.02 and (c - b) * 800.0 > 1.15
    lines = ["G21 G90", f"G0 X{a} Y0 Z0", f"G1 X{b} F100", f"G1 X{c}"]
    blocks = _blocks(tmp_path, lines)
    step = (1.0 / 800.0,) * 3
    assert plans_nothing(blocks, 2, step) and not plans_nothing(blocks, 3, step)
