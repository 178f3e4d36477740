"""Shared by the sender tests: stream a program through a connected Streamer."""

from __future__ import annotations

from scratchfab.machine.sender import Streamer, StreamOptions
from scratchfab.machine.sender_journal import Journal

#: Short timeouts for emulator ports (which send a banner's messages with it, at once).
FAST = StreamOptions(banner_timeout=0.5, banner_settle=0.02, stall_timeout=1.0)


def stream_program(port, prog, journal_path, options=FAST, **kwargs):
    """Connect, stream ``prog`` with a journal at ``journal_path``, return the Streamer."""
    streamer = Streamer(port, options, **kwargs)
    streamer.connect()
    journal = Journal(journal_path).open()
    try:
        streamer.stream(prog, journal)
    finally:
        journal.close()
    return streamer
