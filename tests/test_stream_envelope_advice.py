"""The envelope refusal and the travel warning say what the maker should change.

A homed machine whose work offset is still 0 stands at machine X-1 Y-1 (the pull-off),
which in a work-coordinate profile is work X-1 Y-1: off the board. The envelope refusal
read "the job's X range [-1, 197.734] mm leaves the envelope [0, 300]", a range the file
never reaches; now it names the machine's position as such, and the advice to set the
work zero comes once, last. GRBL's Z travel larger than a work-coordinate profile's
``z_mm`` (the work-Z range the job may use) is no finding; in machine coordinates it
names the setting to change.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from test_stream import _bench_profile, read_record
from test_stream_cli_input import _stream

from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender_checks import compare
from scratchfab.machine.sender_program import load_program

#: A lab's own work-coordinate profile: 300 x 300 travel, Z scribe 0 down / 3 up.
LAB = """name = "lab"
dialect = "grbl-1.1"
start_mm = [0.0, 0.0]

[envelope]
x_mm = [0.0, 300.0]
y_mm = [0.0, 300.0]
z_mm = [-1.0, 5.0]

[board]
origin = "lower-left"
offset_mm = [0.0, 0.0]

[z]
safe_mm = 3.0
engrave_mm = 0.0

[feeds]
engrave_mm_min = 600.0
plunge_mm_min = 200.0

[motion]
max_rate_mm_min = [2000.0, 2000.0, 600.0]
acceleration_mm_s2 = [100.0, 100.0, 50.0]

[tool]
width_mm = 0.1
depth_mm = 0.01

[tool_control]
mode = "z"
"""
JOB = "G21 G90\nG0 Z3\nG0 X10 Y10\nG1 Z0 F100\nG1 X197.734\nG0 Z3\n"
#: The lab machine's GRBL: soft limits on, homed (MPos -1 on each axis, $27=1).
MACHINE = (
    "grblsim://?baud=0&time_scale=0&soft_limits=1&homed=1&$130=300&$131=300&$132=45"
    "&$110=2000&$111=2000&$112=600&$120=100&$121=100&$122=50"
)


@pytest.fixture()
def lab(tmp_path):
    (tmp_path / "lab.toml").write_text(LAB)
    (tmp_path / "j.gcode").write_text(JOB)
    return tmp_path


def _g_sent(rec):
    return [e for e in read_record(rec) if e["ev"] == "rx" and e["text"].startswith("G")]


def test_a_homed_machine_with_no_work_zero_is_named_where_it_stands(lab):
    job, rec = lab / "j.gcode", lab / "rec.jsonl"
    code, _, err = _stream(
        [str(job), "--machine", str(lab / "lab.toml"), "--port", f"{MACHINE}&record={rec}",
         "--yes"],
        "",
    )  # fmt: skip
    assert code == 2
    refused = [line for line in err.splitlines() if line.startswith("refused: ")]
    envelope = next(line for line in refused if "envelope" in line)
    assert envelope == (
        f"refused: {job}:2: the machine stands at work X-1 Y-1 now, outside the envelope "
        "(X [0, 300], Y [0, 300]) of machine 'lab', and the job's first moves run from there "
        "(the file itself: X [10, 197.734], Y [10, 10] mm)"
    )
    assert not any("range [-1," in line for line in refused)  # no range the file never reaches
    last = err.rstrip().splitlines()[-1]
    assert last.startswith(f"error: {job}: GRBL's work offset is 0 on X, Y and Z")
    assert "`G10 L20 P0 X0 Y0` (P0: the work system in use)" in last and "`G10 L20 P0 Z0`" in last
    assert last.endswith("(nothing was sent)")
    assert sum("G10 L20" in line for line in err.splitlines()) == 1  # the advice once
    assert not _g_sent(rec)
    assert "allows more Z travel" not in err  # z_mm is a work range here


def test_the_advice_followed_the_job_streams(lab):
    """The work zero set on the board (G10 L20 at machine X-250 Y-250 Z-40): it streams."""
    job, rec = lab / "j.gcode", lab / "rec.jsonl"
    port = f"{MACHINE}&wco=-250,-250,-40&record={rec}"
    code, out, err = _stream(
        [str(job), "--machine", str(lab / "lab.toml"), "--port", port, "--yes"], ""
    )
    assert code == 0, err
    assert "refused" not in err and "G10 L20" not in err and "done:" in out
    assert _g_sent(rec)


def _placed_refusal(tmp_path, profile, wco, start=(-4.0, 1.0)):
    job = tmp_path / "j.gcode"
    job.write_text("G21 G90\nG0 Z2\nG0 X5 Y0\nG1 Z-0.1 F100\nG1 X8\nG0 Z2\n")
    return compare({}, wco, load_program(job), profile, start_xy=start).refusals


def test_a_start_outside_with_a_work_zero_set_says_to_jog_or_check_the_zero(tmp_path):
    (refusal,) = _placed_refusal(tmp_path, _bench_profile(x=(2.0, 10.0)), (-30.0, -30.0, -5.0))
    assert refusal == (
        f"{tmp_path / 'j.gcode'}:2: the machine stands at work X-4 Y1 now, outside the envelope "
        "(X [2, 10]) of machine 'bench', and the job's first moves run from there (the file "
        "itself: X [5, 8] mm); jog the tool into the envelope, or, if the work zero is not at "
        "the profile's X0 Y0, jog there and send `G10 L20 P0 X0 Y0` (P0: the work system in "
        "use), then stream again"
    )


def test_a_machine_coordinate_profile_is_told_to_jog_not_to_set_a_work_zero(tmp_path):
    """grbl-3018-diamond moves in machine coordinates: a work zero is what it must not have."""
    diamond = load_profile("grbl-3018-diamond")
    narrow = SimpleNamespace(
        name=diamond.name,
        envelope=SimpleNamespace(
            x_mm=(-290.0, -10.0), y_mm=diamond.envelope.y_mm, z_mm=diamond.envelope.z_mm,
            max_travel_mm=(280.0, 180.0, 45.0), coordinates="machine",
        ),
        motion=diamond.motion,
    )  # fmt: skip
    job = tmp_path / "j.gcode"
    job.write_text("G21 G90\nG0 Z-27\nG0 X-220 Y-150\nG1 Z-30.2 F200\nG1 X-200\nG0 Z-27\n")
    refusals = compare({}, (0.0, 0.0, 0.0), load_program(job), narrow, start_xy=(-1, -1)).refusals
    assert refusals == [
        f"{job}:2: the machine stands at work X-1 Y-1 now, outside the envelope (X [-290, -10]) "
        f"of machine '{diamond.name}', and the job's first moves run from there (the file "
        "itself: X [-220, -200] mm); jog the tool into the envelope, then stream again"
    ]


def test_a_file_that_leaves_the_envelope_itself_names_its_own_range(tmp_path):
    """Not the start's position: the range the file's own lines reach."""
    job = tmp_path / "j.gcode"
    job.write_text("G21 G90\nG0 Z2\nG0 X5 Y0\nG1 Z-0.1 F100\nG1 X30\nG0 Z2\n")
    refusals = compare(
        {}, None, load_program(job), _bench_profile(), start_xy=(-40.0, 0.0)
    ).refusals
    assert refusals[0] == (
        f"{job}:5: the job's X range [5, 30] mm leaves the envelope [-10, 10] of machine 'bench'"
    )


def test_relative_moves_from_an_inside_start_that_go_out_name_the_start(tmp_path):
    job = tmp_path / "j.gcode"
    job.write_text("G21 G90\nG0 Z2\nG91 G0 X15\nG90 G0 Z2\n")
    (refusal,) = compare(
        {}, None, load_program(job), _bench_profile(), start_xy=(0.0, 0.0)
    ).refusals
    assert refusal.startswith(
        f"{job}:3: run from where the machine stands now (work X0 Y0), the job's moves reach "
        "X [0, 15] mm, outside the envelope (X [-10, 10]) of machine 'bench'"
    )


@pytest.mark.parametrize(
    ("coordinates", "z_mm", "warned"),
    [("work", (-1.0, 5.0), False), ("machine", (-40.0, 0.0), True)],
)
def test_more_z_travel_than_the_profile_is_told_in_machine_coordinates_only(
    tmp_path, coordinates, z_mm, warned
):
    """A work-coordinate z_mm is the work-Z range the job may use, not the machine's
    travel; a machine-coordinate one is the travel, and the warning names both fixes."""
    profile = SimpleNamespace(
        name="m",
        envelope=SimpleNamespace(
            x_mm=(0.0, 300.0) if coordinates == "work" else (-300.0, 0.0),
            y_mm=(0.0, 300.0) if coordinates == "work" else (-300.0, 0.0),
            z_mm=z_mm, max_travel_mm=(300.0, 300.0, z_mm[1] - z_mm[0]), coordinates=coordinates,
        ),
        motion=SimpleNamespace(
            max_rate_mm_min=(2000.0, 2000.0, 600.0), acceleration_mm_s2=(100.0, 100.0, 50.0)
        ),
    )  # fmt: skip
    job = tmp_path / "j.gcode"
    job.write_text("G21 G90\nG0 X10 Y10\n")
    settings = {130: 300.0, 131: 300.0, 132: 45.0}
    warnings = [
        w for w in compare(settings, None, load_program(job), profile).warnings if "$132" in w
    ]
    if not warned:
        assert warnings == []
        return
    assert warnings == [
        "GRBL $132=45 allows more Z travel than machine 'm' has in its profile ([envelope] "
        "z_mm = [-40, 0], 40 mm): if the machine travels 45 mm, set z_mm = [-45, 0] (a stock "
        "Grbl's travel after homing; a margin inside it is yours to keep); if not, set "
        "$132=40 so that GRBL's soft limits stop where it ends"
    ]
