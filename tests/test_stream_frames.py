"""The sender's work positions after a change of the work frame in a foreign G-code file.

After G92.1, G10 L2, G54-G59, G53 or G28 the sender does not know where the machine
stands in the work frame until each axis is given again in absolute mode; a stop's
executed-through (which a resume trusts) must not match the hold position against
segments drawn in the old frame. The emulator is the reference: it knows the offsets.
"""

from __future__ import annotations

from dataclasses import replace

import pytest
from stream_helpers import executed_blocks, stopped_after

from scratchfab.errors import ConfigError
from scratchfab.machine.grblsim_gcode import ModalState, Settings, interpret
from scratchfab.machine.sender import ControllerInfo, Status, Streamer
from scratchfab.machine.sender_checks import job_extent
from scratchfab.machine.sender_program import (
    TimeLeft,
    load_program,
    resume_preamble,
    strip_block,
    work_xyz,
)

#: Header and frame change: the machine stands at work (0, 0, 1), and after the change at
#: work (0, 10, 1), which the sender knows only where the change gives Y itself.
FRAMES = {
    "G92": ("", "G92 Y10"),
    "G10 L20 current": ("", "G10 L20 P0 Y10"),
    "G10 L2 current": ("", "G10 L2 P1 Y-10"),
    "G55": ("G10 L2 P2 Y-10", "G55"),
    "G92.1": ("G92 Y-10\nG0 Y0", "G92.1"),
}


def _job(path, header: str, change: str) -> None:
    """Block 4 runs along work Y 10 from X 0 to 20 (slowly); block 6 passes there again.

    Drawn in the old frame (Y 0), block 4 misses the hold position and block 6 (the
    same line in both frames, Y given again) matches it.
    """
    lines = ["G21 G90", "G0 Z1", *header.splitlines(), "G0 X0 Y0", change, "G1 X20 F30",
             "G1 X-10 Y10 F3000", "G1 X30", "G1 X-10", "G1 X30", "G1 X-10", "G0 Z2"]  # fmt: skip
    path.write_text("\n".join(lines) + "\n")


def _stopped_after(tmp_path, prog, acks: int, query: str) -> tuple[dict, set[int]]:
    """Stream ``prog`` to the emulator (``query`` added to its URL), stop it by Ctrl-C once
    more than ``acks`` lines are acknowledged: the journal's stop and the blocks it ran."""
    url = f"grblsim://?baud=0&time_scale=0.05{query}"
    events, record = stopped_after(tmp_path / "j.jsonl", prog, acks, url)
    return events[-1], executed_blocks(record)


@pytest.mark.parametrize("frame", list(FRAMES))
def test_a_stop_after_a_frame_change_does_not_claim_the_interrupted_move(tmp_path, frame):
    """Stopped early in the slow move after the change, the journal's executed-through
    ends before it: every motion block up to it was finished by the emulator, and the
    interrupted move is the next one (not the later move that passes the same point)."""
    job = tmp_path / "job.gcode"
    _job(job, *FRAMES[frame])
    prog = load_program(job)
    slow = next(b.index for b in prog.blocks if b.text == "G1X20F30")
    stop, ran = _stopped_after(tmp_path, prog, slow + 4, "")
    assert slow not in ran  # the stop came in the slow move
    assert all(i in ran for i in range(slow) if prog.blocks[i].motion)
    assert stop["executed_through"] == slow - 1


# ---------------------------------------------------------------- against Grbl's interpreter

G54 = (2.0, 3.0, -1.0)
G55 = (10.0, 20.0, -5.0)
G28_AT = (-1.0, -1.0, -1.0)
#: The machine starts at work X0 Y0 of G54 (the sender's assumption), Z unknown to it.
START = (G54[0], G54[1], G54[2] + 7.0)

#: Foreign programs that change the work frame mid-job, then move (G91 too) and give the
#: axes again one by one.
FOREIGN = {
    "G92": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G92 X0 Y2", "G1 X4 F600", "G91 G1 X-2 Y-2",
            "G90 G1 Y3"],
    "G92.1": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G92 X0 Y0", "G1 X4 F600", "G92.1",
              "G1 X2", "G91 G1 Y2", "G90 G1 Y5", "G1 X3 Y4 Z4", "G1 X1"],
    "G55": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G55", "G1 X3 F600", "G1 Y2", "G91 G1 Z-1",
            "G90 G1 X5 Y5 Z4", "G1 X1"],
    "G10 L2 on the system in use": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G10 L2 P1 X3",
                                    "G1 Y4 F600", "G1 X2", "G1 X6"],
    "G10 L2 P0": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G10 L2 P0 Y-4 Z1", "G1 X4 F600",
                  "G1 Y2", "G1 Z3", "G1 X1"],
    "G10 L20 on the system in use": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G10 L20 P1 X7",
                                     "G1 Y4 F600", "G1 X2"],
    "G10 on another system": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G10 L2 P2 X3", "G10 L20 P3 Y9",
                              "G1 Y4 F600", "G55", "G1 X0", "G1 Y0 Z5", "G1 X2"],
    "G53": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G53 G0 Z-1", "G1 X3 F600", "G1 Z4", "G1 X5"],
    "G28 through a point": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G28 Z6", "G1 X3 F600",
                            "G1 X4 Y4 Z4", "G1 X1"],
    "G30": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G30", "G1 X3 F600", "G1 Y2 Z2", "G1 X1"],
    "G43.1": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G43.1 Z2", "G1 X3 F600", "G1 Z3", "G1 X1"],
    "G20 G92": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G20 G92 X1", "G1 Y1 F20", "G21 G1 X30"],
    "M2 back to G54": ["G21 G90 G55", "G0 X1 Y1 Z5", "M2", "G0 X2 F600", "G0 X3 Y3 Z5"],
    # the offset the file set again (no change), then G49 cancelling it (a change)
    "G43.1 again, G49": ["G21 G90", "G43.1 Z2", "G0 Z5", "G0 X1 Y1", "G43.1 Z2", "G1 X3 F600",
                         "G1 Z3", "G49", "G1 X1", "G91 G1 Z-1", "G90 G1 Z4", "G1 X2"],
    "G20 G43.1": ["G21 G90", "G0 Z5", "G0 X1 Y1", "G20 G43.1 Z0.1", "G21 G1 X3 F600", "G1 Z3",
                  "G1 X1"],
    # Z is not known at the start (the machine stands at work Z 7): an increment from it
    "G91 Z from the start": ["G21 G91", "G0 Z1", "G90 G0 X1 Y1", "G91 G1 Z-2 F600",
                             "G90 G1 X3", "G1 Z2", "G1 X1"],
}  # fmt: skip
#: The programs among them that leave X and Y known throughout.
_XY_KEPT = ("G92", "G10 L20 on the system in use", "G20 G92", "G53", "G43.1", "G43.1 again, G49",
            "G20 G43.1", "G91 Z from the start")  # fmt: skip


_CASES = sorted(FOREIGN)


def _grbl_work(lines: list[str]):
    """Per block, Grbl's work position after it, its motions' paths (work mm, each as
    (start, end)) and whether it empties the planner, by the emulator's interpreter
    (``gc_execute_line``)."""
    offsets = [G54, G55, *[(0.0, 0.0, 0.0)] * 4]
    settings = Settings(coord_offsets=offsets, g28=G28_AT, g30=G28_AT)
    state = ModalState(position=START)
    after, paths, syncs = [], [], []
    for raw in lines:
        at = state.position
        out = interpret(strip_block(raw), state, replace(settings, coord_offsets=offsets))
        state, offsets = out.state, out.coord_offsets
        frame = [offsets[state.coord_index][k] + state.g92[k] for k in range(3)]
        frame[2] += state.tlo

        def work(p, frame=frame):
            return tuple(p[k] - frame[k] for k in range(3))

        segs = []
        for act in out.actions:
            if act.kind == "motion":
                segs.append((work(at), work(act.target)))
                at = act.target
        after.append(work(state.position))
        paths.append(segs)
        syncs.append(any(act.kind == "sync" for act in out.actions))
    return after, paths, syncs


def _program(tmp_path, lines):
    """The program as the sender streams it from Grbl's start (work X0 Y0, :data:`START`)."""
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(lines) + "\n")
    return load_program(path).placed_at((0.0, 0.0))


@pytest.mark.parametrize("name", _CASES)
def test_a_known_work_position_is_grbls(tmp_path, name):
    """Where the sender says it knows an axis' work position, it is Grbl's; after the
    change of frame each axis is known again once the file gives it in absolute mode."""
    lines = FOREIGN[name]
    prog = _program(tmp_path, lines)
    truth, _, syncs = _grbl_work(lines)
    assert len(prog.blocks) == len(truth)
    for b, grbl, sync in zip(prog.blocks, truth, syncs, strict=True):
        for k, v in enumerate(work_xyz(b.modal)):
            assert v is None or abs(v - grbl[k]) < 1e-9, (b.lineno, "XYZ"[k], v, grbl[k])
        assert sync or not b.sync_before, b.lineno  # a wait the sender counts on is Grbl's
    assert None not in work_xyz(prog.blocks[-1].modal)  # the file gave X, Y and Z again
    assert any(None in work_xyz(b.modal)[:2] for b in prog.blocks) == (name not in _XY_KEPT)


def _guesser(prog, acked: int) -> Streamer:
    """A Streamer that has sent and seen acknowledged blocks 0 to ``acked`` before the report."""
    s = Streamer.__new__(Streamer)
    s.info = ControllerInfo()
    s._program = prog
    s._all_ran = False
    s._acked_blocks = list(range(acked + 1))
    s._acks_at_status = acked + 1
    return s


@pytest.mark.parametrize("name", _CASES)
def test_a_stop_on_any_move_is_not_taken_for_a_later_one(tmp_path, name):
    """Safety, block by block: stopped anywhere on a move's real path (Grbl's, in the
    frame of the moment), with every block acknowledged that Grbl acknowledges before that
    move ends (up to the next one that empties the planner first), the executed-through
    the journal records ends before that move, and so does the time left's run point
    (neither looks past a move the sender does not follow)."""
    lines = FOREIGN[name]
    prog = _program(tmp_path, lines)
    _, paths, _ = _grbl_work(lines)
    for k, segs in enumerate(paths):
        acked = next((i - 1 for i in range(k + 1, len(prog.blocks)) if prog.blocks[i].sync),
                     len(prog.blocks) - 1)  # fmt: skip
        s = _guesser(prog, acked)
        for a, b in (seg for seg in segs if seg[0] != seg[1]):  # Grbl drops a null move
            for f in (0.0, 0.1, 0.5, 0.9):
                p = tuple(a[j] + f * (b[j] - a[j]) for j in range(3))
                assert s._executed_guess(Status(wpos=p)) <= k - 1, (prog.blocks[k].lineno, f, p)
                left = TimeLeft(prog)
                left.update(acked, acked, p)
                assert left.ran <= k, (prog.blocks[k].lineno, f, p, left.ran)


def test_a_resume_where_the_work_position_is_unknown_is_refused(tmp_path):
    """After G55 the file gives only Z before its next stroke: the preamble cannot bring
    the tool back over the stroke's start, so the resume is refused, naming both lines;
    once the file gives X and Y again, it resumes there."""
    lines = ["G21 G90", "G0 Z2", "G0 X1 Y1", "G1 Z-0.1 F100", "G1 X5", "G0 Z2",
             "G55", "G0 Z2", "G1 Z-0.1", "G1 X9", "G0 Z2",
             "G0 X3 Y3", "G1 Z-0.1", "G1 X7", "G0 Z2"]  # fmt: skip
    prog = _program(tmp_path, lines)
    assert len(prog.strokes) == 3
    with pytest.raises(
        ConfigError, match=r"job\.gcode:9: cannot resume here: after line 7 \('G55'\)"
    ):
        resume_preamble(prog, prog.strokes[1][0])
    pre = resume_preamble(prog, prog.strokes[2][0])
    assert "G0X3Y3" in pre


def test_an_unknown_axis_is_not_taken_as_0_in_the_job_extent(tmp_path):
    """The envelope checks: X and Y unknown after G92.1 stay out of the extent (the
    sender then refuses the job against a profile: the frame is not followed)."""
    lines = ["G21 G90", "G0 X50 Y50 Z5", "G92 X0 Y0", "G1 X10 Y10 F100", "G92.1", "G0 Z3",
             "G91 G0 X-100", "G90 G0 X60 Y70"]  # fmt: skip
    prog = _program(tmp_path, lines)
    lo, hi = job_extent(prog)
    assert lo == [10.0, 10.0, 3.0]  # not 0, nor X-90 by the G91 move from an unknown X
    assert hi == [60.0, 70.0, 5.0]


def test_a_stop_in_the_first_travel_from_away_from_the_origin(tmp_path):
    """An exporter-style job started with the machine at work X0 Y30 (not the origin),
    stopped in its first travel: the stroke after it must not be taken for done, though a
    later travel runs along the same line (X+Y=30) at the same height."""
    job = tmp_path / "job.gcode"
    lines = ["G21 G90 G17 G94", "G0 Z2", "G0 X30 Y0", "G1 Z-0.05 F200", "G1 X31 F600", "G0 Z2",
             "G0 X-5 Y35", "G0 X35 Y-5", "G1 Z-0.05 F200", "G1 X36 F600", "G0 Z2", "M2"]  # fmt: skip
    job.write_text("\n".join(lines) + "\n")
    prog = load_program(job)
    stop, ran = _stopped_after(tmp_path, prog, 8, "&wco=0,-30,0")
    assert 2 not in ran  # stopped in the first travel
    assert all(i in ran for i in range(stop["executed_through"] + 1) if prog.blocks[i].motion)
