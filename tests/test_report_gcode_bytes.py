"""report.html's G-code statistics of a file that is not UTF-8 (a Latin-1 comment): counted,
and the sender's refusal named, not a traceback (a reviewer)."""

from __future__ import annotations

from scratchfab.pipeline.report import gcode_statistics


def test_a_latin1_comment_is_counted_and_the_refusal_named(tmp_path):
    path = tmp_path / "board.gcode"
    path.write_bytes(b"G21 G90 G17 G94\n(gravure sur m\xe9tal)\nG0 Z5\nG0 X1 Y1\nG1 Z-0.1 F100\n"
                     b"G1 X2 F300\nG0 Z5\nM2\n")  # fmt: skip
    stats = gcode_statistics(path)
    assert stats["lines"] == 8
    assert isinstance(stats["sent"], str) and stats["sent"].startswith("none: stream refuses")
    assert "board.gcode" in stats["sent"] and str(tmp_path) not in stats["sent"]
    # the same file in ASCII is read and sent, its comment left out
    path.write_bytes(path.read_bytes().replace(b"\xe9", b"e"))
    assert gcode_statistics(path)["sent"] == 7


def test_cutting_moves_are_counted_as_stream_tells_them_for_the_profile(tmp_path):
    """A servo job held up by M3 S90 whose first move runs under M5 does not tell its up
    state alone (one stroke: every M3 down), but stream, given the profile (off = M3 S90),
    finds its two strokes; the report counts them as stream does for the toolpath's machine."""
    from test_stream_servo_lift import plotter_lines, servo_profile, write

    from scratchfab.machine.profile import load_profile
    from scratchfab.machine.stream_job import load_program_for

    lines = plotter_lines("M3 S90", "M3 S35", ["M5", "G1 X1 Y1 F4000", "M3 S90"])
    path = write(tmp_path, "board.gcode", lines)
    profile = load_profile(servo_profile(tmp_path))
    alone, told = gcode_statistics(path), gcode_statistics(path, profile)
    assert len(load_program_for(path, profile).strokes) == 2  # the reference: stream's reading
    assert told["cuts"] == 2  # X10 to X11, X20 to X21
    assert alone["cuts"] != told["cuts"]


def test_the_ranges_are_where_the_moves_go_as_the_sender_reads_them(tmp_path):
    """Words without spaces, inches, an arc's sweep and an axis named in a comment: the
    ranges are the moves' (work mm), not the file's words (a comment's X5 made a traceback,
    and G0X1Y2 gave no range)."""
    path = tmp_path / "board.gcode"
    path.write_text("G20G90\nG0X1Y2 (to X5)\nG1Z-0.01F10\nG2X3Y2I1J0\nM2\n")
    stats = gcode_statistics(path)
    # by hand, in mm: X 1..3 in; Y 2 in, and the clockwise arc about (2, 2) tops at Y 3 in
    assert stats["X range"] == "25.4 .. 76.2 mm"
    assert stats["Y range"] == "50.8 .. 76.2 mm"
    assert stats["Z range"] == "-0.254 .. -0.254 mm"
    assert stats["sent"] == 5 and stats["lines"] == 5


def test_the_size_is_the_file_s_bytes(tmp_path):
    path = tmp_path / "board.gcode"
    path.write_text("(gravure sur métal)\nG0 X1\n", encoding="utf-8")  # é: two bytes
    stats = gcode_statistics(path)
    assert stats["bytes"] == len("(gravure sur métal)\nG0 X1\n".encode()) == 27
    assert stats["longest_line"] == len("(gravure sur métal)") == 19
