"""A tool length offset set on the machine by hand, and a file that cancels it (G49)."""

from __future__ import annotations

import pytest
from stream_helpers import FAST

from scratchfab.machine.sender import Streamer, open_port
from scratchfab.machine.sender_checks import compare
from scratchfab.machine.sender_program import load_program

URL = "grblsim://?baud=0&time_scale=0.01&boot=0.3&wco=-100,-80,-20"
SETTINGS = {20: 1.0, 22: 1.0, 130: 300.0, 131: 200.0, 132: 60.0}


def _connect_with_offset(z: float):
    """Connect to an emulator whose start-up line sets G43.1 Z``z``; its ``$#``-read info
    and its work Z before and after a G49."""
    port = open_port(URL, 115200)
    try:
        port.sim.startup_lines[0] = f"G43.1Z{z:g}"  # runs before the power-up's banner
        s = Streamer(port, FAST)
        info = s.connect()
        before = s._status_now().wpos
        s._command("G49")
        after = s._status_now().wpos
    finally:
        port.close()
    return info, before, after


def _job(tmp_path, header: str):
    job = tmp_path / "job.gcode"
    job.write_text(f"{header}\nG0 Z5\nG0 X10 Y10\nG1 Z-0.1 F100\nG1 X20 F300\nG0 Z5\nM2\n")
    return load_program(job)


def test_a_g49_with_an_offset_set_on_the_machine_is_refused(tmp_path):
    info, before, after = _connect_with_offset(1.5)
    assert info.tlo == pytest.approx(1.5)
    # the emulator (Grbl's gc_execute_line): the G49 moves work Z by the offset, where the
    # parse took it for no change; the envelope check would be 1.5 mm off past it
    assert before is not None and after is not None
    assert after[2] - before[2] == pytest.approx(1.5, abs=2e-3)
    prog = _job(tmp_path, "G21 G90 G49")
    refusals = compare(SETTINGS, info.wco, prog, tlo=info.tlo).refusals
    assert any(r.startswith(f"{prog.path}:1: 'G21G90G49' cancels") for r in refusals), refusals
    assert any("[TLO:] 1.500 mm" in r and "send G49" in r for r in refusals)


def test_a_file_without_g49_or_a_machine_without_an_offset_is_not_refused_for_it(tmp_path):
    info, _, _ = _connect_with_offset(0.0)
    assert info.tlo == 0.0
    with_g49 = _job(tmp_path, "G21 G90 G49")
    assert not compare(SETTINGS, info.wco, with_g49, tlo=info.tlo).refusals
    without = _job(tmp_path, "G21 G90")
    assert not compare(SETTINGS, info.wco, without, tlo=1.5).refusals
