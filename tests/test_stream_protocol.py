"""The sender's reading of the controller: end of job, grblHAL, safety door, offsets."""

from __future__ import annotations

import json
import urllib.parse

import pytest

from scratchfab.cli import main
from scratchfab.machine.sender import Streamer, StreamFault, StreamOptions, open_port
from scratchfab.machine.sender_journal import Journal, read_journal
from scratchfab.machine.sender_program import load_program

FAST = StreamOptions(banner_timeout=0.5, stall_timeout=1.0)


def _stream(port, prog, journal_path, options=FAST, **kwargs):
    streamer = Streamer(port, options, **kwargs)
    streamer.connect()
    journal = Journal(journal_path).open()
    try:
        streamer.stream(prog, journal)
    finally:
        journal.close()
    return streamer


def test_done_only_once_the_last_move_has_run(tmp_path):
    """GRBL serves a ``?`` that came while it planned the last block after that block's
    ``ok`` and before the cycle start: that Idle report is not the end of the job."""
    job = tmp_path / "end.gcode"
    job.write_text("G21 G90\nG0 Z1\nG1 X2 F600\nM5\nG0 Z5\n")
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"
    port = open_port("grblsim://?plan_time=0.3", 115200)
    try:
        _stream(port, prog, journal)
        record = list(port.sim.record)  # what had run when the sender said done
    finally:
        port.close()
    moves = [e for e in record if e["ev"] == "exec"]
    assert moves and moves[-1]["to"] == [2.0, 0.0, 5.0]
    events = read_journal(journal)
    acks = [e for e in events if e["ev"] == "ack"]
    # the wait the sender adds is not a file line: only the file's blocks are journaled
    assert [e.get("i") for e in acks] == list(range(len(prog.blocks)))
    assert events[-1]["ev"] == "end"


GRBLHAL = "GrblHAL 1.1f ['$' or '$HELP' for help]"
HAL_URL = "grblsim://?banner=" + urllib.parse.quote(GRBLHAL)


def test_grblhal_banner_is_recognised_and_named(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z1\nG1 X2 F600\nG0 Z2\n")
    rec = tmp_path / "rec.jsonl"
    main(["stream", str(job), "--port", f"{HAL_URL}&time_scale=0.01&record={rec}", "--yes",
          "--banner-timeout", "0.5"])  # fmt: skip
    got = capsys.readouterr()
    assert "connected: grblHAL 1.1f, RX buffer 128 bytes" in got.out + got.err
    received = [e["text"] for e in map(json.loads, rec.read_text().splitlines())
                if e["ev"] == "rx" and e["g"]]  # fmt: skip
    assert received == ["G21G90", "G0Z1", "G1X2F600", "G0Z2", "G4P0"]


def test_grblhal_reset_mid_job_is_seen(tmp_path):
    """A reset is recognised by grblHAL's banner too: lines on the way are flushed."""
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\n" + "".join(f"G1 X{k % 7} F3000\n" for k in range(60)))
    port = open_port(f"{HAL_URL}&time_scale=0.01&reset_after=20", 115200)
    try:
        with pytest.raises(StreamFault, match="reset itself mid-job"):
            _stream(port, load_program(job), tmp_path / "j.jsonl")
    finally:
        port.close()


def test_grblhal_tool_offset_on_every_axis(tmp_path):
    """grblHAL's ``[TLO:x,y,z]`` (every axis by default): Z's offset is the third."""
    port = open_port(f"{HAL_URL}&boot=0.3", 115200)
    try:
        port.sim.startup_lines[0] = "G43.1Z2"  # before the power-up's banner
        info = Streamer(port, FAST).connect()
    finally:
        port.close()
    assert info.firmware == "grblHAL" and info.wco_source == "$#"
    assert info.wco == pytest.approx((0.0, 0.0, 2.0))


def test_grblhal_refuses_a_tool_change_before_sending(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z1\nT2 M06\nG1 X2 F600\n")
    port = open_port(f"{HAL_URL}&time_scale=0.01", 115200)
    try:
        with pytest.raises(StreamFault, match=r"job\.gcode:3: M6 \(tool change\): grblHAL"):
            _stream(port, load_program(job), tmp_path / "j.jsonl")
    finally:
        port.close()
    assert not [e for e in port.sim.record if e["ev"] == "rx" and e["g"]]


def test_an_unknown_banner_is_refused(tmp_path):
    port = open_port("grblsim://?banner=Smoothie%20edge&boot=0", 115200)
    try:
        with pytest.raises(StreamFault, match=r"no GRBL banner \('Grbl 1\.1\.\.\.' or 'GrblHAL"):
            Streamer(port, StreamOptions(banner_timeout=0.2)).connect()
    finally:
        port.close()
