"""A controller found locked in Alarm mid-job by an ``error:9`` before any report says so.

GRBL answers ``error:9`` (G-code locked out) to a line only in Alarm (or a jog, which the
sender never starts). After a brown-out with homing on whose banner and messages were lost
on the line, that answer can come before the status report that says Alarm: the stop is
the Alarm's (a reset, the position not trusted), not an error's "machine held".
"""

from __future__ import annotations

from unittest.mock import ANY

import pytest
from stream_helpers import FAST, executed_blocks
from test_stream import _Deaf, write_job

from scratchfab.machine.sender import Streamer, StreamFault, open_port
from scratchfab.machine.sender_journal import Journal, read_journal
from scratchfab.machine.sender_program import load_program

#: Homed, soft limits and homing on ($22=1): a brown-out comes back locked in Alarm.
_URL = "grblsim://?baud=0&time_scale=0.01&soft_limits=1&homed=1&wco=-100,-100,-10"


@pytest.mark.parametrize("reset_after", [3, 20])
def test_error_9_mid_job_stops_as_an_alarm_not_as_a_held_machine(tmp_path, reset_after):
    """The banner, ``[MSG:...]`` and every Alarm report lost: ``error:9`` is the only sign.
    The message names the line that got it and the Alarm, not a hold; nothing after the
    reset runs; no block counts as run that the controller did not run."""
    job = tmp_path / "job.gcode"
    write_job(job, 30)
    prog = load_program(job)
    port = open_port(f"{_URL}&reset_after={reset_after}", 115200)
    streamer = Streamer(port, FAST)
    streamer.connect()
    streamer.port = _Deaf(port, lost=(b"Grbl", b"[MSG", b"<Alarm"))
    journal = tmp_path / "j.jsonl"
    j = Journal(journal).open()
    try:
        with pytest.raises(StreamFault) as info:
            streamer.stream(prog, j)
    finally:
        j.close()
        port.close()
    text = str(info.value)
    record = port.sim.record
    block_of: dict[int, int] = {}  # the emulator's line number -> program block, as received
    for e in record:
        if e["ev"] == "rx" and e["g"]:
            block_of[e["n"]] = len(block_of)
    answers = [(block_of[e["n"]], e["r"]) for e in record if e["ev"] == "resp" and e["g"]]
    refused = next(i for i, r in answers if r == "error:9")
    accepted = max(i for i, r in answers if r == "ok")
    # the reset flushed the lines in flight unanswered: error:9 answers a later one, which
    # the message must not name as the line refused (GRBL answers in order)
    assert accepted + 1 < refused
    said = "error:9 (G-code is locked out during ALARM or jog state) came after line "
    assert text.startswith(f"{said}{prog.blocks[accepted].lineno}, so the controller is in Alarm")
    assert "home it or check the zero, then --resume" in text
    assert "machine held" not in text and "feeding stopped" not in text
    assert not [e for e in record if e["ev"] == "rt" and e["ch"] == ord("!")]  # no hold
    events = read_journal(journal)
    stop = events[-1]
    assert stop["ev"] == "stop" and "error:9" in stop["reason"]
    assert [e for e in events if e["ev"] == "error"] == [{"ev": "error", "code": 9, "time": ANY}]
    ran = executed_blocks(record)
    assert all(i in ran for i in range(stop["executed_through"] + 1) if prog.blocks[i].motion)
