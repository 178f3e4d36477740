"""What the sender does with a position it does not know: Z counted from an unknown start,
a Z frame changed mid-file, and a job's start before it is placed where the machine stands.

Each unknown is left unknown, and every check or preamble that would need it refuses or
leaves it out rather than guessing (a Z taken as 0 could pass a height check that the
machine then fails).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_stream import _arc_samples, _bench_profile

from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.machine.sender_checks import axis_feeds, compare, job_extent
from scratchfab.machine.sender_program import (
    check_tool_up_at_end,
    load_program,
    resume_preamble,
    travel_height,
)
from scratchfab.machine.stream_job import _check_strokes


def _load(tmp_path, lines, **kw):
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(lines) + "\n")
    return load_program(path, **kw)


#: A job that moves Z only by increments (G91) from wherever Z stood: its strokes cut at a
#: height the sender never learns. The spindle runs, so it would pass for a servo job.
RELATIVE_Z = ["G21 G90 M3 S1000", "G91 G0 Z2", "G90 G0 X10 Y10", "G91 G1 Z-2.1 F100",
              "G90 G1 X20", "G91 G0 Z2.1", "G90 G0 X30", "G91 G1 Z-2.1", "G90 G1 X40",
              "G91 G0 Z2.1", "M5"]  # fmt: skip


@pytest.mark.parametrize("threshold", [None, 0.5, -0.05])
def test_an_increment_from_an_unknown_z_stays_unknown(tmp_path, threshold):
    """No Z, so no height passes a Z check: no travel height to lift to, no strokes at any
    threshold, and not a servo job (its spindle output is no tool state)."""
    prog = _load(tmp_path, RELATIVE_Z, z_threshold=threshold)
    assert [b.modal.z for b in prog.blocks] == [None] * len(prog.blocks)
    assert travel_height(prog) is None
    assert not prog.pen_mode and prog.strokes == []
    lo, hi = job_extent(prog)
    assert (lo[2], hi[2]) == (np.inf, -np.inf)  # no Z in the extent
    assert axis_feeds(prog)[2] == 0.0  # its plunges' speed is not known either
    check_tool_up_at_end(prog)  # it lifts at its end
    with pytest.raises(ConfigError, match="cannot resume here: the file has not given Z in "):
        resume_preamble(prog, 7)  # the second plunge


def test_a_relative_job_cut_off_at_a_plunge_is_refused(tmp_path):
    """Its Zs compare among themselves (all counted from where the job began): a file that
    ends by feeding down below the height it travels at is refused, saying so."""
    prog = _load(tmp_path, RELATIVE_Z[:8])
    with pytest.raises(ConfigError) as err:
        check_tool_up_at_end(prog)
    assert str(err.value).startswith(
        f"{prog.path}:8: the program ends by feeding the tool down to Z -0.1 mm, below its "
        "travel height 2 (both counted from the Z the job began at), and never lifts it"
    )


def test_a_resume_does_not_travel_at_a_z_of_another_frame(tmp_path):
    """The file travels at Z 9, then changes the frame Z is counted in (G10 L2 on the
    system in use): until it gives Z again the height is not known, so a resume there is
    refused, naming the line; after, the preamble travels at the new frame's Z 2 only (Z 9
    of the old frame may lie anywhere in the new one)."""
    lines = ["G21 G90", "G0 Z9", "G0 X1 Y1", "G1 Z-0.1 F100", "G1 X5", "G0 Z9",
             "G10 L2 P1 Z-3", "G0 X2 Y2", "G1 Z-0.1", "G1 X6", "G0 Z2",
             "G0 X3 Y3", "G1 Z-0.1", "G1 X7", "G0 Z2"]  # fmt: skip
    prog = _load(tmp_path, lines)
    assert len(prog.strokes) == 3
    with pytest.raises(ConfigError) as err:
        resume_preamble(prog, prog.strokes[1][0])
    assert str(err.value).startswith(
        f"{prog.path}:9: cannot resume here: the file has not given Z in absolute mode (G90) "
        "since line 7 ('G10L2P1Z-3')"
    )
    pre = resume_preamble(prog, prog.strokes[2][0])
    assert [line for line in pre if "Z" in line] == ["G0Z2"]
    assert "G0X3Y3" in pre


@pytest.mark.parametrize(
    ("offset", "line"),
    [
        (["G43.1 Z1.5", "G0 Z2"], "line 3 ('G43.1Z1.5') set a tool length offset"),
        (["G92 X0 Y0"], "line 3 ('G92X0Y0') set a G92 offset"),
    ],
)
def test_a_resume_after_an_offset_a_reset_clears_is_refused(tmp_path, offset, line):
    """The stop's soft reset cleared it, so the file's positions past it would land
    elsewhere; once the file cleared it itself (G49, G92.1) the resume goes on."""
    body = ["G0 Z2", "G0 X1 Y1", "G1 Z-0.1 F100", "G1 X5", "G0 Z2",
            "G0 X3 Y3", "G1 Z-0.1", "G1 X7", "G0 Z2"]  # fmt: skip
    prog = _load(tmp_path, ["G21 G90", "G0 Z2", *offset, *body])
    with pytest.raises(ConfigError) as err:
        resume_preamble(prog, prog.strokes[1][0])
    assert str(err.value).startswith(f"{prog.path}:")
    assert f"cannot resume here: {line}, which the stop's soft reset cleared" in str(err.value)
    cleared = "G49" if "G43.1" in offset[0] else "G92.1"
    again = [cleared, "G0 Z2"]  # Z (and after G92.1 X and Y) given again
    prog = _load(tmp_path, ["G21 G90", "G0 Z2", *offset, *body[:5], *again, *body[5:]])
    assert "G0X3Y3" in resume_preamble(prog, prog.strokes[1][0])


def test_the_envelope_is_checked_from_where_the_job_starts(tmp_path):
    """The file lifts Z before its first XY move, where the machine stands: checked from
    there once placed (refused outside the envelope), and not at the parse's assumed
    X0 Y0, which is no position of the machine's."""
    prog = _load(tmp_path, ["G21 G90", "G0 Z2", "G0 X5 Y0", "G1 Z-0.1 F100", "G1 X8", "G0 Z2"])
    profile = _bench_profile(x=(2.0, 10.0))
    settings = {110: 1000, 111: 1000, 112: 500}
    assert job_extent(prog) == ([5.0, 0.0, -0.1], [8.0, 0.0, 2.0])  # X0 Y0 is not known
    assert compare(settings, None, prog, profile).refusals == []
    assert compare(settings, None, prog, profile, start_xy=(3.0, 1.0)).refusals == []
    refused = compare(settings, None, prog, profile, start_xy=(-4.0, 1.0)).refusals
    assert refused == [
        f"{prog.path}:2: the machine stands at work X-4 Y1 now, outside the envelope (X [2, 10]) "
        "of machine 'bench', and the job's first moves run from there (the file itself: X [5, 8] "
        "mm); jog the tool into the envelope, or, if the work zero is not at the profile's X0 "
        "Y0, jog there and send `G10 L20 P0 X0 Y0` (P0: the work system in use), then stream "
        "again"
    ]
    # in another work system than the file's the start is not placed: left out
    prog = _load(tmp_path, ["G21 G90 G54", "G0 Z2", "G0 X5 Y0", "G1 Z-0.1 F100", "G0 Z2"])
    assert compare(settings, None, prog, profile, start_xy=(-4.0, 1.0), wcs="G55").refusals == []


def test_a_first_move_is_timed_from_where_the_job_starts(tmp_path):
    """A feed move from the start runs along the line from where the machine stands: to
    (3, 4) at F1000 from (0, 0), X at 600 and Y at 800 mm/min; from (3, -4), Y at 1000."""
    prog = _load(tmp_path, ["G21 G90", "G1 X3 Y4 F1000", "G91 G1 X1 F100"])
    assert axis_feeds(prog)[:2] == [100.0, 0.0]  # the first move, from where?, left out
    assert axis_feeds(prog.placed_at((0.0, 0.0)))[:2] == pytest.approx([600.0, 800.0])
    assert axis_feeds(prog.placed_at((3.0, -4.0)))[:2] == pytest.approx([100.0, 1000.0])
    relative = _load(tmp_path, ["G21 G91", "G1 X3 Y4 F1000"])  # the same wherever it starts
    assert axis_feeds(relative)[:2] == pytest.approx([600.0, 800.0])


@pytest.mark.parametrize(("start", "cw"), [((20.0, 30.0), True), ((-5.0, 2.0), False)])
def test_an_arc_from_the_start_sweeps_from_where_the_machine_stands(tmp_path, start, cw):
    """A G91 arc first in the file: its sweep is known once placed, wherever that is, and
    left out before."""
    motion = "G2" if cw else "G3"
    prog = _load(tmp_path, ["G21 G91 G17", f"{motion} X10 Y0 I5 J0 F100"])
    assert job_extent(prog)[0][:2] == [np.inf, np.inf]
    lo, hi = job_extent(prog.placed_at(start))
    s = np.asarray(start)
    pts = _arc_samples(s, s + (10.0, 0.0), cw, ij=(5.0, 0.0))
    assert np.allclose((lo[0], lo[1], hi[0], hi[1]), (*pts.min(0), *pts.max(0)), atol=1e-6)


def test_a_resume_of_a_job_without_absolute_z_says_why_it_cannot_tell_what_cuts(tmp_path):
    """No Z level to list: the refusal says the file gives Z only as increments."""
    prog = _load(tmp_path, RELATIVE_Z)
    with pytest.raises(ScratchfabError) as err:
        _check_strokes(prog, prog.path)
    assert "(it gives Z only as G91 increments from where Z stood, or not at all)" in str(err.value)
