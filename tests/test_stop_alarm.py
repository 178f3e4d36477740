"""What the sender says and journals when an alarm comes while it stops the machine.

An ``ALARM:N`` that cuts the stop's feed hold short means GRBL stopped the machine itself
(at speed, where the hold still slowed it down): the message must say so, not "machine
held", also when a second Ctrl-C (or a signal) cut the stop short. ``ALARM:2`` names the
line whose target left the travel: GRBL checks a line when it plans it, before its
``ok``. A feed hold the sender did not send (the controller's hold button) that ends in
a soft-limit alarm at speed is journaled as a maybe lost position, which a resume tells.
"""

from __future__ import annotations

import json
import re
import signal

import pytest
from stream_helpers import (
    FAST,
    HeldUntilFeedHold,
    PortProxy,
    executed_blocks,
    interrupt_after,
    stream_program,
    stroke_job,
)

from scratchfab.machine.sender import (
    StopSignal,
    Streamer,
    StreamFault,
    StreamStopped,
    open_port,
)
from scratchfab.machine.sender_journal import Journal, read_journal
from scratchfab.machine.sender_program import load_program, resume_preamble
from scratchfab.machine.stream_job import lost_position_warning

#: As test_stop_soft_limit: homed at machine X -1, soft limits on (X travels -200..0, $130
#: at its default 200), work offset 0. 2 mm moves down X at 20 mm/s fill the planner; one
#: line lies outside the travel.
_MOVES = ["G21G90", "G1X-3F1200"] + [f"G1X{-3 - 2 * k}" for k in range(1, 30)]
_JOB = "\n".join([*_MOVES[:22], "G1X10", *_MOVES[22:]]) + "\n"
_URL = "grblsim://?baud=115200&soft_limits=1&homed=1"
_HELD = "machine held, then soft-reset"


def _outside_lines(text: str) -> list[tuple[int, str]]:
    """The file lines (number, text) whose X target lies beyond machine X 0 (offset 0)."""
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        x = re.search(r"X(-?[0-9.]+)", line)
        if x and float(x[1]) > 0.0:
            out.append((n, line))
    return out


def _stream(tmp_path, job_text, progress, ask="stop", port=None, said=None):
    """Stream ``job_text`` to the soft-limit emulator; the exception, journal and record."""
    job = tmp_path / "job.gcode"
    job.write_text(job_text)
    port = port or open_port(_URL, 115200)
    try:
        with pytest.raises((StreamStopped, StreamFault, KeyboardInterrupt)) as exc:
            stream_program(
                port,
                load_program(job),
                tmp_path / "j.jsonl",
                on_progress=progress,
                ask_interrupt=lambda: ask,
                on_message=(said.append if said is not None else None),
            )
    finally:
        port.close()
    sim = getattr(port, "sim", None) or port.inner.sim
    return exc.value, read_journal(tmp_path / "j.jsonl"), sim.record


@pytest.mark.parametrize("ask", ["stop", "resume"])
def test_an_alarm_during_the_users_hold_is_told_first_with_the_line_out_of_travel(tmp_path, ask):
    """Ctrl-C holds at speed; GRBL reads the out-of-travel line while slowing down and
    stops the motors itself (the emulator records the speed). The message names that
    line (the only one beyond machine X 0) and, stopped, says the hold was cut short
    rather than 'machine held'; the journal counts as run only moves that ran."""
    port = HeldUntilFeedHold(open_port(_URL, 115200), b"G1X10")  # read in the hold, always
    exc, events, record = _stream(tmp_path, _JOB, interrupt_after(19), ask, port=port)
    alarms = [e for e in record if e["ev"] == "alarm"]
    assert [a["code"] for a in alarms] == [2] and alarms[0]["lost"] > 0.0
    text = str(exc)
    ((n, line),) = _outside_lines(_JOB)
    assert "ALARM:2 (soft limit" in text and f"on line {n} ({line!r})" in text
    assert "machine X 10.000 outside -200..0 ($130)" in text
    assert _HELD not in text
    if ask == "stop":
        assert isinstance(exc, StreamStopped)
        assert text.index("the feed hold was cut short: ALARM:2") < text.index("soft-reset it")
        assert text.endswith("clear the alarm as it says, then continue with --resume")
    through = events[-1]["executed_through"]
    assert events[-1]["ev"] == "stop" and through < n - 1
    assert set(range(1, through + 1)) <= executed_blocks(record)


def test_a_line_out_of_travel_after_a_g92_is_said_to_be_unknown(tmp_path):
    """Past a G92 the sender does not place targets in machine coordinates: the alarm's
    line is said to be unknown, never a guess."""
    job = "G21G90\nG92X0\n" + _JOB.split("\n", 1)[1]
    exc, _, record = _stream(tmp_path, job, None)
    assert [e["code"] for e in record if e["ev"] == "alarm"] == [2]
    text = str(exc)
    assert "ALARM:2" in text and "which line's target left the travel is not known" in text
    assert "whose target lies beyond" not in text


class _CtrlCAfterAlarm(PortProxy):
    """A port raising ``exc`` (a second Ctrl-C, a signal) on the first read after an
    ``ALARM:`` line came through, once."""

    def __init__(self, inner, exc: BaseException) -> None:
        super().__init__(inner)
        self._exc, self._got, self.fired = exc, b"", False

    def read(self, size=1):
        if b"ALARM:" in self._got and not self.fired:
            self.fired = True
            raise self._exc
        data = self.inner.read(size)
        self._got += data
        return data


@pytest.mark.parametrize("second", [KeyboardInterrupt(), StopSignal(signal.SIGTERM)])
def test_a_second_ctrl_c_after_an_alarm_mentions_the_alarm(tmp_path, second):
    """The first Ctrl-C's stop waits for the hold; ALARM:2 comes; a second Ctrl-C (or a
    SIGTERM) cuts the stop short. What the user is told names the alarm, not 'machine
    held'."""
    port = _CtrlCAfterAlarm(open_port(_URL, 115200), second)
    said: list[str] = []
    exc, events, record = _stream(tmp_path, _JOB, interrupt_after(19), port=port, said=said)
    assert port.fired and [e["code"] for e in record if e["ev"] == "alarm"] == [2]
    told = str(exc) if isinstance(second, StopSignal) else said[-1]
    if isinstance(second, StopSignal):
        assert isinstance(exc, StreamStopped) and told.startswith("stopped by SIGTERM after line")
    else:
        assert type(exc) is KeyboardInterrupt
    assert "the feed hold was cut short: ALARM:2" in told and _HELD not in told
    assert not any(_HELD in m for m in said)
    assert events[-1]["ev"] == "stop"


def test_the_controllers_hold_button_before_a_soft_limit_is_journaled_as_maybe_lost(tmp_path):
    """A feed hold the sender did not send (the controller's button: '!' straight to the
    port) slows the machine down; GRBL reads the out-of-travel line meanwhile and stops
    the motors at speed. The sender cannot tell that hold from GRBL's own soft-limit hold:
    the journal's alarm says the position is maybe lost, and a resume warns."""
    port = open_port(_URL, 115200)
    pressed: list[int] = []

    def button(p):
        if p.acked > 19 and not pressed:
            pressed.append(1)
            port.write(b"!")  # not through the sender

    exc, events, record = _stream(tmp_path, _JOB, button, port=port)
    (alarm,) = [e for e in record if e["ev"] == "alarm"]
    assert alarm["code"] == 2 and alarm["lost"] > 0.0  # the reference: stopped at speed
    assert isinstance(exc, StreamFault) and "home it ($H) before --resume unless" in str(exc)
    assert [(e["code"], e.get("lost")) for e in events if e["ev"] == "alarm"] == [(2, "maybe")]
    warning = lost_position_warning(events)
    assert warning is not None and "the controller's feed hold button" in warning
    through = events[-1]["executed_through"]
    assert set(range(1, through + 1)) <= executed_blocks(record)


class _OksUpTo(PortProxy):
    """A port passing the controller's first ``n`` ``ok`` answers and dropping later ones:
    the sender sees no file line accepted."""

    def __init__(self, inner, n: int) -> None:
        super().__init__(inner)
        self._left, self._buf = n, b""

    @property
    def in_waiting(self):
        return self.inner.in_waiting

    def read(self, size=1):
        self._buf += self.inner.read(size)
        *lines, self._buf = self._buf.split(b"\n")
        out = b""
        for line in lines:
            if line.strip() == b"ok":
                if self._left <= 0:
                    continue
                self._left -= 1
            out += line + b"\n"
        return out


def test_a_resumed_session_stopped_before_its_first_line_names_that_line(tmp_path):
    """Stopped before GRBL accepted any file line of a resumed session (their answers
    dropped on the way): the message names the line the session starts at, not
    'line none'."""
    job = tmp_path / "job.gcode"
    stroke_job(job, 6)
    prog = load_program(job)
    start = next(a for a, _ in prog.strokes if a > 8)
    port = _OksUpTo(open_port("grblsim://?baud=0&time_scale=0.05", 115200), 10**6)
    try:
        # the connect's $I, $$, $#, $G are answered; then the preamble's lines only
        streamer = Streamer(port, FAST, ask_interrupt=lambda: "stop")
        streamer.connect()
        port._left = len(resume_preamble(prog, start))
        streamer.on_progress = interrupt_after(-1)
        journal = Journal(tmp_path / "j.jsonl").open()
        try:
            with pytest.raises(StreamStopped) as exc:
                streamer.stream(
                    prog, journal, start=start, preamble=resume_preamble(prog, start), resume=True
                )
        finally:
            journal.close()
    finally:
        port.close()
    assert not [e for e in read_journal(tmp_path / "j.jsonl") if "i" in e]
    text = str(exc.value)
    assert "none" not in text
    assert text.startswith(
        f"stopped by the user before GRBL accepted line {prog.blocks[start].lineno}, the first "
        "line of this resumed session; machine held, then soft-reset"
    )


@pytest.mark.parametrize(
    ("state", "own", "lost"),
    [
        ("Run", False, "maybe"),  # a hold button's hold may begin and end between reports
        ("Hold:1", False, "maybe"),  # GRBL's own soft-limit hold, or the button's
        ("Hold:0", False, None),  # held: standing when the line was read
        ("Idle", False, None),  # standing: GRBL alarms before any motion
        ("Run", True, True),  # the sender's own hold, not yet seen complete
    ],
)
def test_a_soft_limit_is_journaled_lost_unless_the_machine_was_last_seen_standing(
    tmp_path, state, own, lost
):
    """With a fast deceleration a hold the sender did not send may start and end between
    two status reports: where the last one showed the machine moving, the position is
    maybe lost (GRBL may have stopped the motors at speed), as where it showed Hold:1."""
    from scratchfab.machine.sender import ControllerInfo, Status

    streamer = Streamer.__new__(Streamer)  # the alarm's rule alone: no port
    streamer.info = ControllerInfo()  # no $$ read: $22 not known
    streamer.status = Status(state=state)
    streamer._hold_unseen = own
    streamer._journal = Journal(tmp_path / "j.jsonl").open()
    streamer._soft_limit_line = lambda: "on a line not known"  # type: ignore[method-assign]
    fault = streamer._alarm_fault(2)
    streamer._journal.close()
    (alarm,) = [json.loads(line) for line in (tmp_path / "j.jsonl").read_text().splitlines()]
    assert alarm["ev"] == "alarm" and alarm.get("lost") == lost
    assert ("home it ($H)" in str(fault)) is (lost is not None)
