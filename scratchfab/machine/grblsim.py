r"""A GRBL 1.1 controller in software, for tests, dry runs and other senders.

The emulator reproduces what a sender can observe on the serial line of a Grbl 1.1h board:

- the banner ``\r\nGrbl 1.1h ['$' for help]\r\n`` at power-up and after every soft reset,
  ``[MSG:...]`` feedback, ``ALARM:N`` and ``ok``/``error:N`` responses ending in ``\r\n``;
- bytes arrive at the line's speed (10 bits per byte at ``baud``); realtime bytes
  (``?``, ``!``, ``~``, ``0x18``, overrides) are picked off on arrival anywhere in the stream;
  the rest go into a 128-byte RX buffer that silently drops bytes when full (recorded);
- the main loop moves characters into an 80-byte line buffer (stripping spaces, control
  characters and comments, upper-casing), treats CR and LF each as a line end (so CRLF
  gets two ``ok``), and answers ``error:11`` for lines over 79 characters;
- a 15-block planner: ``ok`` means "queued", so it lags while the planner is full; a
  block frees (``Bf:``, a waiting line's ``ok``) once the stepper has prepared its last
  segment, 40-50 ms before it ends (sooner for blocks shorter than that). Motion
  is timed as Grbl's planner runs it, by the ETA's model (:mod:`scratchfab.toolpath.timing`):
  per-axis rates and accelerations (``$110``-``$112``, ``$120``-``$122``), corners at the
  junction speed of ``$11``, look-ahead over the blocks queued when it plans (the newest
  ends at rest, so a planner that runs short slows down; a block queued behind the running
  one re-plans it once the segments prepared before it came have run), trapezoid profiles
  in the reported position; the realtime ``FS:`` rate is the speed where the prepared
  segments end (Grbl's ``prep.current_speed``: 40-50 ms ahead, 0 once a stop or the end
  is all prepared); moves run between targets rounded to whole steps
  (``$100``-``$102``) and the reported position is the steps taken so far (each axis
  by Grbl's Bresenham counters, tick by tick under AMASS, an event's ticks from one
  event's distance before it ends), so ``X0.01`` at 250 steps/mm ends at 0.012; a move
  of no whole step, which Grbl drops, passes at once, takes no block in ``Bf:`` and no
  ``plan_time``; a changed feed or rapid override (``0x90``-``0x97``) re-plans, the
  running block slowing down (through it into the next where it is too short) or
  speeding up at its acceleration; a hold, override or new block acts once the stepper
  has run the segments it had prepared (5 of 10 ms, the running one included, each
  block's last one shorter: 40-50 ms; 10 ms longer while one runs under 1.25 steps, as
  from rest or at a slow feed); a ``$100``-``$102`` change keeps the step counts, so the
  reported position moves; all times ``time_scale``.
  These wait for the planner to empty (so their ``ok`` comes after the motion before
  them ended): spindle and coolant changes, dwells, M0/M2/M30, G10, G28.1/G30.1,
  G92/G92.1 and a change of G54-G59 or of the G43.1 offset (Grbl's default
  ``FORCE_BUFFER_SYNC_DURING_WCO_CHANGE``); not an S change in a block that moves under
  laser mode (``$32=1``); in laser mode with M3 on, also a block without motion that
  switches between G1-G3 and another motion mode, and a move of no whole step (Grbl's
  ``mc_line`` syncs the spindle where ``plan_buffer_line`` drops a move);
- ``$`` commands with their state rules (``error:8``/``error:9``), check mode ``$C`` with the
  soft reset on leaving it, soft limits (``$20``) raising ``ALARM:2`` and locking until reset
  (checked as Grbl's ``mc_line`` comes to each motion, so after a line's spindle sync or
  an arc's earlier segments; in a cycle it holds first: ``Hold:1``, no line read, the
  alarm once the machine stands, as Grbl's ``limits_soft_check``; during a hold that
  still slows down, ``ALARM:2`` at once with the machine stopped at speed),
  feed hold ``Hold:1`` -> ``Hold:0`` and resume (a hold, door or jog cancel slows down
  at the acceleration of the block it is in, into the next one if it must, as Grbl's
  stepper does, and the reported position follows; the resume starts from rest; lines
  are still read and planned while it decelerates, none once it is complete, M0's
  ``ok`` comes after the resume; a hold or door during a dwell is ``Hold:0``/``Door``
  at once and the dwell's time stands still until the resume, Idle again); a feed
  hold or jog cancel (``0x85``) during a jog cancels it instead: the machine slows down
  (still ``Jog``; no line is parsed meanwhile), the jog blocks are flushed, Idle;
- the safety door (``0x84``, or :meth:`GrblSim.open_door` for the switch): the machine
  stops (``Door:2``; a jog is cancelled first and reports ``Jog`` until it stopped),
  spindle and coolant go off, ``Door:1`` while the door is open and
  ``Door:0`` once it is closed (:meth:`GrblSim.close_door`); no line is parsed meanwhile
  (Grbl's suspend loop). Cycle start (``~`` or :meth:`GrblSim.cycle_start`) in ``Door:0``
  restores spindle and coolant (``Door:3``, Grbl's 4 s spindle and 1 s coolant delays times
  ``time_scale``) and resumes; in ``Door:1`` it is ignored. A reset with the door open
  comes back in ``Door:1``. No parking motion (Grbl's default build).

Fault injection (see :class:`SimOptions`): an error at the N-th G-code block, a disconnect
after N blocks (the host vanishes; the controller still runs what it had received), lost
``ok``s and slow answers. Every received line, response and executed motion is recorded in
:attr:`GrblSim.record` (and written as JSONL to ``SimOptions.record`` on close).
"""

from __future__ import annotations

import collections
import dataclasses
import itertools
import json
import math
import threading
import time
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from scratchfab.errors import ConfigError
from scratchfab.machine.grblsim_gcode import (
    MM_PER_INCH,
    Action,
    GcodeError,
    ModalState,
    Settings,
    interpret,
    read_number,
)
from scratchfab.model.schema import check_bounds, parse_table, spec
from scratchfab.toolpath.timing import (
    exit_speed_sq,
    one_corner_speed_sq,
    one_move_limits,
    one_profile_seconds,
    profile_at,
)

VERSION = "1.1h"
BUILD = "20190830"
BANNER = f"\r\nGrbl {VERSION} ['$' for help]\r\n"
RX_BUFFER_SIZE = 128
PLANNER_BLOCKS = 15
LINE_BUFFER_SIZE = 80

CMD_STATUS = 0x3F  # ?
CMD_HOLD = 0x21  # !
CMD_START = 0x7E  # ~
CMD_RESET = 0x18
CMD_DOOR = 0x84
CMD_JOG_CANCEL = 0x85
#: Grbl's stepper segments (``stepper.c``): ``DT_SEGMENT`` is 1 / ``ACCELERATION_TICKS_PER_SECOND``
#: (100), and the ring of ``SEGMENT_BUFFER_SIZE`` 6 holds 5 prepared segments, the one the
#: stepper interrupt runs included: the 40-50 ms a hold or an override comes after.
SEGMENT_SECONDS = 0.01
SEGMENTS_PREPARED = 5
#: Grbl 1.1's ``SAFETY_DOOR_SPINDLE_DELAY`` and ``SAFETY_DOOR_COOLANT_DELAY`` (seconds).
DOOR_SPINDLE_DELAY = 4.0
DOOR_COOLANT_DELAY = 1.0

#: Grbl 1.1h defaults (``defaults.h``, generic machine).
DEFAULT_SETTINGS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
    20: 0, 21: 0, 22: 0, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0,
    32: 0, 100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}  # fmt: skip
_INT_SETTINGS = {0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32}


class LinkDown(Exception):
    """The emulated serial link is gone (fault injection or closed)."""


@dataclass(frozen=True)
class SimOptions:
    """How the emulator behaves; every field can be set from a ``grblsim://?key=value`` URL.

    Counts of G-code blocks are 1-based since power-up; 0 turns the fault off.

    Attributes:
        baud: Line speed for byte timing (10 bits per byte); 0 makes the line instantaneous.
        time_scale: Multiplies motion, dwell, hold and homing times (0.01 = 100x faster).
        latency: One-way link latency in seconds (e.g. a USB frame), added to both directions.
        error_at: The N-th G-code block answers ``error:<error_code>`` instead of running.
        error_code: The code for ``error_at`` (Grbl sends it as one byte: 1 to 255).
        disconnect_after: After the N-th G-code block is received the link drops; the
            controller keeps running what it already received (the host vanished).
        usb_powered: The controller loses power with the link (``disconnect_after`` or
            :meth:`drop_link`; a board powered over the USB cable) and stops where it is,
            running nothing more of what it had received.
        lose_ok_at: The ``ok`` of the N-th G-code block is never sent (a garbled answer).
        reset_after: The controller resets itself (brown-out) after the N-th G-code block.
        slow: Extra seconds before every ``ok``/``error`` answer.
        plan_time: Seconds Grbl spends planning each motion block (not scaled by
            ``time_scale``). A ``?`` arriving meanwhile is served after the line's ``ok``
            and before the cycle start, as Grbl's main loop does: an ``Idle`` report with a
            block queued but not started (the premature Idle a sender must not take for
            the end of the job). 0: planning takes no time.
        boot: Seconds between power-up and the banner.
        soft_limits: Start with ``$20=1`` and ``$22=1`` (so also in ALARM until homed/unlocked).
        homed: With ``soft_limits``: start homed (Idle at ``MPos = -$27`` on every axis).
        wco: The G54 offset at power-up in mm; ``x,y,z`` in a URL.
        wco_field: Status reports carry ``WCO:`` (Grbl's compile option
            ``REPORT_FIELD_WORK_COORD_OFFSET``, on by default); off, only ``$#`` tells it.
        banner: The start-up banner line ("": ``Grbl 1.1h ['$' for help]``). One starting
            ``GrblHAL `` (grblHAL's, e.g. ``GrblHAL 1.1f ['$' or '$HELP' for help]``) also
            makes ``$I`` and ``$#`` answer as grblHAL's defaults do: ``[OPT:V,15,128,3,0]``
            and ``[FIRMWARE:grblHAL]``, and ``[TLO:x,y,z]`` (its ``TOOL_LENGTH_OFFSET_AXIS``
            is -1, every axis). Everything else stays Grbl 1.1h.
        record: Write the event record here (JSONL) when the emulator closes ("": none).
        settings: ``$`` settings overrides, ``{number: value}``; ``$N=value`` in a URL.
    """

    baud: int = field(default=115200, metadata=spec(ge=0))
    time_scale: float = field(default=1.0, metadata=spec(ge=0))
    latency: float = field(default=0.0, metadata=spec(ge=0))
    error_at: int = field(default=0, metadata=spec(ge=0))
    error_code: int = field(default=20, metadata=spec(ge=1, le=255))
    disconnect_after: int = field(default=0, metadata=spec(ge=0))
    usb_powered: bool = False
    lose_ok_at: int = field(default=0, metadata=spec(ge=0))
    reset_after: int = field(default=0, metadata=spec(ge=0))
    slow: float = field(default=0.0, metadata=spec(ge=0))
    plan_time: float = field(default=0.0, metadata=spec(ge=0))
    boot: float = field(default=0.0, metadata=spec(ge=0))
    soft_limits: bool = False
    homed: bool = False
    wco: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wco_field: bool = True
    banner: str = ""
    record: str = ""
    settings: dict[int, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Options built in code meet the bounds a URL's do (a NaN time spins the emulator).

        Raises:
            ValueError: Naming the field, or the setting and its value.
        """
        check_bounds(self)
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"SimOptions.{f.name}: expected a finite number, got {value}")
        for number, value in self.settings.items():
            if number not in DEFAULT_SETTINGS or not (math.isfinite(value) and value >= 0):
                raise ValueError(
                    f"SimOptions.settings: ${number}={value}: expected a Grbl 1.1 setting "
                    "at least 0"
                )

    @classmethod
    def from_query(cls, query: Mapping[str, str], source: str = "port 'grblsim://'") -> SimOptions:
        """Options from text pairs (a ``grblsim://`` URL's query), every value checked now.

        Raises:
            ConfigError: One line starting with ``source``, naming the key, the value and
                what is expected (an unknown key also gets the nearest valid one).
        """
        hints = typing.get_type_hints(cls)
        data: dict[str, Any] = {}
        overrides: dict[int, float] = {}
        for key, raw in query.items():
            where = f"{source}: {key}"
            if key.startswith("$") and key[1:].isdigit():
                number = int(key[1:])
                if number not in DEFAULT_SETTINGS:
                    known = ", ".join(f"${k}" for k in DEFAULT_SETTINGS)
                    raise ConfigError(f"{where}: not a Grbl 1.1 setting (settings: {known})")
                value = _number_from_text(raw, float)
                if value is None or not math.isfinite(value) or value < 0:
                    raise ConfigError(f"{where}: expected a number at least 0, got {raw!r}")
                overrides[number] = value
            elif key == "settings":
                raise ConfigError(f"{where}: set GRBL settings as $N=value (e.g. $110=900)")
            elif key == "banner" and not (
                0 < len(raw) <= 100 and raw.isascii() and raw.isprintable()
            ):
                raise ConfigError(
                    f"{where}: expected one line of 1 to 100 printable ASCII characters "
                    f"(e.g. GrblHAL 1.1f ['$' or '$HELP' for help]), got {raw!r}"
                )
            elif key in hints:
                data[key] = _value_from_text(raw, hints[key], where)
            else:
                data[key] = raw  # parse_table names it with the nearest valid key
        data["settings"] = overrides
        return parse_table(cls, data, source)


_TRUE = ("1", "true", "yes")
_FALSE = ("0", "false", "no")


def _number_from_text(raw: str, kind: type[int] | type[float]) -> float | None:
    """``raw`` as a plain ASCII int or float (non-finite floats included), else None."""
    if not raw.isascii() or raw != raw.strip() or "_" in raw:
        return None
    try:
        return kind(raw)
    except ValueError:
        return None


def _value_from_text(raw: str, tp: Any, where: str) -> Any:
    """A URL query value as the field type ``tp``; parse_table then checks finiteness and bounds."""
    if tp is bool:
        if raw.lower() in _TRUE + _FALSE:
            return raw.lower() in _TRUE
        raise ConfigError(f"{where}: expected 1, 0, true, false, yes or no, got {raw!r}")
    if tp is int or tp is float:
        value = _number_from_text(raw, tp)
        if value is None:
            words = "an integer" if tp is int else "a number"
            raise ConfigError(f"{where}: expected {words}, got {raw!r}")
        return value
    if tp == tuple[float, float, float]:
        parts = [_number_from_text(v, float) for v in raw.split(",")]
        if len(parts) != 3 or None in parts:
            raise ConfigError(f"{where}: expected x,y,z (3 numbers in mm), got {raw!r}")
        return tuple(parts)
    return raw


def _lround(x: float) -> int:
    """C's ``lround``: to the nearest integer, halves away from zero (Grbl's steps)."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


@dataclass
class _Block:
    """A planned motion and, once planned, its current velocity profile."""

    start: tuple[float, float, float]  # mm, on the step grid (Grbl's planner position)
    end: tuple[float, float, float]  # mm, on the step grid (the target's whole steps)
    target: tuple[float, float, float]  # mm: the target as programmed (for the record)
    rate: float  # mm/min: the G1 feed, or the axis-limited rapid rate (before overrides)
    limit: float  # mm/min: the axis-limited rate along the move
    rapid: bool
    jog: bool  # a $J= move: no feed override (Grbl's PL_COND_FLAG_NO_FEED_OVERRIDE)
    line: int  # received-line index
    work_end: tuple[float, float, float]
    work_start: tuple[float, float, float]
    spindle: str
    length: float  # mm
    unit: tuple[float, float, float]  # direction
    accel: float  # mm/s^2 along the move
    corner_sq: float  # (mm/s)^2: the junction limit with the move before (0: from rest)
    done: float = 0.0  # mm run before the current profile starts (a re-plan or a hold)
    v0: float = 0.0  # mm/s entering the current profile
    v1: float = 0.0  # mm/s leaving the move
    vmax: float = 0.0  # mm/s cruise (overrides applied)
    span: float = 0.0  # mm the current profile covers (less than what is left: a hold's stop)
    duration: float = 0.0  # seconds of the current profile, already scaled
    seen: bool = True  # the stepper's profile takes it in (its arrival's re-plan has acted)
    least: float = 0.0  # mm of 1.25 step events: the least a segment runs (:meth:`_ends`)


@dataclass
class _Pending:
    """A parsed line whose actions have not all run yet (Grbl blocked inside the line)."""

    line: int
    gcode: int
    actions: list[Action]
    index: int = 0
    response: str = "ok"
    until: float = 0.0  # dwell/homing/planning end time
    planning: bool = False  # ``until`` is the end of planning a motion (plan_time)
    dwell_left: float = -1.0  # seconds left of a dwell suspended by a hold or door, else -1


class GrblSim:
    """The emulated controller. Thread-safe host side: :meth:`host_write` / :meth:`host_read`.

    Args:
        options: Behaviour and fault injection.
        clock: Monotonic clock in seconds (tests may pass a fake one).
    """

    def __init__(
        self, options: SimOptions | None = None, clock: Callable[[], float] = time.monotonic
    ):
        self.options = options or SimOptions()
        self._clock = clock
        self._cond = threading.Condition()
        self.record: list[dict[str, Any]] = []
        self.settings: dict[int, float] = dict(DEFAULT_SETTINGS)
        if self.options.soft_limits:
            self.settings[20] = 1
            self.settings[22] = 1
        self.settings.update(self.options.settings)
        self.startup_lines = ["", ""]
        self._grblhal = self.options.banner.startswith("GrblHAL ")
        self._offsets: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * 6
        self._offsets[0] = self.options.wco
        self.g28 = (0.0, 0.0, 0.0)
        self.g30 = (0.0, 0.0, 0.0)
        self.mpos: tuple[float, float, float] = (0.0, 0.0, 0.0)  # on the step grid
        self._target = self.mpos  # the last finished block's target as programmed
        self.state = "Idle"
        self.overruns = 0
        self.link_up = True
        self._byte_time = 10.0 / self.options.baud if self.options.baud > 0 else 0.0
        self._wire: collections.deque[tuple[float, int]] = collections.deque()
        self._wire_last = 0.0
        self._rx: collections.deque[int] = collections.deque()
        self._line: list[str] = []
        self._comment = ""  # "(" or ";" while inside a comment
        self._overflow = False
        self._pending: _Pending | None = None
        self._planner: collections.deque[_Block] = collections.deque()
        self._head_start = 0.0  # when the head block's current profile started
        self._hold_complete = False
        self._stopping = False  # a hold, door or jog cancel decelerates the machine to a stop
        self._stop_due = False  # such a stop is commanded, the prepared segments still run
        self._seg_origin = 0.0  # where the segments of the head block's run start (s)
        self._seg_last = 0.0  # the last segment end counted (the head's run start at least)
        # [segment ends left after _seg_last, kind, what]: "stop", "replan" (the feed and
        # rapid overrides), "block" (a new block), "probe" (a list that gets the time and
        # the speed there)
        self._deferred: list[list[Any]] = []
        self._land_at = math.inf  # when the first of them acts (:meth:`_schedule`)
        self._free_at: float | None = None  # when a block frees for a waiting line (None: unknown)
        self._wake_at = math.inf  # the waiting line looks again (:meth:`_block_free`)
        self._door_ajar = False  # the door switch
        self._restore_until = math.inf  # Door:3: spindle/coolant restoring before resuming
        self._door_saved: tuple[str, float, frozenset[str]] = ("M5", 0.0, frozenset())
        self._critical = False
        self._soft_limit = False  # a soft limit in a cycle: holding, then ALARM:2
        self._reset_at = math.inf
        self._boot_at = math.inf
        self._spindle = "M5"
        self._spindle_speed = 0.0
        self._coolant: frozenset[str] = frozenset()
        self._gc = ModalState()
        self._lines = 0
        self._gcode_lines = 0
        self._out: collections.deque[tuple[float, bytes]] = collections.deque()
        self._ready = bytearray()
        self._tx_free = 0.0
        self._wco_counter = 0
        self._ovr_counter = 0
        self._overrides = [100, 100, 100]
        self._planned_overrides = [100, 100]  # feed and rapid as the stepper runs them
        self._jogging = False
        self._jog_cancel = False  # stopping a jog that is then flushed (``!`` or 0x85)
        self._door_after_jog = False  # the door opened during the jog: Door once it stopped
        self._report_due = False  # a ``?`` that came while planning, served after it
        self._last_state_logged = ""
        self._thread: threading.Thread | None = None
        self._stop = False
        self.on_link_down: Callable[[], None] | None = None

    # ------------------------------------------------------------------ host side

    def start(self, thread: bool = True) -> None:
        """Power the controller up (banner after ``boot`` seconds) and run it.

        Args:
            thread: Run it on its own thread by ``clock``; False: the caller runs it with
                :meth:`advance` (a simulation in the caller's own time, e.g. a fake clock).
        """
        with self._cond:
            now = self._clock()
            self._tx_free = now
            self._wire_last = now
            self._boot_at = now + self.options.boot
            if thread:
                self._thread = threading.Thread(target=self._run, name="grblsim", daemon=True)
                self._thread.start()

    def advance(self, now: float) -> None:
        """Run the controller up to ``now`` (for a caller that started it without a thread)."""
        with self._cond:
            self._advance(now)

    def next_event(self) -> float:
        """When the controller next acts or a byte reaches the host (``inf``: waits for input)."""
        with self._cond:
            t = self._next_event()
            return min(t, self._out[0][0]) if self._out else t

    def host_write(self, data: bytes) -> int:
        """Bytes from the host; they reach the controller at the line's speed."""
        with self._cond:
            if not self.link_up:
                raise LinkDown("grblsim: link is down")
            now = self._clock()
            t = max(now + self.options.latency, self._wire_last)
            for byte in data:
                t += self._byte_time
                self._wire.append((t, byte))
            self._wire_last = t
            self._cond.notify_all()
        return len(data)

    def _collect(self, now: float) -> None:
        while self._out and self._out[0][0] <= now:
            self._ready += self._out.popleft()[1]

    def host_read(self, size: int, timeout: float | None) -> bytes:
        """Up to ``size`` bytes that have arrived at the host, waiting at most ``timeout`` s."""
        deadline = None if timeout is None else self._clock() + timeout
        with self._cond:
            while True:
                if not self.link_up:
                    raise LinkDown("grblsim: link is down")
                now = self._clock()
                self._collect(now)
                if self._ready:
                    out = bytes(self._ready[:size])
                    del self._ready[:size]
                    return out
                wait = 0.05 if not self._out else max(0.0, self._out[0][0] - now)
                if deadline is not None:
                    if now >= deadline:
                        return b""
                    wait = min(wait, deadline - now)
                self._cond.wait(wait)

    def host_in_waiting(self) -> int:
        """Bytes ready for the host."""
        with self._cond:
            if not self.link_up:
                raise LinkDown("grblsim: link is down")
            self._collect(self._clock())
            return len(self._ready)

    def host_flush_input(self) -> None:
        """Discard what has arrived at the host (pyserial's reset_input_buffer)."""
        with self._cond:
            self._collect(self._clock())
            self._ready.clear()

    def close(self, drain_timeout: float = 30.0) -> None:
        """The host is gone: run what was received (bounded), stop, and write the record."""
        deadline = time.monotonic() + drain_timeout
        with self._cond:
            while self._thread is not None and time.monotonic() < deadline and self._busy():
                self._cond.wait(0.02)
            self._stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self.options.record:
            from scratchfab.fileio import write_text

            write_text(
                self.options.record,
                "".join(json.dumps(e, separators=(",", ":")) + "\n" for e in self.record),
            )

    def _now(self) -> float:
        """The clock's time, the controller run up to it first (under the lock).

        A switch or button acts on the state of its instant: the emulator's thread may not
        have run the events before it yet (a hold completed, a move ended), and acting on
        the state before them would mix instants (a cycle start lost on a hold already
        complete, a door stopping a move that had ended).
        """
        t = self._clock()
        self._advance(t)
        return t

    def open_door(self) -> None:
        """The safety door switch opens (as the ``0x84`` realtime command does)."""
        with self._cond:
            self._door_event(self._now())
            self._cond.notify_all()

    def close_door(self) -> None:
        """The safety door switch closes: ``Door:1`` becomes ``Door:0`` (resumable)."""
        with self._cond:
            t = self._now()
            self._door_ajar = False
            if self.state == "Door":
                self._set_state(t, "Door")
            self._cond.notify_all()

    def cycle_start(self) -> None:
        """The controller's cycle start button (as ``~``)."""
        with self._cond:
            self._realtime(self._now(), CMD_START)
            self._cond.notify_all()

    def _busy(self) -> bool:
        if self._critical or (self.state in ("Hold", "Door") and self._hold_complete):
            return False
        return bool(self._wire or self._rx or self._pending or self._planner)

    def drop_link(self) -> None:
        """Cut the link now (like pulling the USB cable of an externally powered board)."""
        with self._cond:
            self._drop_link(self._now())

    def _drop_link(self, t: float) -> None:
        if not self.link_up:
            return
        self.link_up = False
        self._out.clear()
        self._ready.clear()
        self._log(t, "disconnect")
        if self.options.usb_powered:
            self._power_off(t)
        self._cond.notify_all()
        if self.on_link_down is not None:
            threading.Thread(target=self.on_link_down, daemon=True).start()

    # ------------------------------------------------------------------ event loop

    def _run(self) -> None:
        with self._cond:
            while not self._stop:
                now = self._clock()
                self._advance(now)
                nxt = self._next_event()
                self._cond.wait(min(max(nxt - now, 0.0), 0.05) if nxt < math.inf else 0.05)

    def _head_end(self) -> float:
        if not self._running():
            return math.inf
        return self._head_start + self._planner[0].duration

    def _next_event(self) -> float:
        t = min(self._head_end(), self._reset_at, self._boot_at, self._restore_until)
        t = min(t, self._land_at, self._wake_at)
        if self._wire:
            t = min(t, self._wire[0][0])
        if self._pending is not None and self._pending.until > 0.0:
            t = min(t, self._pending.until)
        return t

    def _advance(self, now: float) -> None:
        while True:
            t = self._next_event()
            if t > now:
                return
            if t == self._boot_at:
                self._boot_at = math.inf
                self._power_up(t)
            elif t == self._reset_at:
                # a brown-out: no ALARM:3, the position is lost (power-up state)
                self._reset_at = math.inf
                self._planner.clear()
                self.mpos = (0.0, 0.0, 0.0)
                self.state = "Alarm" if self.settings[22] else "Idle"
                self._soft_reset(t, from_command=False)
            elif self._wire and t == self._wire[0][0]:
                self._receive(t, self._wire.popleft()[1])
            elif t == self._restore_until:
                self._restore_until = math.inf
                self._door_resume(t)
            elif t == self._land_at:
                self._run_on(self._segment_end, t)
            elif t == self._wake_at:
                self._wake_at = math.inf
            elif t == self._head_end():
                self._run_on(self._finish_head, t)
            elif self._pending is not None and t == self._pending.until:
                self._pending.until = 0.0
                self._pending.planning = False
            self._main(t)

    def _run_on(self, step: Callable[[float], None], t: float) -> None:
        """A change landing or the head's end: the motion runs on as :meth:`_ahead`'s copies ran it.

        When a block frees stays what a copy found: it ran these very steps (a new block,
        override, stop or start is what changes it, and finds it again).
        """
        free = self._free_at
        step(t)
        self._free_at = free

    # ------------------------------------------------------------------ receive side

    def _receive(self, t: float, byte: int) -> None:
        if byte == CMD_STATUS:
            if self._pending is not None and self._pending.planning:
                self._report_due = True  # Grbl is inside plan_buffer_line()
            elif not self._critical and self.state != "Home":
                self._emit(t, self._status_report(t))
            return
        if byte in (CMD_HOLD, CMD_START, CMD_RESET) or byte >= 0x80:
            self._realtime(t, byte)
            return
        if len(self._rx) >= RX_BUFFER_SIZE:
            self.overruns += 1
            self._log(t, "overrun", byte=byte)
            return
        self._rx.append(byte)

    def _realtime(self, t: float, byte: int) -> None:
        self._log(t, "rt", ch=byte)
        if byte == CMD_RESET:
            self._soft_reset(t, from_command=True)
        elif byte == CMD_HOLD or byte == CMD_JOG_CANCEL:
            if self.state == "Jog":
                self._cancel_jog(t)  # Grbl 1.1: any hold during a jog cancels the jog
            elif byte == CMD_JOG_CANCEL:
                pass  # only a jog can be cancelled
            elif self.state == "Run":
                self._decelerate(t, "Hold")
            elif self.state == "Idle":
                self._hold_complete = True
                self._set_state(t, "Hold")
                self._suspend_dwell(t)
        elif byte == CMD_DOOR:
            self._door_event(t)
        elif byte == CMD_START:
            if self.state == "Door":
                self._door_restore(t)
            elif self.state == "Hold" and self._hold_complete:
                self._hold_complete = False
                if self._planner:
                    self._start_motion(t)  # from rest: planned so when the hold stopped it
                    self._set_state(t, "Run")
                else:
                    self._set_state(t, "Idle")
                    self._resume_dwell(t)
        elif 0x90 <= byte <= 0x94:
            self._overrides[0] = _override(self._overrides[0], byte - 0x90)
            self._ovr_counter = 0
            self._defer(t, "replan", self._overrides[:2])  # plan_update_velocity_profile_parameters
        elif 0x95 <= byte <= 0x97:
            self._overrides[1] = (100, 50, 25)[byte - 0x95]
            self._ovr_counter = 0
            self._defer(t, "replan", self._overrides[:2])
        elif 0x99 <= byte <= 0x9D:
            self._overrides[2] = _override(self._overrides[2], byte - 0x99)
            self._ovr_counter = 0
        # other extended bytes (toggles) are accepted and ignored

    def _cancel_jog(self, t: float) -> None:
        """Decelerate the jog (state stays Jog), then flush it (:meth:`_end_jog`)."""
        if self._jog_cancel:
            return
        self._jog_cancel = True
        self._decelerate(t, "Jog")

    def _end_jog(self, t: float) -> None:
        """The cancelled jog stopped: flush its blocks, sync the position, Idle.

        A door that opened meanwhile takes it to the door state instead, already stopped.
        """
        self._stop_head(t)
        self._planner.clear()
        self._jog_cancel = False
        self._jogging = False
        self._gc.position = self.mpos
        if self._door_after_jog:
            self._door_after_jog = False
            self._hold_complete = True
            self._door_stopped(t)
        elif self.state == "Jog":
            self._set_state(t, "Idle")

    def _door_event(self, t: float) -> None:
        """The door opened: stop like a feed hold, then cut spindle and coolant."""
        self._door_ajar = True
        if self.state in ("Alarm", "Check", "Sleep", "Home"):
            return
        if self.state == "Door":
            if self._restore_until < math.inf:  # reopened while restoring: stop again
                self._restore_until = math.inf
                self._door_stopped(t)
            else:
                self._set_state(t, "Door")
            return
        if self.state == "Jog":  # Grbl cancels the jog (still Jog), then enters the door
            self._cancel_jog(t)
            self._door_after_jog = True
        elif self.state == "Run":
            self._decelerate(t, "Door")
        elif self._hold_complete or self.state == "Idle":
            self._hold_complete = True
            self.state = "Door"
            self._door_stopped(t)
            self._suspend_dwell(t)
        else:  # Hold:1: the hold under way finishes as the door's stop
            self._set_state(t, "Door")

    def _door_stopped(self, t: float) -> None:
        """Motion stopped behind an open door: spindle and coolant off (restored on resume)."""
        if self._spindle != "M5" or self._coolant:
            self._door_saved = (self._spindle, self._spindle_speed, self._coolant)
            self._spindle, self._spindle_speed, self._coolant = "M5", 0.0, frozenset()
            self._log(t, "spindle", spindle="M5", s=0.0)
        self._set_state(t, "Door", force=True)

    def _door_restore(self, t: float) -> None:
        """Cycle start in ``Door:0``: spin up (``Door:3``), then resume."""
        if not self._hold_complete or self._door_ajar or self._restore_until < math.inf:
            return  # Door:1, Door:2 or already restoring: Grbl ignores it
        spindle, _, coolant = self._door_saved
        delay = (DOOR_SPINDLE_DELAY if spindle != "M5" else 0.0) + (
            DOOR_COOLANT_DELAY if coolant else 0.0
        )
        self._restore_until = t + delay * self.options.time_scale
        self._set_state(t, "Door")

    def _door_resume(self, t: float) -> None:
        spindle, speed, coolant = self._door_saved
        self._door_saved = ("M5", 0.0, frozenset())
        if spindle != "M5" or coolant:
            self._spindle, self._spindle_speed, self._coolant = spindle, speed, coolant
            self._log(t, "spindle", spindle=spindle, s=speed)
        self._hold_complete = False
        if self._planner:
            self._start_motion(t)
            self._set_state(t, "Jog" if self._jogging else "Run")
        else:
            self._set_state(t, "Idle")
            self._resume_dwell(t)

    def _suspend_dwell(self, t: float) -> None:
        """A hold or door while Grbl dwells: the dwell's count stops (its suspend loop).

        Grbl's ``delay_sec`` runs the realtime loop between its 50 ms steps, so a hold
        suspends the dwell there; the emulator stops it at the hold's instant.
        """
        p = self._pending
        if p is not None and p.dwell_left < 0.0 and p.until > t and not p.planning:
            if p.actions[p.index - 1].kind == "dwell":
                p.dwell_left = p.until - t
                p.until = math.inf

    def _resume_dwell(self, t: float) -> None:
        """The cycle start after a hold or door: a suspended dwell runs what it had left."""
        p = self._pending
        if p is not None and p.dwell_left >= 0.0:
            p.until = t + p.dwell_left
            p.dwell_left = -1.0

    def _main(self, t: float) -> None:
        """Grbl's ``protocol_main_loop``, then its realtime point when it runs dry or waits.

        Grbl starts a cycle only when its serial input runs dry, the planner is full or a
        line waits for the planner to empty (``protocol_auto_cycle_start``); a status
        request pending at that point is served first, so it still says Idle.
        """
        self._main_loop(t)
        if self._pending is not None and self._pending.planning:
            return
        self._serve_due_report(t)
        self._auto_cycle_start(t)

    def _serve_due_report(self, t: float) -> None:
        if self._report_due:
            self._report_due = False
            if not self._critical and self.state != "Home":
                self._emit(t, self._status_report(t))

    def _auto_cycle_start(self, t: float) -> None:
        if self._wire and self._wire[0][0] <= t:
            return  # bytes arriving at this instant are in the RX buffer: not run dry yet
        if self.state == "Idle" and self._planner and not self._critical:
            self._start_motion(t)
            self._set_state(t, "Jog" if self._jogging else "Run")

    def _main_loop(self, t: float) -> None:
        """Move characters into the line buffer and run lines until input or Grbl waits.

        Grbl's suspend loop (``protocol_exec_rt_suspend``) runs while a door is handled, a
        cancelled jog stops (``SUSPEND_JOG_CANCEL``, set at once) or a hold is complete
        (``Hold:0``, also M0's): no line is parsed or carried on meanwhile, and M0's ``ok``
        comes after the cycle start. While a hold decelerates (``Hold:1``) lines are still
        read and planned, up to a full planner.
        """
        while not self._critical and self._reset_at == math.inf and self._boot_at == math.inf:
            if (
                self._soft_limit
                or self.state == "Door"
                or self._jog_cancel
                or (self.state == "Hold" and self._hold_complete)
            ):
                return
            if self._pending is not None:
                if not self._step_pending(t):
                    return
                continue
            if not self._rx:
                return
            c = chr(self._rx.popleft())
            if c in "\r\n":
                self._end_of_line(t)
            elif self._comment:
                if self._comment == "(" and c == ")":
                    self._comment = ""
            elif c <= " " or c == "/":
                continue
            elif c in "(;":
                self._comment = c
            elif len(self._line) >= LINE_BUFFER_SIZE - 1:
                self._overflow = True
            else:
                self._line.append(c.upper())

    def _end_of_line(self, t: float) -> None:
        line = "".join(self._line)
        overflow = self._overflow
        self._line.clear()
        self._comment = ""
        self._overflow = False
        self._lines += 1
        n = self._lines
        gcode = 0
        if line and not line.startswith("$") and not overflow:
            self._gcode_lines += 1
            gcode = self._gcode_lines
        self._log(t, "rx", n=n, g=gcode, text=line)
        if gcode and gcode == self.options.disconnect_after:
            self._drop_link(t)
            if self.options.usb_powered:
                return  # powered off: this line never runs
        if gcode and gcode == self.options.reset_after:
            self._reset_at = t
        if overflow:
            self._respond(t, n, gcode, "error:11")
        elif not line:
            self._respond(t, n, gcode, "ok")
        elif line.startswith("$"):
            self._system(t, n, line)
        elif self.state in ("Alarm", "Jog"):
            self._respond(t, n, gcode, "error:9")
        elif gcode == self.options.error_at:
            self._respond(t, n, gcode, f"error:{self.options.error_code}")
        else:
            self._gcode(t, n, gcode, line)

    def _gc_settings(self) -> Settings:
        s = self.settings
        return Settings(
            max_rate=(s[110], s[111], s[112]),
            max_travel=(s[130], s[131], s[132]),
            soft_limits=bool(s[20]),
            arc_tolerance=s[12],
            laser_mode=bool(s[32]),
            coord_offsets=list(self._offsets),
            g28=self.g28,
            g30=self.g30,
        )

    def _gcode(self, t: float, n: int, gcode: int, line: str) -> None:
        try:
            outcome = interpret(line, self._gc, self._gc_settings())
        except GcodeError as exc:
            self._respond(t, n, gcode, f"error:{exc.code}")
            return
        if outcome.soft_limit and self.state == "Check":
            self._soft_limit_alarm(t)  # mc_line checks soft limits even in check mode
            return
        wco = self._wco()
        self._offsets = outcome.coord_offsets
        self._gc = outcome.state
        if self._wco() != wco:
            self._wco_counter = 0  # system_flag_wco_change(): WCO in the next report
        if self.state == "Check":
            self._respond(t, n, gcode, "ok")
            return
        self._pending = _Pending(n, gcode, outcome.actions)

    def _wco(self) -> tuple[float, float, float]:
        off = self._offsets[self._gc.coord_index]
        g92 = self._gc.g92
        return (off[0] + g92[0], off[1] + g92[1], off[2] + g92[2] + self._gc.tlo)

    def _step_pending(self, t: float) -> bool:
        """Run the pending line's next action; False while Grbl would be blocked."""
        p = self._pending
        assert p is not None
        if p.until > 0.0:
            return False
        if p.index >= len(p.actions):
            self._pending = None
            if p.response:
                self._respond(t, p.line, p.gcode, p.response)
            self._serve_due_report(t)  # the next realtime point: after the ok
            return True
        act = p.actions[p.index]
        if act.outside and not self._jogging:
            # mc_line's limits_soft_check, before it waits for a free block: in a cycle a
            # feed hold first (the alarm once stopped, _stopped), else the alarm at once
            if self.state == "Run":
                self._soft_limit = True
                self._decelerate(t, "Hold")
            else:
                self._soft_limit_alarm(t)
            return False
        if act.kind == "motion":
            # Grbl's mc_line waits for a free block, then drops a move of no step, which so
            # takes none
            if not self._block_free(t):
                return False
            self._plan(t, act, p.line)
            p.index += 1
            if self._planner[-1].length <= 0.0 and self.settings[32] and self._gc.spindle == "M3":
                # mc_line: a dropped move under M3 in laser mode syncs (spindle_sync)
                p.actions.insert(p.index, Action("sync"))
            if self.options.plan_time > 0.0 and self._planner[-1].length > 0.0:
                # plan_buffer_line returns PLAN_EMPTY_BLOCK before any planning
                p.until = t + self.options.plan_time
                p.planning = True
                return False
            return True
        laser_free = act.kind == "spindle" and act.free
        if not laser_free and (self._planner or self.state in ("Run", "Jog")):
            return False
        if act.kind == "spindle":
            self._spindle = act.spindle
            self._spindle_speed = act.speed if act.spindle != "M5" else 0.0
            self._log(t, "spindle", spindle=self._spindle, s=self._spindle_speed)
        elif act.kind == "coolant":
            self._coolant = self._gc.coolant
        elif act.kind in ("dwell", "home"):
            p.index += 1
            if act.kind == "home":
                self._set_state(t, "Home")
            until = t + act.seconds * self.options.time_scale
            if until > t:
                p.until = until
                return False
            return True
        elif act.kind == "pause":
            self._hold_complete = True
            self._set_state(t, "Hold")
        elif act.kind == "end":
            self._spindle = "M5"
            self._spindle_speed = 0.0
            self._coolant = frozenset()
            self._emit(t, "[MSG:Pgm End]\r\n")
        elif act.kind == "homed":
            pull = self.settings[27]
            self.mpos = self._on_grid((-pull, -pull, -pull))  # limits_go_home: lround
            self._gc.position = self.mpos
            self._set_state(t, "Idle")
        p.index += 1
        return True

    def _plan(self, t: float, act: Action, line: int) -> None:
        """Grbl's ``plan_buffer_line``: queue the move, then re-plan the running one.

        A move's rate and acceleration limits and its junction speed with the move before
        (none when the planner is empty: it starts from rest) are fixed here, as in Grbl.
        """
        start = self._planner[-1].end if self._planner else self.mpos
        end = self._on_grid(act.target)
        s = self.settings
        rates = (s[110], s[111], s[112])
        accels = (s[120], s[121], s[122])
        delta = (end[0] - start[0], end[1] - start[1], end[2] - start[2])  # from whole steps
        length, u, limit, accel = one_move_limits(delta, rates, accels)
        if end == start:
            length = 0.0  # no step on any axis: Grbl drops it (PLAN_EMPTY_BLOCK)
        before = next((b for b in reversed(self._planner) if b.length > 0), None)
        corner_sq = 0.0
        if before is not None and length > 0:
            corner_sq = one_corner_speed_sq(before.unit, u, accels, s[11])
        wco = self._wco()
        frm = self._planner[-1].target if self._planner else self._resting_target()
        to = act.target
        self._planner.append(
            _Block(
                start=start,
                end=end,
                target=act.target,
                rate=limit * 60.0 if act.rapid else act.rate,
                limit=limit * 60.0,
                rapid=act.rapid,
                jog=self._jogging,
                line=line,
                work_start=(frm[0] - wco[0], frm[1] - wco[1], frm[2] - wco[2]),
                work_end=(to[0] - wco[0], to[1] - wco[1], to[2] - wco[2]),
                spindle=self._spindle,
                length=length,
                unit=u,
                accel=max(accel, 1e-9),  # $120=0: a machine that barely moves
                corner_sq=corner_sq,
            )
        )
        block = self._planner[-1]
        block.least = self._least(block)
        block.seen = False
        self._defer(t, "block", block)  # planner_recalculate: st_update_plan_block_parameters
        if self.state == "Idle" and self._jogging:
            # a jog starts at once (jog_execute); other motion waits for the auto cycle start
            self._start_motion(t)
            self._set_state(t, "Jog")

    def _running(self) -> bool:
        """The head block moves: a cycle or jog, or a hold, door or jog cancel stopping it."""
        return bool(self._planner) and (
            self._stopping or self._stop_due or self.state in ("Run", "Jog")
        )

    def _blocks(self) -> int:
        """Planner blocks queued; a move of no whole step takes none (Grbl drops it)."""
        return sum(1 for b in self._planner if b.length > 0.0)

    def _block_free(self, t: float) -> bool:
        """Whether the planner has a free block at ``t`` for a line that waits for one.

        Grbl frees a block once ``st_prep_buffer`` has prepared its last segment
        (``plan_discard_current_block``: 40-50 ms before it ends, sooner for short blocks),
        not when it ends. Waiting, the line looks again when the next block frees
        (``_wake_at``), found again after a change of the plan that the copies finding it
        did not run (a new block, override, stop or start: :meth:`_schedule`, :meth:`_run_on`).
        """
        if self._blocks() < PLANNER_BLOCKS:
            return True
        if self._free_at is None:
            self._free_at = self._next_free(t, self._blocks() - PLANNER_BLOCKS + 1)
        self._wake_at = self._free_at if self._free_at > t else math.inf
        return t >= self._free_at

    def _head_progress(self, t: float) -> tuple[float, float]:
        """Distance (mm) into the head's current profile and its speed (mm/s) at ``t``."""
        if not self._running():
            return 0.0, 0.0
        head = self._planner[0]
        scale = self.options.time_scale
        if scale <= 0.0 or head.span <= 0.0:  # no time passes, or nothing to run
            return 0.0, head.v0
        return profile_at(
            (t - self._head_start) / scale, head.span, head.v0, head.v1, head.vmax, head.accel
        )

    def _prepared_speed(self, t: float) -> tuple[float, int]:
        """The speed (mm/s) where the segments prepared by ``t`` end, and the blocks freed.

        The speed is Grbl's ``FS:`` rate: ``st_get_realtime_rate`` reports
        ``prep.current_speed``, the speed at the end of the last segment ``st_prep_buffer``
        prepared (5 with the one running: 40-50 ms ahead; 0 once the profile to a stop or the
        end is all prepared). The blocks are those whose segments are all prepared (Grbl has
        discarded them: free in ``Bf:``). Found by running a copy of the motion on, changes
        still deferred acting as they will.
        """
        if not self._running() or self.options.time_scale <= 0.0:
            return self._head_progress(t)[1], 0
        most = self._ends(self._seg_last, t)[0] + SEGMENTS_PREPARED
        count, last = self._ends(self._seg_last, math.inf, most)
        if count == most and last <= self._land_at and last < self._head_end():
            return self._head_progress(last)[1], 0  # within the head's profile as it is
        time_speed, freed, _, _ = self._ahead(most, math.inf)
        return (time_speed[1] if time_speed else 0.0), freed

    def _next_free(self, t: float, blocks: int) -> float:
        """When the first ``blocks`` queued blocks have all their segments prepared (inf: never).

        A block's last segment is prepared 5 segment ends (the buffer, the running one
        included) before it ends: when the segment 5 ends earlier has run.
        """
        if not self._running() or self.options.time_scale <= 0.0:
            return math.inf
        head = self._planner[0]
        if blocks == 1 and head.length > 0.0 and head.span >= head.length - head.done:
            # the head's profile runs to its end: no copy needed unless a change lands first
            ends = self._ends(self._seg_last, self._head_end())[0]
            if ends <= SEGMENTS_PREPARED:
                return t
            free = self._ends(self._seg_last, math.inf, ends - SEGMENTS_PREPARED)[1]
            if free < self._land_at:
                return free
        _, freed, ends, tail = self._ahead(math.inf, blocks)
        if freed < blocks:
            return math.inf  # a stop comes first
        if tail is not None:
            return tail
        if ends <= SEGMENTS_PREPARED:
            return t  # prepared since the head's run started
        time_speed = self._ahead(ends - SEGMENTS_PREPARED, math.inf)[0]
        return time_speed[0] if time_speed else t

    def _ahead(
        self, most: float, blocks: float
    ) -> tuple[tuple[float, float] | None, int, int, float | None]:
        """Run a copy of the motion on to a segment end or the end of some blocks.

        To the ``most``-th segment end after ``_seg_last``, or until ``blocks`` blocks ran
        to their end, whichever comes first.

        Returns:
            The time and speed at that segment end (None: the motion stopped or ended before),
            the blocks of motion that ran to their end by then (one ending there included),
            the segment ends counted and, when the last of ``blocks`` ended, the time of the
            segment end 5 before its end where its last profile has it (else None).
        """
        ahead = _clone(self)
        queued = {id(b): _clone(b) for b in self._planner}
        ahead._planner = collections.deque(queued[id(b)] for b in self._planner)
        ahead._deferred = [
            [n, kind, queued.get(id(what), what)] for n, kind, what in self._deferred
        ]
        ahead._gc = _clone(self._gc)
        ahead.record = []
        ahead.link_up = False  # it says nothing
        found: list[tuple[float, float]] = []
        ends = 0
        if most < math.inf:
            ahead._deferred.append([most, "probe", found])
            ahead._schedule()
        freed = 0
        tail = None
        while not found and freed < blocks:
            end = ahead._head_end()
            landing = ahead._land_at
            if min(end, landing) == math.inf:
                break  # stopped or ended: the profile is all prepared
            stretch = ahead._ends(ahead._seg_last, min(end, landing))[0]
            ends += stretch
            if landing < end:
                ahead._segment_end(landing)
            else:
                head = ahead._planner[0]
                whole = head.length > 0.0 and head.span >= head.length - head.done
                if whole and freed + 1 == blocks and stretch > SEGMENTS_PREPARED:
                    tail = ahead._ends(ahead._seg_last, end, stretch - SEGMENTS_PREPARED)[1]
                ahead._finish_head(end)
                freed += whole
        return (found[0] if found else None), freed, ends, tail

    def _cruise(self, block: _Block) -> float:
        """A block's nominal speed (mm/s) under the overrides (``plan_compute_profile_nominal_speed``).

        At least Grbl's ``MINIMUM_FEED_RATE`` (1 mm/min); a jog takes no feed override.
        """
        if block.rapid:
            rate = block.limit * self._planned_overrides[1] / 100.0
        else:
            feed = 100 if block.jog else self._planned_overrides[0]
            rate = min(block.rate * feed / 100.0, block.limit)
        return max(rate, 1.0) / 60.0

    def _replan(self, t: float) -> None:
        """Re-plan the head block as Grbl's ``planner_recalculate`` does on a new block.

        The head, if it runs, goes on from where it is at the speed it has (Grbl's
        ``st_update_plan_block_parameters``); else from rest.
        """
        if not self._planner:
            return
        entry = 0.0
        if self._running():
            head = self._planner[0]
            ran, entry = self._head_progress(t)
            head.done = min(head.done + ran, head.length)
            self._head_start = t
        self._plan_head(entry)

    def _plan_head(self, entry: float) -> None:
        """The head block's profile from ``entry`` (mm/s) over what is left of it.

        Look-ahead covers only the blocks queued now, the newest ending at rest (a planner
        that runs short slows down), by the ETA's model (:mod:`scratchfab.toolpath.timing`).
        A head entered faster than it may now go (a lowered override) slows down at its
        acceleration; where the block is too short for that, it slows down all along it and
        the next block enters at the speed left (Grbl's deceleration-only profile,
        ``PREP_FLAG_DECEL_OVERRIDE``). While a hold, door or jog cancel stops the machine,
        the head only slows down, at its acceleration, to a stop within it or through it
        into the next block (``STEP_CONTROL_EXECUTE_HOLD``).
        """
        head = self._planner[0]
        head.vmax = self._cruise(head)
        left = head.length - head.done
        head.v0 = entry
        head.span = 0.0
        head.duration = 0.0
        if left <= 0.0:  # nothing left, or a move Grbl drops: passed at the speed it has
            head.v1 = entry
            self._schedule()
            return
        shed = 2.0 * head.accel * left  # the speed^2 the head can shed (or gain) over it
        if self._stopping:
            head.vmax = entry
            exit_sq = entry * entry - shed
            head.span = left if exit_sq > 0.0 else min(left, entry * entry / (2.0 * head.accel))
        else:
            later = []
            speed = head.vmax
            for b in itertools.islice(self._planner, 1, None):
                if not b.seen:
                    break  # queued since the segments now prepared were
                if b.length > 0.0:
                    cruise = self._cruise(b)
                    later.append(
                        (min(b.corner_sq, speed * speed, cruise * cruise), 2.0 * b.accel * b.length)
                    )
                    speed = cruise
            exit_sq = max(exit_speed_sq(entry * entry, shed, later), entry * entry - shed)
            head.vmax = max(head.vmax, math.sqrt(max(exit_sq, 0.0)))  # deceleration only
            head.span = left
        head.v1 = math.sqrt(max(exit_sq, 0.0))
        if head.span > 0.0:
            seconds = one_profile_seconds(head.span, head.v0, head.v1, head.vmax, head.accel)
            head.duration = seconds * self.options.time_scale
        self._schedule()  # the segments follow the profile

    def _finish_head(self, t: float) -> None:
        """The head's profile ended: a stop inside the block (a hold), else the block ended."""
        head = self._planner[0]
        if head.span < head.length - head.done:
            head.done += head.span
            self._head_start = t
            self._stopped(t)
            return
        if head.length > 0.0:
            self._segment_end(t)  # its last segment ends with it (st_prep_buffer)
            if not self._planner or self._planner[0] is not head:
                return  # what acted there (a hold's stop at the block's end) took it on
        block = self._planner.popleft()
        self.mpos = block.end
        self._target = block.target
        self._start_motion(t)
        self._log(
            t,
            "exec",
            n=block.line,
            frm=_r(block.work_start),
            to=_r(block.work_end),
            rapid=block.rapid,
            spindle=block.spindle,
        )
        if self._planner:
            # queued once this block's segments were all prepared: its own come from there,
            # planned with what was queued then (st_prep_buffer loads it on its arrival)
            self._planner[0].seen = True
            self._plan_head(block.v1)
        elif self._stopping or self._stop_due:
            self._stopped(t)  # stopped at the end of the last block
        else:
            self._jogging = False
            self._clear_deferred()
            self._set_state(t, "Idle")

    def _start_motion(self, t: float) -> None:
        """The head block starts to run at ``t``: its profile and its segments start there."""
        self._head_start = t
        self._seg_origin = t
        self._seg_last = t
        self._schedule()

    def _ends(self, frm: float, until: float, most: float = math.inf) -> tuple[int, float]:
        """How many of the head's segment ends come after ``frm`` (one) up to ``until``.

        At most ``most`` of them; also the last one's time.

        ``st_prep_buffer`` ends a segment after 10 ms (``DT_SEGMENT``), or more 10 ms where
        that is less than ``REQ_MM_INCREMENT_SCALAR`` (1.25) steps of the block (slow
        moves, a start from rest: its "very slow segments" rule), and at the profile's end.
        The speed of a profile is least at the ends of any span of it, so where both ends
        are fast enough (1.25 steps in 10 ms of the machine's own time, ``time_scale`` aside)
        the 10 ms segments are counted at once (the last grid point fast enough found by
        bisection: the speed rises, then falls).
        """
        head = self._planner[0]
        scale = self.options.time_scale
        dt = SEGMENT_SECONDS * scale
        end = self._head_start + head.duration
        need = head.least

        def at(t: float) -> tuple[float, float]:
            if head.span <= 0.0:
                return 0.0, head.v0
            return profile_at(
                (min(t, end) - self._head_start) / scale,
                head.span,
                head.v0,
                head.v1,
                head.vmax,
                head.accel,
            )

        k = math.floor((frm - self._seg_origin) / dt + 1e-9)
        count, last = 0, frm
        done, speed = at(last)
        while count < most:
            stop = min(until, end)
            far = math.floor((stop - self._seg_origin) / dt + 1e-9)  # the last whole grid point
            if far > k + 1 and speed * SEGMENT_SECONDS >= need:
                if at(self._seg_origin + far * dt)[1] * SEGMENT_SECONDS < need:
                    # the speed rises, then falls: the grid points fast enough lead the span
                    lo, hi = k, far
                    while hi - lo > 1:
                        mid = (lo + hi) // 2
                        if at(self._seg_origin + mid * dt)[1] * SEGMENT_SECONDS >= need:
                            lo = mid
                        else:
                            hi = mid
                    far = lo
                jump = min(far - k - 1, int(min(most - count, 1e9)) - 1)
                if jump > 0:  # all 10 ms segments: to one before the far point at once
                    k += jump
                    count += jump
                    last = self._seg_origin + k * dt
                    done, speed = at(last)
                    continue
            k += 1
            point = self._seg_origin + k * dt
            if point >= end - 1e-12 * max(1.0, abs(end)):
                point = end
            if point > until + 1e-12 * max(1.0, abs(until)):
                break
            mm, v = at(point)
            if point == end or mm - done >= need * (1.0 - 1e-9):
                count, last, done, speed = count + 1, point, mm, v
            if point == end:
                break
        return count, last

    def _least(self, block: _Block) -> float:
        """The mm of 1.25 of a block's step events (``REQ_MM_INCREMENT_SCALAR``)."""
        a, b = self._to_steps(block.start), self._to_steps(block.end)
        events = max(abs(q - p) for p, q in zip(a, b, strict=True))
        return 1.25 * block.length / events if events and block.length > 0.0 else 0.0

    def _schedule(self) -> None:
        """When the first deferred change acts, if the head's segments run on to it.

        The plan changed (or may have): when a block frees is found again.
        """
        self._free_at = None
        self._land_at = math.inf
        if self._deferred and self._running():
            left = min(item[0] for item in self._deferred)
            count, last = self._ends(self._seg_last, math.inf, left)
            if count >= left:
                self._land_at = last

    def _defer(self, t: float, kind: str, what: Any = None) -> None:
        """A stop, re-plan or new block that takes effect once the prepared segments ran.

        Grbl's ``st_update_plan_block_parameters`` re-plans from the end of the segment
        buffer (``prep.current_speed``): the segments already prepared (``st_prep_buffer``
        keeps 5, the one running included; 10 ms each, longer at slow speeds, shorter where
        a block ends) run as they were, so a hold, override or new block acts 40-50 ms later
        than it came. Not moving, or with no time passing (``time_scale`` 0), it acts at once.
        """
        if not self._running() or self.options.time_scale <= 0.0:
            self._apply_deferred(t, kind, what)
            return
        left = SEGMENTS_PREPARED + self._ends(self._seg_last, t)[0]
        self._deferred.append([left, kind, what])
        self._schedule()

    def _segment_end(self, t: float) -> None:
        """Count the segment ends up to ``t`` (a segment's end, or the head's end).

        Deferred changes whose segments have run act, in the order they came.
        """
        if not self._deferred:
            self._seg_last = t
            return
        passed = self._ends(self._seg_last, t)[0]
        if t >= self._land_at:  # the landing itself counts, whatever the clock's rounding
            passed = max(passed, min(item[0] for item in self._deferred))
        self._seg_last = t
        if passed <= 0:
            return
        due = []
        for item in self._deferred:
            item[0] -= passed
            if item[0] <= 0:
                due.append(item)
        self._deferred = [item for item in self._deferred if item[0] > 0]
        self._schedule()
        for _, kind, what in due:
            self._apply_deferred(t, kind, what)

    def _apply_deferred(self, t: float, kind: str, what: Any = None) -> None:
        """A deferred change acts: an override's or new block's re-plan, or the stop."""
        if kind == "probe":
            what.append((t, self._head_progress(t)[1]))
            return
        if kind in ("replan", "block"):
            if kind == "replan":
                self._planned_overrides = what
            else:
                what.seen = True
            self._replan(t)
            return
        moving = self._running()
        ran, speed = self._head_progress(t)
        self._stop_due = False
        if moving:
            head = self._planner[0]
            head.done = min(head.done + ran, head.length)
            self._head_start = t
        self._stopping = True
        if moving:
            self._plan_head(speed)
        else:
            self._stopped(t)  # nothing moves

    def _clear_deferred(self) -> None:
        """Nothing waits on the segments (stopped, reset): the plan takes in all from now on."""
        self._planned_overrides = self._overrides[:2]
        self._deferred = []
        self._land_at = math.inf
        self._free_at = None
        self._stop_due = False
        for block in self._planner:
            block.seen = True

    def _decelerate(self, t: float, state: str) -> None:
        """A hold, door or jog cancel: the head slows down to a stop (:meth:`_defer`).

        Grbl's protocol sets the state and ``STEP_CONTROL_EXECUTE_HOLD`` at once, and its
        stepper decelerates from the end of the segments already prepared; the ``state``
        (``Hold:1``, ``Door:2`` or ``Jog``) holds until :meth:`_stopped`.
        """
        moving = self._running()
        self._hold_complete = False
        self._set_state(t, state)
        self._stop_due = moving
        self._defer(t, "stop")

    def _stopped(self, t: float) -> None:
        """The hold's deceleration ended: ``Hold:0``, the door's stop or the jog's flush.

        Grbl's ``plan_cycle_reinitialize``: the rest of the head is planned from rest. It
        keeps the exact mm left (``st_prep_buffer`` sets ``pl_block->millimeters`` to where
        the forced deceleration ended, on no step) and the whole steps left
        (``prep.steps_remaining``): the resume's profile covers those mm, the position
        counts the steps (:meth:`_position`).
        """
        self._stopping = False
        self._clear_deferred()
        if self._jog_cancel:
            self._end_jog(t)
            return
        if self._soft_limit:  # protocol.c's cycle stop with sys.soft_limit: Idle, then reset
            self._stop_head(t)
            self._set_state(t, "Idle")
            self._soft_limit_alarm(t)
            return
        self._hold_complete = True
        if self._planner:
            self._plan_head(0.0)
        if self.state == "Door":
            self._door_stopped(t)
        elif self.state == "Hold":
            self._set_state(t, "Hold")

    def _steps_per_mm(self) -> tuple[float, float, float]:
        s = self.settings
        return (s[100], s[101], s[102])

    def _to_steps(
        self, p: tuple[float, float, float], per_mm: tuple[float, float, float] | None = None
    ) -> tuple[int, int, int]:
        """A position in whole steps (``plan_buffer_line``'s ``lround(target * steps_per_mm)``).

        ``per_mm``: other steps/mm than ``$100``-``$102`` (those the position was counted in).
        """
        k = per_mm or self._steps_per_mm()
        return (_lround(p[0] * k[0]), _lround(p[1] * k[1]), _lround(p[2] * k[2]))

    def _from_steps(self, n: tuple[int, int, int]) -> tuple[float, float, float]:
        """Steps in mm (``system_convert_axis_steps_to_mpos``; an axis of no steps/mm: 0)."""
        k = self._steps_per_mm()
        x, y, z = (a / b if b > 0 else 0.0 for a, b in zip(n, k, strict=True))
        return (x, y, z)

    def _on_grid(self, p: tuple[float, float, float]) -> tuple[float, float, float]:
        """``p`` rounded to whole steps on each axis: where Grbl's motors can stand."""
        return self._from_steps(self._to_steps(p))

    def _resting_target(self) -> tuple[float, float, float]:
        """Where the machine stands as programmed: the last target, unless it since moved."""
        return self._target if self._on_grid(self._target) == self.mpos else self.mpos

    def _position(self, t: float) -> tuple[float, float, float]:
        """Grbl's ``sys_position``: the steps its stepper interrupt has taken so far, in mm.

        The head block's ``count`` step events (the most steps of an axis) run in segments
        whose first interrupt tick comes where the exact distance left is a whole number of
        steps (``st_prep_buffer`` carries the partial step's time, ``dt_remainder``) and runs
        an event at once: while moving, event ``k`` has run from ``k - 1`` events' distance
        on, up to the events the stepper gets (``count``, or ``count - ceil(steps left)``
        where a hold ends inside the block); at rest ``count - ceil(steps left)`` have run.
        Below 8 kHz AMASS splits an event into 2, 4 or 8 ticks (the segment's level:
        :meth:`_segment_level`), its Bresenham counters scaled by 8 (``stepper.c``'s ISR:
        each axis's counter starts at half the events, adds its steps each tick and steps
        the axis when it exceeds the events), so a minor axis may step within an event
        before the major one does.
        A report so leads the distance run, as Grbl's does (the interrupt counts a step on
        the tick that decides it; its pulse goes out on the next): the major axis's step
        ``k`` counts once ``k - 1`` events ran (``k - 1/2`` under AMASS), not at ``k``.
        """
        if not self._planner:
            return self.mpos
        head = self._planner[0]
        ran, speed = self._head_progress(t)
        a, b = self._to_steps(head.start), self._to_steps(head.end)
        count = max(abs(q - p) for p, q in zip(a, b, strict=True))
        if count == 0 or head.length <= 0.0:
            return head.start
        per_mm = count / head.length
        events = (head.done + ran) * per_mm
        whole = min(count, max(0, math.floor(events + 1e-9)))
        level, ticks = 0, whole
        if speed > 0.0 and self._running() and self.options.time_scale > 0.0:
            left = head.length - head.done
            last = count if head.span >= left else math.floor((head.done + head.span) * per_mm)
            level = self._segment_level(t, per_mm)
            ticks = max(
                whole << level,
                min(math.floor(events * (1 << level) + 1e-9) + 1, max(last, 0) << level),
            )
        n, j = divmod(ticks, 1 << level)
        now = tuple(
            p
            + int(
                math.copysign(
                    (4 * count + (8 * n + (j << (3 - level))) * abs(q - p) - 1) // (8 * count),
                    q - p,
                )
            )
            for p, q in zip(a, b, strict=True)
        )
        return self._from_steps(now)  # type: ignore[arg-type]

    def _segment_level(self, t: float, per_mm: float) -> int:
        """The AMASS level of the head's segment running at ``t`` (:func:`_amass_level`).

        ``st_prep_buffer`` picks it per segment from the segment's step rate (its events
        over its time), not from the speed of the instant: a segment accelerating through
        a level's rate runs at one level all along.
        """
        start = self._ends(self._seg_last, t)[1]
        stop = self._ends(start, math.inf, 1)[1]
        if stop <= start:  # the profile's end: no segment after it
            return _amass_level(self._head_progress(t)[1] * per_mm)
        mm = self._head_progress(stop)[0] - self._head_progress(start)[0]
        return _amass_level(mm * per_mm * self.options.time_scale / (stop - start))

    # ------------------------------------------------------------------ resets and alarms

    def _power_up(self, t: float) -> None:
        if self.settings[22] and self.settings[20] and self.options.homed:
            pull = self.settings[27]
            self.mpos = self._on_grid((-pull, -pull, -pull))
            self.state = "Idle"
        elif self.settings[22]:
            self.state = "Alarm"
        self._log(t, "power")
        self._restart(t)

    def _restart(self, t: float) -> None:
        """Grbl's ``main()`` loop after a reset: banner, then the alarm lock or startup lines.

        Grbl clears its ``sys`` struct here, report counters included, so the first status
        report after any reset carries ``WCO:`` and ``Ov:``.
        """
        self._gc = ModalState(position=self.mpos)
        self._wco_counter = 0
        self._ovr_counter = 0
        self._emit(t, f"\r\n{self.options.banner}\r\n" if self.options.banner else BANNER)
        if self.state == "Alarm":
            self._emit(t, "[MSG:'$H'|'$X' to unlock]\r\n")
        else:
            self.state = "Idle"
            for text in self.startup_lines:
                if text:
                    try:
                        out = interpret(text, self._gc, self._gc_settings())
                        self._gc = out.state
                        self._emit(t, f">{text}:ok\r\n")
                    except GcodeError as exc:
                        self._emit(t, f">{text}:error:{exc.code}\r\n")
        self._set_state(t, self.state, force=True)
        if self._door_ajar and self.state == "Idle":  # Grbl checks the door switch at init
            self._hold_complete = True
            self._set_state(t, "Door")

    def _power_off(self, t: float) -> None:
        """Lose power: the head block stops part-way and nothing else runs."""
        self._stop_head(t)
        self._planner.clear()
        self._rx.clear()
        self._wire.clear()
        self._pending = None
        self._boot_at = self._reset_at = self._restore_until = math.inf
        self._stopping = False
        self._clear_deferred()
        self._spindle = "M5"
        self._set_state(t, "Idle")
        self._log(t, "power_off")

    def _stop_head(self, t: float) -> None:
        """Log the part of the head block done by now and move there (it stops now)."""
        if self._planner:
            pos = self._position(t)
            head = self._planner[0]
            if pos != head.start:
                wco = self._wco()
                self._log(
                    t,
                    "partial",
                    n=head.line,
                    frm=_r(head.work_start),
                    to=_r((pos[0] - wco[0], pos[1] - wco[1], pos[2] - wco[2])),
                    rapid=head.rapid,
                    spindle=head.spindle,
                )
            self.mpos = pos

    def _soft_reset(self, t: float, from_command: bool) -> None:
        moving = self.state in ("Run", "Jog", "Home") or (
            self.state in ("Hold", "Door") and not self._hold_complete
        )
        self._stop_head(t)
        self._planner.clear()
        self._rx.clear()
        self._line.clear()
        self._comment = ""
        self._overflow = False
        self._pending = None
        self._report_due = False
        self._stopping = False
        self._soft_limit = False
        self._hold_complete = False
        self._restore_until = math.inf
        self._door_saved = ("M5", 0.0, frozenset())
        self._jog_cancel = False
        self._door_after_jog = False
        self._jogging = False
        self._spindle = "M5"
        self._spindle_speed = 0.0
        self._coolant = frozenset()
        self._overrides = [100, 100, 100]
        self._clear_deferred()
        self._log(t, "reset", command=from_command)
        if self._critical:
            self._critical = False
            self.state = "Alarm"
        elif moving:
            self.state = "Alarm"
            self._emit(t, "ALARM:3\r\n")
            self._log(t, "alarm", code=3)
        elif self.state != "Alarm":
            self.state = "Idle"
        self._restart(t)

    def _soft_limit_alarm(self, t: float) -> None:
        """Grbl's ``limits_soft_check`` after any hold: ``mc_reset``, then ``ALARM:2``, locked.

        Not in a cycle (a hold decelerating, blocks queued but not started) the machine
        stops where it is: ``mc_reset`` sees ``STEP_CONTROL_EXECUTE_HOLD``, kills the
        steppers (``st_go_idle``, "position has likely been lost") and sets
        ``EXEC_ALARM_ABORT_CYCLE``, which ``limits_soft_check`` then overwrites with
        ``EXEC_ALARM_SOFT_LIMIT`` (``system_set_exec_alarm`` assigns): the sender sees
        ``ALARM:2`` only, though the machine stopped at speed. The record's alarm says so
        (``lost``: the speed in mm/min it was stopped from). The queued blocks are lost.
        """
        speed = self._head_progress(t)[1] * 60.0
        if self.state in ("Run", "Jog", "Hold", "Door"):
            self._stop_head(t)
        self._planner.clear()
        self._stopping = False
        self._clear_deferred()
        self._soft_limit = False
        self._pending = None
        self._spindle = "M5"
        self._spindle_speed = 0.0
        self._critical = True
        self.state = "Alarm"
        self._emit(t, "ALARM:2\r\n")
        self._emit(t, "[MSG:Reset to continue]\r\n")
        if speed > 0.0:
            self._log(t, "alarm", code=2, lost=round(speed, 3))
        else:
            self._log(t, "alarm", code=2)

    def _set_state(self, t: float, state: str, force: bool = False) -> None:
        name = self._state_name()
        self.state = state
        if force or self._state_name() != name or self._last_state_logged != name:
            self._last_state_logged = self._state_name()
            self._log(t, "state", state=self._last_state_logged)

    def _state_name(self) -> str:
        if self.state == "Hold":
            return "Hold:0" if self._hold_complete else "Hold:1"
        if self.state == "Door":
            if self._restore_until < math.inf:
                return "Door:3"
            if not self._hold_complete:
                return "Door:2"
            return "Door:1" if self._door_ajar else "Door:0"
        return self.state

    # ------------------------------------------------------------------ output

    def _emit(self, t: float, text: str) -> None:
        if not self.link_up:
            return
        data = text.encode("ascii")
        start = max(t + self.options.latency, self._tx_free)
        done = start + len(data) * self._byte_time
        self._tx_free = done
        self._out.append((done, data))
        self._cond.notify_all()

    def _respond(self, t: float, n: int, gcode: int, response: str) -> None:
        self._log(t, "resp", n=n, g=gcode, r=response)
        if gcode and gcode == self.options.lose_ok_at:
            return
        self._emit(t + self.options.slow, response + "\r\n")

    def _log(self, t: float, event: str, **data: Any) -> None:
        self.record.append({"t": round(t, 6), "ev": event, **data})

    def _status_report(self, t: float) -> str:
        pos = self._position(t)
        wco = self._wco()
        inches = bool(self.settings[13])
        if not int(self.settings[10]) & 1:
            pos = (pos[0] - wco[0], pos[1] - wco[1], pos[2] - wco[2])
        fields_ = [
            self._state_name(),
            ("MPos:" if int(self.settings[10]) & 1 else "WPos:") + _fmt(pos, inches),
        ]
        speed, freed = self._prepared_speed(t)
        if int(self.settings[10]) & 2:
            free = PLANNER_BLOCKS - self._blocks() + freed
            fields_.append(f"Bf:{free},{RX_BUFFER_SIZE - len(self._rx)}")
        rate = speed * 60.0
        if inches:
            fields_.append(f"FS:{rate / MM_PER_INCH:.1f},{self._spindle_speed:.0f}")
        else:
            fields_.append(f"FS:{rate:.0f},{self._spindle_speed:.0f}")
        busy = self.state in ("Run", "Jog", "Hold", "Home", "Door")
        if self._wco_counter > 0:
            self._wco_counter -= 1
        else:
            self._wco_counter = (30 if busy else 10) - 1
            self._ovr_counter = max(self._ovr_counter, 1)
            if self.options.wco_field:
                fields_.append("WCO:" + _fmt(wco, inches))
        if self._ovr_counter > 0:
            self._ovr_counter -= 1
        else:
            self._ovr_counter = (20 if busy else 10) - 1
            fields_.append("Ov:{},{},{}".format(*self._overrides))
            acc = (
                ("S" if self._spindle == "M3" else "C" if self._spindle == "M4" else "")
                + ("F" if "M8" in self._coolant else "")
                + ("M" if "M7" in self._coolant else "")
            )
            if acc:
                fields_.append("A:" + acc)
        return "<" + "|".join(fields_) + ">\r\n"

    # ------------------------------------------------------------------ $ commands

    def _system(self, t: float, n: int, line: str) -> None:
        """Grbl's ``system_execute_line``: the ``$`` commands with their state rules."""
        state = self.state
        idle_or_alarm = state in ("Idle", "Alarm")
        reply = "ok"
        cmd = line[1:]
        if cmd == "":
            self._emit(
                t, "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]\r\n"
            )
        elif cmd == "$":
            if state in ("Run", "Hold"):
                reply = "error:8"
            else:
                for k, v in sorted(self.settings.items()):
                    self._emit(t, f"${k}={_fmt_setting(k, v)}\r\n")
        elif cmd == "G":
            self._emit(t, self._gc_report())
        elif cmd == "C":
            if state == "Check":
                self._emit(t, "[MSG:Disabled]\r\n")
                self._respond(t, n, 0, "ok")
                self._soft_reset(t, from_command=False)
                return
            if state != "Idle":
                reply = "error:8"
            else:
                self._set_state(t, "Check")
                self._emit(t, "[MSG:Enabled]\r\n")
        elif cmd == "X":
            if state == "Alarm":
                self._emit(t, "[MSG:Caution: Unlocked]\r\n")
                self._set_state(t, "Idle")
        elif cmd.startswith("J="):
            reply = self._jog(t, n, cmd[2:])
            if reply == "":
                return
        elif not idle_or_alarm:
            reply = "error:8"
        elif cmd == "#":
            inches = bool(self.settings[13])  # like GRBL's printFloat_CoordValue
            for k in range(6):
                self._emit(t, f"[G{54 + k}:{_fmt(self._offsets[k], inches)}]\r\n")
            self._emit(t, f"[G28:{_fmt(self.g28, inches)}]\r\n[G30:{_fmt(self.g30, inches)}]\r\n")
            tlo = _fmt((0.0, 0.0, self._gc.tlo) if self._grblhal else (self._gc.tlo,), inches)
            self._emit(t, f"[G92:{_fmt(self._gc.g92, inches)}]\r\n[TLO:{tlo}]\r\n")
            self._emit(t, f"[PRB:{_fmt((0.0, 0.0, 0.0), inches)}:0]\r\n")
        elif cmd == "I":
            opt = f"V,{PLANNER_BLOCKS},{RX_BUFFER_SIZE}" + (",3,0" if self._grblhal else "")
            self._emit(t, f"[VER:{VERSION}.{BUILD}:]\r\n[OPT:{opt}]\r\n")
            if self._grblhal:
                self._emit(t, "[FIRMWARE:grblHAL]\r\n")
        elif cmd == "N":
            for k, text in enumerate(self.startup_lines):
                self._emit(t, f"$N{k}={text}\r\n")
        elif cmd.startswith("N") and "=" in cmd and cmd[1:].split("=")[0] in ("0", "1"):
            index, text = cmd[1:].split("=", 1)
            self.startup_lines[int(index)] = text
        elif cmd == "H":
            if not self.settings[22]:
                reply = "error:5"
            else:
                self._pending = _Pending(n, 0, [Action("home", seconds=0.5), Action("homed")])
                return
        elif cmd == "SLP":
            self._set_state(t, "Sleep")
            self._emit(t, "[MSG:Sleeping]\r\n")
        elif cmd.startswith("RST="):
            what = cmd[4:]
            if what not in ("$", "#", "*"):
                reply = "error:3"
            else:
                if what in ("$", "*"):
                    steps = self._steps_per_mm()
                    self.settings = dict(DEFAULT_SETTINGS)
                    self._keep_steps(steps)
                if what in ("#", "*"):
                    self._offsets = [(0.0, 0.0, 0.0)] * 6
                    self.g28 = self.g30 = (0.0, 0.0, 0.0)
                self._emit(t, "[MSG:Restoring defaults]\r\n")
        elif "=" in cmd:
            reply = self._set_setting(cmd)
        else:
            reply = "error:3"
        self._respond(t, n, 0, reply)

    def _set_setting(self, cmd: str) -> str:
        key, _, raw = cmd.partition("=")
        if not key.isdigit():
            return "error:3"
        try:  # Grbl's read_float: sign, digits and a point (no exponent, nan or inf)
            value, end = read_number(raw, 0)
        except GcodeError:
            return "error:2"
        if end != len(raw):
            return "error:3"
        k = int(key)
        if k not in DEFAULT_SETTINGS:
            return "error:3"
        if value < 0:
            return "error:4"
        if k == 0 and value < 3:
            return "error:6"
        if k == 20 and value and not self.settings[22]:
            return "error:10"
        steps = self._steps_per_mm()
        self.settings[k] = int(value) if k in _INT_SETTINGS else value
        self._keep_steps(steps)
        return "ok"

    def _keep_steps(self, before: tuple[float, float, float]) -> None:
        """A ``$100``-``$102`` change keeps the step counts, so the positions in mm move.

        Grbl's ``settings_store_global_setting`` only stores the new steps/mm: the machine
        position (``sys_position``) and the planner's (``pl.position``) stay in steps and are
        reported as steps / ``$100`` (``system_convert_axis_steps_to_mpos``); the parser's
        position (``gc_state.position``, mm) stays as it was.
        """
        if before == self._steps_per_mm():
            return
        self.mpos = self._from_steps(self._to_steps(self.mpos, before))
        for block in self._planner:
            block.start = self._from_steps(self._to_steps(block.start, before))
            block.end = self._from_steps(self._to_steps(block.end, before))
            block.least = self._least(block)

    def _jog(self, t: float, n: int, body: str) -> str:
        if self.state not in ("Idle", "Jog"):
            return "error:8"
        if any(f"G{g}" in body for g in ("0", "1", "2", "3", "4")) and not all(
            tok in ("G20", "G21", "G90", "G91", "G53") for tok in _g_words(body)
        ):
            return "error:16"
        if "F" not in body:
            return "error:22"
        try:
            out = interpret("G1" + body, self._gc, self._gc_settings())
        except GcodeError as exc:
            return f"error:{exc.code}"
        if out.soft_limit:
            return "error:15"
        self._jogging = True
        self._pending = _Pending(n, 0, [a for a in out.actions if a.kind == "motion"])
        return ""

    def _gc_report(self) -> str:
        g = self._gc
        parts = [
            g.motion,
            f"G{54 + g.coord_index}",
            f"G{g.plane}",
            "G20" if g.inches else "G21",
            "G91" if g.relative else "G90",
            "G93" if g.inverse_time else "G94",
            g.spindle,
            " ".join(sorted(g.coolant)) or "M9",
            f"T{g.tool}",
            f"F{g.feed / (MM_PER_INCH if g.inches else 1.0):g}",
            f"S{g.spindle_speed:g}",
        ]
        return "[GC:" + " ".join(parts) + "]\r\n"


_T = typing.TypeVar("_T")


def _clone(obj: _T) -> _T:
    """A shallow copy of a plain object (``copy.copy``'s result, without its dispatch)."""
    new = object.__new__(type(obj))
    new.__dict__.update(obj.__dict__)
    return new


def _override(value: int, k: int) -> int:
    """Feed/spindle override bytes: reset to 100 %, +10, -10, +1, -1 (kept in 10-200 %)."""
    if k == 0:
        return 100
    return min(200, max(10, value + (10, -10, 1, -1)[k - 1]))


def _amass_level(events_per_s: float) -> int:
    """Grbl's AMASS level at a step rate: 0 above 8 kHz, then 1, 2, 3 below 4 and 2 kHz.

    ``st_prep_buffer`` compares a segment's cycles per step at 16 MHz with ``AMASS_LEVEL1``
    to ``3`` (``F_CPU`` / 8000, / 4000, / 2000); level ``L`` runs ``2^L`` ticks an event.
    """
    cycles = 16e6 / events_per_s if events_per_s > 0.0 else math.inf
    return 0 if cycles < 2000 else 1 if cycles < 4000 else 2 if cycles < 8000 else 3


def _g_words(body: str) -> list[str]:
    out = []
    i = 0
    while i < len(body):
        if body[i] == "G":
            j = i + 1
            while j < len(body) and (body[j].isdigit() or body[j] == "."):
                j += 1
            out.append(body[i:j])
            i = j
        else:
            i += 1
    return out


def _r(p: tuple[float, float, float]) -> list[float]:
    return [round(v, 4) for v in p]


def _fmt(p: tuple[float, ...], inches: bool) -> str:
    if inches:
        return ",".join(f"{v / MM_PER_INCH:.4f}" for v in p)
    return ",".join(f"{v:.3f}" for v in p)


def _fmt_setting(k: int, v: float) -> str:
    return f"{int(v)}" if k in _INT_SETTINGS else f"{v:.3f}"
