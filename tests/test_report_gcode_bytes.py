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
