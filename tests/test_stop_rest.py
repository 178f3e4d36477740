"""A stop standing exactly at a move's end, on fine steps, the work offset only from ``$#``.

``$#`` prints the offsets to 0.001 mm, so at 800 steps/mm (0.00125 mm a step) GRBL's
rounding of a target to a step is open over three steps: a stop at the end cannot be told
from one a step short of it. The sender rests once at such an end with the tool up (it
feeds nothing until the controller reports Idle there) and learns the step; a later stop at
the same target is then matched in whole steps. The truth is the emulator's record of the
moves it finished.
"""

from __future__ import annotations

import collections
import dataclasses

import numpy as np
import pytest
from stream_helpers import FAST, executed_blocks, spy_rests, stream_program

from scratchfab.export.gcode import gcode_lines
from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender import Status, Streamer, StreamStopped, _first_given, open_port
from scratchfab.machine.sender_journal import read_journal
from scratchfab.machine.sender_program import load_program
from scratchfab.toolpath.plan import Toolpath

#: 800 steps/mm, an offset with more digits than $# prints, no WCO: field in the reports
URL = (
    "grblsim://?baud=0&time_scale=0.05&wco=-100.12345,-80.54321,-30.98765&wco_field=0"
    "&$100=800&$101=800&$102=800"
)


def _lround(v: float) -> int:
    """C's lround: halves away from zero."""
    return int(v + 0.5) if v >= 0 else -int(-v + 0.5)


def _dwell_job(path, strokes: int, after: str = "G1 Z-0.05 F200") -> list[int]:
    """Strokes each travelling to X1 Y1, plunging to Z-0.05 and cutting to X(1 + 3k) Y6,
    a 10 s dwell after the block ``after`` (the plunge; or the travel ``G0 X1 Y1``, the
    tool up); the blocks dwelt after."""
    lines = ["G21 G90", "G0 Z2"]
    dwelt = []
    for k in range(strokes):
        for block in ("G0 X1 Y1", "G1 Z-0.05 F200"):
            lines.append(block)
            if block == after:
                dwelt.append(len(lines) - 1)
                lines.append("G4 P10")
        lines += [f"G1 X{3.0 * k + 1.0:.3f} Y6 F600", "G0 Z2"]
    path.write_text("\n".join(lines) + "\n")
    return dwelt


def _stop_in_dwell(tmp_path, rests: int, after: str) -> tuple[int, int, int]:
    """Ctrl-C during the second stroke's dwell, the machine standing at the end of its block
    ``after``: the journal's executed-through, the emulator's last finished block, that block."""
    plunges = _dwell_job(tmp_path / "job.gcode", 3, after)
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
    """The first travel to X1 Y1 (tool up) is rested at: the second's end is known."""
    through, truth, travel = _stop_in_dwell(tmp_path, 24, "G0 X1 Y1")
    assert truth == travel  # the emulator stands at the travel's end, dwelling
    assert through == truth  # not run again on --resume


def test_without_rests_the_same_stop_is_cut_again(tmp_path):
    through, truth, travel = _stop_in_dwell(tmp_path, 0, "G0 X1 Y1")
    assert truth == travel
    assert through < truth  # never past it; the move is run again


def test_no_rest_with_the_tool_down_so_a_plunge_end_is_plunged_again(tmp_path):
    """A plunge leaves the tool on the board: no rest there (a drag tool held still marks
    it), so a stop at the second plunge's end is not pinned down; never counted past it."""
    through, truth, plunge = _stop_in_dwell(tmp_path, 24, "G1 Z-0.05 F200")
    assert truth == plunge
    assert through < truth


@pytest.mark.parametrize(("name", "spm"), [("grbl-3018-diamond", 800), ("grbl-plotter-scribe", 80)])
def test_rests_land_only_where_the_tool_is_up(tmp_path, monkeypatch, name, spm):
    """Each profile's export streamed with rests: every block rested after leaves the
    tool up, as the G-code says (Z above the middle of the profile's safe and engrave
    heights; the servo's M5)."""
    profile = load_profile(name)
    rng = np.random.default_rng(4)
    lo = np.array([profile.envelope.x_mm[0], profile.envelope.y_mm[0]]) + 20.0
    a = rng.uniform(lo + 10.0, lo + 70.0, (12, 2))
    strokes = np.stack([a, a + rng.uniform(-5.0, 5.0, (12, 2))], axis=1).round(3)
    outline = lo + np.array([[0.0, 0.0], [80.0, 0.0], [80.0, 80.0], [0.0, 80.0]])
    tp = Toolpath(strokes, np.arange(12), (100.0, 100.0), outline, profile, {})
    (tmp_path / "job.gcode").write_text("\n".join(gcode_lines(tp)) + "\n")
    prog = load_program(tmp_path / "job.gcode")
    rested = spy_rests(monkeypatch)
    url = f"grblsim://?baud=0&time_scale=0.01&wco=12.3456,-7.6543,-3.2109&$100={spm}&$101={spm}&$102={spm}"
    port = open_port(url, 115200)
    try:
        stream_program(port, prog, tmp_path / "j.jsonl", dataclasses.replace(FAST, rests=24))
    finally:
        port.close()
    assert rested  # it rested somewhere
    for j in rested:
        modal = prog.blocks[j].modal
        if profile.tool_control.mode == "servo":
            assert modal.spindle == "M5", prog.blocks[j].text
        else:
            mid = 0.5 * (profile.z.safe_mm + profile.z.engrave_mm)
            assert modal.z is not None and modal.z > mid, prog.blocks[j].text


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


def _grbl_step(work: str, offset: np.float32, spm: float) -> int:
    """Grbl 1.1's step for a work target written ``work`` (mm, G90) under ``offset``, all in
    single precision as on the AVR: read_float (the digits as an integer, times 0.01 per
    two decimals, 0.1 for an odd one), plus the offset, times steps/mm, lround."""
    f = np.float32
    whole, _, frac = work.lstrip("-").partition(".")
    v, e = f(int(whole + frac)), -len(frac)
    while e <= -2:
        v, e = f(v * f(0.01)), e + 2
    if e < 0:
        v = f(v * f(0.1))
    v = -v if work.startswith("-") else v
    return _lround(float(f(f(v + offset) * f(spm))))


def test_target_steps_allow_for_grbl_single_precision_of_target_and_offset():
    """Homed machines work in negative machine space: a work X near 290 under an offset
    near -290 lands near machine 0, but GRBL rounds the 290 it read and the sum to single
    precision (errors of 290's size, not of the sum's). With the offset pinned down by
    many rests, every target's span still holds GRBL's step."""
    rng = np.random.default_rng(11)
    spm = 800.0
    streamer = Streamer(port=None)
    streamer.info.settings = {100: spm, 101: spm, 102: spm}
    for _ in range(20):
        w = np.float32(-rng.uniform(250.0, 300.0))
        report = Status(wco=(float(w), 0.0, 0.0), wco_printed=True)
        learnt: dict[float, int] = {}
        for _ in range(60):  # rests at targets GRBL rounded, as Idle reports show them
            t = f"{rng.uniform(250.0, 300.0):.3f}"
            learnt[float(t)] = _grbl_step(t, w, spm)
        streamer._rests = (learnt, {}, {})
        lo, hi = streamer._offset_window(0, report)
        assert lo <= float(w) <= hi  # the true offset stays in the window
        for _ in range(200):
            t = f"{-float(w) + rng.uniform(-0.5, 0.5):.3f}"  # machine targets near 0
            first, last = streamer._target_steps(0, float(t), report)
            assert first <= _grbl_step(t, w, spm) <= last, (t, float(w))
