"""The dropped link's message names the spindle only where the file starts one.

A 3018 owner streaming a Z drag-bit job (no M3/M4 anywhere) read "a controller that kept
power goes on running the lines it had received (up to a planner full of moves, spindle
on)": a spindle that job never starts. The words follow the file.
"""

from __future__ import annotations

import re

import pytest
from test_stream_cli_input import _stream

DRAG = ["G21 G90", "G0 Z2"] + [
    line for k in range(8) for line in (f"G0 X{2 * k} Y0", "G1 Z-0.05 F200", "G1 Y8 F600", "G0 Z2")
]
SPINDLE = ["G21 G90", "M3 S1000", "G0 Z2"] + DRAG[2:] + ["M5"]


@pytest.mark.parametrize("lines", [DRAG, SPINDLE], ids=["drag-bit", "spindle"])
def test_the_lost_link_names_the_spindle_only_where_the_file_starts_one(tmp_path, lines):
    job = tmp_path / "job.gcode"
    job.write_text("\n".join([*lines, "M2"]) + "\n")
    port = "grblsim://?baud=0&time_scale=0.02&disconnect_after=12"
    code, _, err = _stream([str(job), "--port", port, "--yes"], "")
    assert code == 3 and "Traceback" not in err, err
    said = next(line for line in err.splitlines() if "goes on running" in line)
    starts = any(re.search(r"\bM0*[34](?!\d)", line) for line in lines)  # the file's own words
    assert starts == (lines is SPINDLE)
    assert ("spindle on" in said) == starts, said
    assert "up to a planner full of moves" in said, said
