"""The sender's reading of the controller: end of job, grblHAL, safety door, offsets."""

from __future__ import annotations

from scratchfab.machine.sender import Streamer, StreamOptions, open_port
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
