"""Shared by the sender tests: stream a program through a connected Streamer."""

from __future__ import annotations

import math

import pytest

from scratchfab.machine.sender import Streamer, StreamOptions, StreamStopped, open_port
from scratchfab.machine.sender_journal import Journal, default_journal_path, read_journal
from scratchfab.machine.sender_program import load_program, resume_preamble

#: Short timeouts for emulator ports (which send a banner's messages with it, at once).
FAST = StreamOptions(banner_timeout=0.5, banner_settle=0.02, stall_timeout=1.0)


def stream_program(port, prog, journal_path, options=FAST, resume_at=None, **kwargs):
    """Connect, stream ``prog`` with a journal at ``journal_path``, return the Streamer.

    ``resume_at``: a block index to resume at, as ``stream --resume`` does (the resume
    preamble, the journal session marked as a continuation); None streams from the top.
    """
    streamer = Streamer(port, options, **kwargs)
    streamer.connect()
    journal = Journal(journal_path).open()
    try:
        if resume_at is None:
            streamer.stream(prog, journal)
        else:
            preamble = resume_preamble(prog, resume_at)
            streamer.stream(prog, journal, start=resume_at, preamble=preamble, resume=True)
    finally:
        journal.close()
    return streamer


def executed_blocks(record, until: float = math.inf) -> set[int]:
    """Program blocks (in received order) whose motion the emulator finished, at its
    clock's ``until`` or before (its ``record``)."""
    block_of: dict[int, int] = {}
    for e in record:
        if e["ev"] == "rx" and e["g"]:
            block_of[e["n"]] = len(block_of)
    return {block_of[e["n"]] for e in record if e["ev"] == "exec" and e["t"] <= until}


def interrupt_after(acks: int, exc: type[BaseException] = KeyboardInterrupt):  # noqa: ANN201
    """An ``on_progress`` raising ``exc`` (Ctrl-C) once more than ``acks`` lines are
    acknowledged, once; its ``fired`` list is not empty once it has."""
    fired: list[int] = []

    def progress(p):
        if p.acked > acks and not fired:
            fired.append(1)
            raise exc

    progress.fired = fired  # type: ignore[attr-defined]
    return progress


def stopped_after(journal_path, prog, acks: int, url: str) -> tuple[list[dict], list[dict]]:
    """Stream ``prog`` to the emulator at ``url``, stopped by Ctrl-C once more than ``acks``
    lines are acknowledged (the user answers "stop"): the journal's events and the
    emulator's record. The journal ends with the stop."""
    progress = interrupt_after(acks)
    port = open_port(url, 115200)
    try:
        with pytest.raises(StreamStopped):
            stream_program(
                port, prog, journal_path, on_progress=progress, ask_interrupt=lambda: "stop"
            )
    finally:
        port.close()
    events = read_journal(journal_path)
    assert events[-1]["ev"] == "stop"
    return events, port.sim.record


def stroke_job(path, strokes: int) -> None:
    """Write a G-code job of ``strokes`` 8 mm strokes along Y, 2 mm apart: each a travel,
    a plunge, a cut and a lift (four lines), after two lines of setup."""
    lines = ["G21 G90", "G0 Z2"]
    for k in range(strokes):
        x = 2.0 * k
        lines += [f"G0 X{x:.3f} Y0", "G1 Z-0.05 F200", f"G1 X{x:.3f} Y8 F600", "G0 Z2"]
    path.write_text("\n".join(lines) + "\n")


def alarmed_job(path, lost, code: int, homing: bool = True) -> str:
    """Write :func:`stroke_job` (12 strokes) to ``path``, stop it on the emulator after 12
    acknowledged lines and journal an ``ALARM:code`` with ``lost`` before the stop (as the
    sender journals one): the lost-position warning a resume then gives. The journal says
    GRBL's homing was ``homing`` ($22; a soft limit needs it on, which the emulator's
    defaults leave off)."""
    import json

    from scratchfab.machine.stream_job import lost_position_warning

    stroke_job(path, 12)
    journal = default_journal_path(path)
    stopped_after(journal, load_program(path), 12, "grblsim://?baud=0&time_scale=0.02")
    text = journal.read_text().splitlines()
    start = json.loads(text[0])
    assert start["ev"] == "start" and start["homing"] is False  # the emulator's $22=0
    text[0] = json.dumps({**start, "homing": homing})
    alarm = {"ev": "alarm", "code": code, "lost": lost, "time": "2026-01-01T00:00:00"}
    journal.write_text("\n".join([*text[:-1], json.dumps(alarm), text[-1]]) + "\n")
    warning = lost_position_warning(read_journal(journal), homing=homing)
    assert warning is not None
    return warning


def spy_rests(monkeypatch) -> list[int]:
    """The blocks the sender rests after (``Streamer._wants_rest`` said yes), as it streams."""
    rested: list[int] = []
    wants = Streamer._wants_rest

    def spy(self, j):
        out = wants(self, j)
        if out:
            rested.append(j)
        return out

    monkeypatch.setattr(Streamer, "_wants_rest", spy)
    return rested


#: A partial board on a machine and on the emulator: (real port, flags, answers, refusal).
PARTIAL_BOARD_CASES = [
    (True, ["--yes"], "", "refusing to cut a partial board with --yes: "),
    (True, [], "n\n", "not confirmed; nothing was sent"),
    (True, [], "y\ny\n", None),  # the partial board, then the usual question
    (False, ["--yes"], "", None),  # the emulator: said, neither asked nor refused
]


class PortProxy:
    """A port passing everything to ``inner``; a test's subclass changes ``read``."""

    def __init__(self, inner) -> None:
        self.inner = inner

    def __getattr__(self, name):
        return getattr(self.inner, name)

    @property
    def timeout(self):
        return self.inner.timeout

    @timeout.setter
    def timeout(self, value):
        self.inner.timeout = value


class HeldUntilFeedHold(PortProxy):
    """A link that holds back the line starting with ``line`` (and all written after it)
    until the sender's feed hold (``!``) has passed, then sends them.

    So the controller reads that line only once the hold came, however late the sender's
    Ctrl-C comes on a loaded machine (at its next progress report, up to a poll period
    after the ok that triggers it, plus the scheduler's delays): in real time the emulator
    would otherwise read it in the cycle, a few blocks after the trigger's ok. Realtime
    bytes pass at once.
    """

    def __init__(self, inner, line: bytes) -> None:
        super().__init__(inner)
        self.line = line
        self.held = b""
        self.released = False

    def write(self, data: bytes) -> int:
        if self.released or (len(data) == 1 and (data in b"?~\x18" or data[0] >= 0x80)):
            return self.inner.write(data)
        if data == b"!":
            self.inner.write(data)
            self.released = True
            if self.held:
                self.inner.write(self.held)
            return 1
        if self.held or data.startswith(self.line):
            self.held += data
            return len(data)
        return self.inner.write(data)


@pytest.fixture
def at_a_terminal(monkeypatch):
    """stdin taken for a terminal: a person answers even the questions a pipe may not
    (was the machine homed?), as the tests' piped input does for them."""
    monkeypatch.setattr("scratchfab.cli.options.stdin_is_a_terminal", lambda: True)


def hard_limit_run(tmp_path):
    """A pipeline (:func:`conftest.write_pipeline`) run to its end, then journaled as if its
    stream met a hard limit (``ALARM:1``, position lost) after 40 acknowledged lines:
    (the pipeline file, the job folder, its stream journal)."""
    import json

    from conftest import write_pipeline

    from scratchfab.pipeline.config import load_pipeline
    from scratchfab.pipeline.runner import run_pipeline

    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    run_pipeline(load_pipeline(path), job, say=lambda _: None)
    journal = job / "stream" / "journal.jsonl"
    events = read_journal(journal)
    last = max(k for k, e in enumerate(events) if e["ev"] == "start")
    acks = [e for e in events[last:] if e["ev"] == "ack" and "i" in e][:40]
    alarm = {"ev": "alarm", "code": 1, "lost": True, "time": "2026-01-01T00:00:00"}
    stop = {"ev": "stop", "reason": "ALARM:1", "executed_through": acks[-1]["i"]}
    with journal.open("a") as handle:  # as if the stream met a hard limit after 40 lines
        for event in [events[last], *acks, alarm, stop]:
            handle.write(json.dumps(event) + "\n")
    return path, job, journal
