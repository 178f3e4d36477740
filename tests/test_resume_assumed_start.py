"""A resume of a file that counts X or Y from where its job began is refused."""

import pytest

from scratchfab.errors import ConfigError
from scratchfab.machine.sender_program import load_program, resume_preamble

#: A relative (G91) job: each stroke's place depends on where the machine stood at start.
RELATIVE = ["G21 G91", "G0 Z1", "G0 X10 Y10", "G1 Z-1.1 F100", "G1 X5", "G0 Z1.1",
            "G0 X5", "G1 Z-1.1", "G1 Y5", "G0 Z1.1"]  # fmt: skip
#: An absolute job that never gives Y: Y stays where the machine stood.
NO_Y = ["G21 G90", "G0 Z1", "G0 X10", "G1 Z-0.1 F100", "G1 X15", "G0 Z1",
        "G0 X20", "G1 Z-0.1", "G1 X25", "G0 Z1"]  # fmt: skip


@pytest.mark.parametrize(("lines", "axes"), [(RELATIVE, "X and Y"), (NO_Y, "Y")])
def test_a_resume_where_the_file_counts_from_its_start_is_refused(tmp_path, lines, axes):
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(lines) + "\n")
    prog = load_program(path)
    start = [b.index for b in prog.blocks if b.text.startswith("G1Z-")][1]  # the 2nd plunge
    with pytest.raises(ConfigError) as err:
        resume_preamble(prog, start)
    text = str(err.value)
    assert f"{path}:{prog.blocks[start].lineno}: cannot resume here" in text
    assert f"has not given {axes} in absolute mode" in text


def test_a_resume_after_x_and_y_given_absolute_goes_there(tmp_path):
    # the same job as NO_Y with Y given once: the second stroke starts at work (20, 3)
    path = tmp_path / "job.gcode"
    path.write_text("\n".join([*NO_Y[:2], "G0 X10 Y3", *NO_Y[3:]]) + "\n")
    prog = load_program(path)
    assert "G0X20Y3" in resume_preamble(prog, prog.strokes[1][0])


@pytest.mark.parametrize(
    ("header", "controller", "placed"),
    [
        ("G21 G90", "G55", True),  # the file runs in the controller's system
        ("G21 G90 G54", "G54", True),
        ("G21 G90 G54", "G55", False),  # the start was read in G55, the job runs in G54
        ("G21 G90 G54", None, False),  # the controller's system is not known
    ],
)
def test_a_job_is_placed_only_in_the_system_the_start_was_read_in(
    tmp_path, header, controller, placed
):
    path = tmp_path / "job.gcode"
    path.write_text(f"{header}\nG0 Z1\nG0 X10\nG1 Z-0.1 F100\nG1 X15\nG0 Z1\nG0 Y20\n")
    prog = load_program(path).placed_at((5.0, 30.0), controller)
    # Y is counted from the start until the last line gives it
    ys = [b.modal.y for b in prog.blocks[:-1]]
    assert ys == [30.0 if placed else 0.0] * len(ys)
    assert all(b.modal.assumed == ("" if placed else "Y") for b in prog.blocks[2:-1])
    assert prog.blocks[-1].modal.y == 20.0
