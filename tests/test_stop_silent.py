"""A controller that falls silent mid-job: the stop says what to do next, as other faults do."""

from __future__ import annotations

import dataclasses
import time

import pytest
from stream_helpers import FAST, PortProxy, stream_program, stroke_job

from scratchfab.machine.sender import StreamFault, open_port
from scratchfab.machine.sender_journal import read_journal
from scratchfab.machine.sender_program import load_program


class _Silent(PortProxy):
    """A port whose controller sends nothing more once ``quiet`` is set (a hung board)."""

    quiet = False

    @property
    def in_waiting(self):
        return 0 if self.quiet else self.inner.in_waiting

    def read(self, size=1):
        if self.quiet:
            time.sleep(self.inner.timeout or 0.0)
            return b""
        return self.inner.read(size)


def test_silence_stops_the_stream_naming_resume(tmp_path):
    stroke_job(tmp_path / "job.gcode", 20)
    prog = load_program(tmp_path / "job.gcode")
    port = _Silent(open_port("grblsim://?baud=0&time_scale=0.2", 115200))

    def progress(p):
        if p.acked > 10:
            port.quiet = True

    options = dataclasses.replace(FAST, silence_timeout=0.5)
    try:
        with pytest.raises(StreamFault) as caught:
            stream_program(port, prog, tmp_path / "j.jsonl", options, on_progress=progress)
    finally:
        port.close()
    text = str(caught.value)
    assert "(no status reports)" in text
    assert "press its reset before going near it" in text
    assert text.endswith("run the same command with --resume")
    stop = read_journal(tmp_path / "j.jsonl")[-1]
    assert stop["ev"] == "stop" and stop["executed_through"] < 11
