"""A stop standing exactly at a move's end, on fine steps, the work offset only from ``$#``.

``$#`` prints the offsets to 0.001 mm, so at 800 steps/mm (0.00125 mm a step) GRBL's
rounding of a target to a step is open over three steps: a stop at the end cannot be told
from one a step short of it. The sender rests once at such an end (it feeds nothing until
the controller reports Idle there) and learns the step; a later stop at the same target is
then matched in whole steps. The truth is the emulator's record of the moves it finished.
"""

from __future__ import annotations

import collections
import dataclasses

import pytest
from stream_helpers import FAST, executed_blocks, stream_program

from scratchfab.machine.sender import Status, Streamer, StreamStopped, _first_given, open_port
from scratchfab.machine.sender_journal import read_journal
from scratchfab.machine.sender_program import load_program

#: 800 steps/mm, an offset with more digits than $# prints, no WCO: field in the reports
URL = (
    "grblsim://?baud=0&time_scale=0.05&wco=-100.12345,-80.54321,-30.98765&wco_field=0"
    "&$100=800&$101=800&$102=800"
)


def _lround(v: float) -> int:
    """C's lround: halves away from zero."""
    return int(v + 0.5) if v >= 0 else -int(-v + 0.5)


def _dwell_job(path, strokes: int) -> list[int]:
    """Strokes each plunging to Z-0.05 then dwelling 10 s; the plunges' block indices."""
    lines = ["G21 G90", "G0 Z2"]
    plunges = []
    for k in range(strokes):
        lines += [f"G0 X{3.0 * k + 1.0:.3f} Y1", "G1 Z-0.05 F200"]
        plunges.append(len(lines) - 1)
        lines += ["G4 P10", f"G1 X{3.0 * k + 1.0:.3f} Y6 F600", "G0 Z2"]
    path.write_text("\n".join(lines) + "\n")
    return plunges


def _stop_in_dwell(tmp_path, rests: int) -> tuple[int, int, int]:
    """Ctrl-C during the second stroke's dwell, the machine standing at its plunge's end:
    the journal's executed-through, the emulator's last finished block, the plunge."""
    plunges = _dwell_job(tmp_path / "job.gcode", 3)
    prog = load_program(tmp_path / "job.gcode")
    plunge = plunges[1]
    fired: list[int] = []

    port = open_port(URL, 115200)

    def progress(p):
        # the emulator finished the plunge: the machine dwells at its end
        if plunge in executed_blocks(port.sim.record) and not fired:
            fired.append(1)
            raise KeyboardInterrupt

    options = dataclasses.replace(FAST, rests=rests)
    try:
        with pytest.raises(StreamStopped):
            stream_program(
                port,
                prog,
                tmp_path / "j.jsonl",
                options,
                on_progress=progress,
                ask_interrupt=lambda: "stop",
            )
    finally:
        port.close()
    assert fired
    ran = executed_blocks(port.sim.record)
    return read_journal(tmp_path / "j.jsonl")[-1]["executed_through"], max(ran), plunge


def test_stop_at_a_rested_end_counts_the_move_run(tmp_path):
    through, truth, plunge = _stop_in_dwell(tmp_path, rests=24)
    assert truth == plunge  # the emulator stands at the plunge's end, dwelling
    assert through == truth  # not cut again on --resume


def test_without_rests_the_same_stop_is_cut_again(tmp_path):
    through, truth, plunge = _stop_in_dwell(tmp_path, rests=0)
    assert truth == plunge
    assert through < truth  # never past it; the move is cut again


SPM, WCO = 800.0, (-100.12345, -80.54321, -30.98765)


def _resting(prog, j: int) -> Streamer:
    """A Streamer of ``prog`` (a stream from the top) resting at block ``j``, answered."""
    streamer = Streamer(port=None)
    streamer.info.settings = {100: SPM, 101: SPM, 102: SPM}
    streamer._program = prog
    streamer._inflight = collections.deque()
    streamer._resting = j
    streamer._acked_blocks = list(range(j + 1))
    streamer._acks_at_status = j + 1
    streamer._rests = ({}, {}, {})
    streamer._given_from = _first_given(prog.blocks, 0)
    return streamer


def _idle(steps) -> Status:
    """An Idle report at machine ``steps`` (MPos to 0.001 mm, the offset from $#)."""
    mpos = tuple(round(n / SPM, 3) for n in steps)
    printed = tuple(round(w, 3) for w in WCO)
    wpos = tuple(m - w for m, w in zip(mpos, printed, strict=True))
    return Status(state="Idle", mpos=mpos, wpos=wpos, wco=printed, mpos_given=True)


def test_the_first_report_after_the_rested_moves_answer_is_not_trusted(tmp_path):
    """Grbl 1.1 reports status in the main loop's pass that answered the line before that
    pass starts the cycle (protocol_auto_cycle_start, then protocol_execute_realtime, whose
    report comes before the cycle start): the first report after the answer may say Idle
    with the move still queued. Only a later one's Idle is learnt, as GRBL's steps there:
    lround((target + offset) * steps/mm)."""
    plunges = _dwell_job(tmp_path / "job.gcode", 2)
    prog = load_program(tmp_path / "job.gcode")
    j = plunges[0]
    streamer = _resting(prog, j)
    target = (1.0, 1.0, -0.05)
    steps = [_lround((t + w) * SPM) for t, w in zip(target, WCO, strict=True)]
    idle = _idle(steps)
    assert not streamer._rest_at(idle)  # maybe from the pass that answered it
    assert streamer._rests == ({}, {}, {}) and streamer._rested_through == -1
    assert streamer._rest_at(idle)
    assert streamer._rests == tuple({t: n} for t, n in zip(target, steps, strict=True))
    assert streamer._rested_through == j


def test_a_rest_before_the_first_xy_learns_z_only(tmp_path):
    """The job placed where the machine was found (work X3.5 Y2.25): before its first X
    and Y the machine stands on the steps it was found on, not GRBL's rounding of the
    placed start, so only Z (given by the rested G0 Z2) is learnt there."""
    _dwell_job(tmp_path / "job.gcode", 1)
    prog = load_program(tmp_path / "job.gcode").placed_at((3.5, 2.25))
    streamer = _resting(prog, 1)  # G0 Z2
    found = (-77299, -62602)  # any steps near work (3.5, 2.25)
    steps = [*found, _lround((2.0 + WCO[2]) * SPM)]
    assert not streamer._rest_at(_idle(steps))
    assert streamer._rest_at(_idle(steps))
    assert streamer._rests == ({}, {}, {2.0: steps[2]})
