r"""Stream G-code to a GRBL 1.1 controller safely (no click here; the CLI wraps it).

Protocol (``../shared/references/grbl-1.1-facts.md``):

- Start: wait for the banner (an Arduino reboots when the port opens); if none comes, soft
  reset (``0x18``) and wait again. Then ``$I`` (RX buffer size from ``[OPT:...]``), ``$$``
  and a status report. A controller in ALARM is refused.
- grblHAL (banner ``GrblHAL 1.1f ['$' or '$HELP' for help]``, or ``Grbl 1.1f`` at its
  compatibility levels above 0) speaks the Grbl 1.1 protocol: the same answers, banner
  after every reset, ``[OPT:opts,blocks,rx,...]``, ``$C``/``[MSG:Enabled]``, ``?``/``!``/
  ``~``/``0x18``. What differs and is handled: states with a substate (``Run:1``,
  ``Alarm:N``), ``Door:N`` numbered by its parking state, a ``[TLO:]`` per axis; its
  ``Tool`` state (a manual tool change, ``M6``) wants a sender that stops feeding and
  acknowledges it, so a program with ``M6`` is refused before anything is sent (for any
  firmware: grblHAL can present itself as ``Grbl 1.1f``, and Grbl 1.1 answers ``error:20``).
- Lines are sent stripped and ``\n``-terminated. **Character counting** (default) keeps the
  bytes of unanswered lines within ``rx_buffer - margin``; every non-realtime byte counts,
  ``?`` is realtime and does not. **Simple** sends one line and waits for its answer. Only
  ``ok`` and ``error:N`` answer a line (oldest first); ``<...>``, ``[...]``, ``ALARM:N`` and
  banners do not. ``$`` lines are always sent one at a time, and ``$$``, ``$#``, ``$I``
  and ``$N`` only once the controller is Idle (else GRBL answers error:8).
- Stroke barrier: the first block of a stroke is sent only when every block of the previous
  stroke is acknowledged, so after a disconnect at most one stroke can have run unacknowledged.
- Status ``?`` at most ``poll_hz`` (5 Hz) for the progress report and the watchdogs.
- End of job: after the file's last line the sender sends ``G4P0`` (:data:`END_WAIT`) and
  the job is done when it is acknowledged and a later report says Idle. An ``ok`` means
  "queued", and GRBL serves a ``?`` that came while it planned the last block after that
  block's ``ok`` but before its cycle start, so an Idle report right after the last ``ok``
  is no proof that the motion ran. GRBL answers a dwell only after the planner has
  emptied and the cycle stopped (``mc_dwell`` -> ``protocol_buffer_synchronize``); this
  holds with or without ``Bf:`` in the reports (``$10``), and on grblHAL. The dwell is
  not a file line: it is not journaled, and its ``ok`` tells that every acknowledged
  block ran.
- Faults: ``error:N`` stops feeding at once and sends feed hold; ``ALARM:N``; an unexpected
  banner (controller reset: soft-reset at once so that lines already on the way do not run
  from a lost position); a stall (lines in flight, controller Idle, no answer for
  ``stall_timeout``, plus the dwell of a ``G4`` being answered); silence; a lost
  connection. Ctrl-C holds, then asks resume or stop.
- Safety door: ``Door:N`` is a pause the controller made, not a fault: the sender says
  so (door open, spindle off; closed, waiting for cycle start) and waits, with the stall
  watchdog off (it only runs while Idle); the job goes on when the controller resumes
  (its cycle start; the sender never resumes a door by itself). ``Door:0`` (closed) and
  ``Door:1`` (open) are stopped; ``Door:2`` and up are still stopping or restoring.
  A door state at connect, after check mode's reset or when the stream starts is refused
  (GRBL parses no line until it is dealt with; a line left unanswered there would be
  answered later, its ``ok`` taken for the next line's).
  Stopping safely is: feed hold, wait for ``Hold:0`` (or Idle), soft reset (spindle off,
  queue flushed, no alarm), banner.
- Lift (``StreamOptions.lift``): after that stop (an error, a stall, silence, the user's
  stop), once the controller reports Idle after the reset, the tool goes up: a Z tool by
  ``G21G53G0Z..`` to the travel height (the profile's ``z.safe_mm``, else the highest Z of
  the file's own moves) placed in machine coordinates with the work offset the job ran
  under (the reset clears G92; a startup line may select another system), only up, at
  most the profile's envelope top and, with soft limits on, machine Z 0 (``-$27`` with hard
  limits on: the Z switch trips at 0); then ``G4P0`` and Idle. A servo scribe gets the
  profile's up command, unless that is M5, which the reset just did. Never after an
  alarm (GRBL is locked; the sender never sends ``$X``), a reset of the controller's own,
  a lost link, a machine that did not report standing still before the reset, or with
  the safety door open: the stop's message says why instead.
  A failed lift is told and not tried again.
- Journal: every ``ok`` of a file block is appended and flushed; after a reset the journal
  records which acknowledged blocks actually ran (from the hold position), so ``--resume``
  never skips a stroke (:mod:`scratchfab.machine.sender_journal`). After a lost link it
  records which ran by the last position report, for a board that lost power with the
  cable (``--recut-unsure``).
"""

from __future__ import annotations

import collections
import contextlib
import errno
import math
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import serial

from scratchfab.console import clock
from scratchfab.errors import Interrupted, ScratchfabError
from scratchfab.machine.grbl_codes import MM_PER_INCH, alarm_meaning, error_meaning
from scratchfab.machine.profile import Z_UNLIMITED_MM, gcode_number
from scratchfab.machine.sender_checks import KEPT, REPORT_DIGIT_MM, ZERO_KEPT, same_offset
from scratchfab.machine.sender_journal import Journal, last_surely_run
from scratchfab.machine.sender_program import (
    DEFAULT_RAPID_MM_MIN,
    Block,
    Modal,
    Program,
    TimeLeft,
    along_move,
    block_words,
    dwell_seconds,
    followed_move,
    known_xyz,
    resume_point,
    servo_up,
    stands_at_end,
    strip_block,
    travel_height,
)

if TYPE_CHECKING:
    from scratchfab.machine.profile import MachineProfile

if "scratchfab.machine" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("scratchfab.machine")

REALTIME_STATUS = b"?"
REALTIME_HOLD = b"!"
REALTIME_RESUME = b"~"
REALTIME_RESET = b"\x18"
#: Door states with the machine standing still (Grbl 1.1 and grblHAL): closed, open.
DOOR_STOPPED = ("Door:0", "Door:1")
#: Start-up banners: Grbl 1.1, and grblHAL at its default compatibility level 0.
BANNERS = {"Grbl ": "Grbl", "GrblHAL ": "grblHAL"}
#: ``$`` reports GRBL refuses (error:8) while the machine moves: sent once it is Idle.
_IDLE_ONLY = frozenset({"$$", "$#", "$I", "$N"})
#: Sent after the file's last line: GRBL answers a dwell once every move before it ran.
END_WAIT = "G4P0"
#: The step (mm) a stop's position is matched with on an axis whose ``$100``-``$102`` is
#: not known: 40 steps/mm, a coarse belt drive. Wider only matches an earlier move (cut
#: again); never used to tell a move ended (there an unknown step counts as none).
COARSE_STEP_MM = 0.025
#: Seconds of check mode before its progress lines start (a short file's says nothing).
CHECK_QUIET_S = 2.0

#: GRBL's ``error:9``: G-code locked out, which it answers only in Alarm (or a jog).
GC_LOCKED = 9


def machine_coordinates(profile: MachineProfile | None) -> bool:
    """Whether ``profile`` works in GRBL's machine coordinates (``[envelope] coordinates``).

    Such a machine finds its position again by homing alone: it refuses a work offset, so
    setting a work zero is no advice for it. None (no profile known): False.
    """
    return profile is not None and profile.envelope.coordinates == "machine"


def homing_of(settings: Mapping[int, float]) -> bool | None:
    """GRBL's homing cycle as ``$$`` gave it (``$22``): on, off, or None where not read."""
    return bool(settings[22]) if 22 in settings else None


#: Why ``$H`` is no advice where GRBL's homing is off.
HOMING_OFF = "homing is off, $22=0: $H answers error:5"
#: How a Z tool is raised on a machine with homing on: Grbl's default HOMING_CYCLE_0 is Z.
HOME_RAISES = "home it ($H): GRBL's homing raises Z first (its default cycle)"


class Refind(NamedTuple):
    """How a lost position is found again, for a profile's frame and GRBL's ``$22``.

    Attributes:
        verb: What to do, short: ``re-home``, ``re-home or re-zero``, ``re-zero``.
        done: What was done since, for a question: ``homed ($H)``...
        do: What to do, in full.
        again: What finds the position after an unlock (``$X``) where homing is off.
    """

    verb: str
    done: str
    do: str
    again: str


def refind(profile: MachineProfile | None, homing: bool | None = None) -> Refind:
    """:class:`Refind` for ``profile`` and ``homing`` (``$22``; None: not known).

    A machine-coordinate profile (``[envelope] coordinates = "machine"``) is found again
    by homing alone: it refuses a work offset, so setting a work zero is no advice for it;
    with homing off it needs homing turned on first. A work-coordinate profile, or none
    known (a foreign file, no ``--machine``): homing, or the work zero set again on the
    board's origin (with a profile, its exact command: :func:`work_zero_again`); with
    homing off (``$22=0``, where ``$H`` answers ``error:5``) only the work zero, after an
    unlock (``$X``).
    """
    zero, zeroed = work_zero_again(profile)
    if machine_coordinates(profile):
        frame = "its profile works in GRBL's machine coordinates"
        if homing is False:
            # a 3018 often has no homing switches: $22=1 without them fails every $H
            on = "if it has homing switches, turn homing on ($22=1) and home"
            switchless = (
                "; without switches a work-coordinate profile fits it ([envelope] "
                'coordinates = "work", the work zero set on the board)'
            )
            return Refind(
                "if it has homing switches, turn homing on ($22=1) and re-home",
                "homed ($H) with homing turned on ($22=1)",
                f"{on} the machine ($H) ({frame}, which homing sets: set no work zero){switchless}",
                f"{on} it ($H) ({frame}, which homing sets){switchless}",
            )
        do = f"home the machine ($H) ({frame}: set no work zero)"
        return Refind("re-home", "homed ($H)", do, "home it ($H)")
    if homing is False:
        return Refind(
            "re-zero",
            f"unlocked ($X) and its work zero set again {zeroed}",
            f"unlock it ($X) and {zero} ({HOMING_OFF})",
            zero,
        )
    return Refind(
        "re-home or re-zero",
        f"homed ($H), or its work zero set again {zeroed}",
        f"home the machine ($H), or unlock it ($X) and {zero}",
        zero,
    )


def work_zero_command(profile: MachineProfile) -> tuple[str, str]:
    """The board point the profile's G-code counts from, and the command that zeroes there.

    ``("lower-left corner", "G10 L20 P0 X20 Y20")`` for a board's lower-left corner at
    ``[board] offset_mm = [20, 20]``: the numbers as the G-code writes them, in the work
    system in use (P0, which the G-code runs in as it selects none). Sending ``X0 Y0``
    there, a habit, would move every cut by the offset.
    """
    x, y = profile.origin_xy_text()
    return profile.board.origin_text, f"G10 L20 P0 X{x} Y{y}"


def work_zero_again(profile: MachineProfile | None) -> tuple[str, str]:
    """How the work zero is set again on the board: (to do, as done), for messages.

    With a profile known, the exact command at the board's origin point
    (:func:`work_zero_command`); without one, the words alone:
    ``("set the work zero again on the board's origin", "on the board's origin")``.
    """
    if profile is None:
        return "set the work zero again on the board's origin", "on the board's origin"
    point, command = work_zero_command(profile)
    z = f" and Z on the board's surface (`{Z_ZERO}`)" if _z_tool(profile) else ""
    return (
        f"set the work zero again: {_jog_and_send(profile)}",
        f"(`{command}` at the board's {point}){z}",
    )


#: Zeroes work Z where the tool touches the board's surface (the ``[z]`` heights count from it).
Z_ZERO = "G10 L20 P0 Z0"


def _z_tool(profile: MachineProfile) -> bool:
    """A tool that Z lowers onto the board (``mode`` "z" or "spindle"), not a servo's."""
    return profile.tool_control.mode != "servo"


def _jog_and_send(profile: MachineProfile) -> str:
    """``jog to the board's lower-left corner and send `G10 L20 P0 X20 Y20` there``.

    A Z tool (``[tool_control] mode`` "z" or "spindle") is zeroed in Z too, on the board's
    surface.
    """
    point, command = work_zero_command(profile)
    z = (
        f", touch the tool on the board's surface and send `{Z_ZERO}`, then jog Z up"
        if _z_tool(profile)
        else ""
    )
    return f"jog to the board's {point} and send `{command}` there{z}"


def zero_kept_advice(
    profile: MachineProfile | None,
    verb: str = "set the work zero again",
    offset: tuple[float, float, float] | None = None,
) -> str:
    """How to set the work zero again where a reset cleared a G92 zero: one a reset keeps.

    ``offset``: the work offset before the reset (machine mm), where known: ``G10 L2 P0``
    with it restores the same zero exactly, the machine position kept (a reset at rest
    keeps it). Else, or besides, with a work-coordinate profile its exact command at the
    board's origin point (:func:`work_zero_command`); without one the G-code's origin
    (:data:`~scratchfab.machine.sender_checks.ZERO_KEPT`). ``verb`` starts the advice.
    """
    if profile is None or machine_coordinates(profile):
        again = f"{verb} {ZERO_KEPT}"
    else:
        again = f"{verb}: {_jog_and_send(profile)} ({KEPT})"
    if offset is None:
        return again
    x, y, z = (gcode_number(v, 3) for v in offset)
    return (
        f"{verb} with `G21 G10 L2 P0 X{x} Y{y} Z{z}` (the earlier work offset in machine "
        f"mm; {KEPT}) where the machine has not lost its position since; else {again}"
    )


def unlock_advice(
    profile: MachineProfile | None,
    homing: bool | None,
    lost: bool | None = None,
    raise_it: str | None = None,
) -> str | None:
    """How to leave an Alarm where homing is off (``$22=0``): unlock, find the position again.

    ``lost``: True, the position is likely lost; otherwise it may be. ``raise_it``: how the
    tool is raised, where it may be down: said between the unlock and the work zero, as
    moving to the board's origin with the tool down drags it across the board. None where
    homing is on or not known: ``home it ($H)`` holds, in the caller's own words.
    """
    if homing is not False:
        return None
    again = refind(profile, False).again
    unlock = "unlock it ($X)" if raise_it is None else f"unlock it ($X) yourself, {raise_it},"
    if lost:
        join = " and" if raise_it is None else " then"
        return f"{unlock}{join} {again} ({HOMING_OFF})"
    if raise_it is None:
        return f"unlock it ($X), and if its position may be lost {again} ({HOMING_OFF})"
    return f"{unlock} then, if its position may be lost, {again} ({HOMING_OFF})"


def rehome(profile: MachineProfile | None, homing: bool | None = None) -> str:
    """How a lost position is found again, as a verb (:func:`refind`'s ``verb``).

    ``re-home`` for a machine-coordinate profile with homing, ``re-home or re-zero`` for a
    work-coordinate or unknown one, ``re-zero`` where homing is off (``$22=0``), and for a
    machine-coordinate profile without it, to turn homing on first (if it has switches).
    """
    return refind(profile, homing).verb


def reconnect_next(profile: MachineProfile | None, homing: bool | None = None) -> str:
    """What to do once a controller that was lost (its link, or its answers) stands still."""
    return (
        f"then reconnect, {rehome(profile, homing)} the machine (opening the port reboots an "
        "Arduino-based controller, which loses its position) and run the same command with "
        "--resume"
    )


def link_lost_next(profile: MachineProfile | None, homing: bool | None = None) -> str:
    """What to do after a lost connection, once the machine stands still."""
    return (
        f"{reconnect_next(profile, homing)}, adding --recut-unsure ([stream] recut_unsure = "
        "true in a pipeline) if the board's lights went out with the cable"
    )


def silent_next(profile: MachineProfile | None, homing: bool | None = None) -> str:
    """What to do after the controller fell silent (no status reports).

    The hold and the reset sent may not have reached it.
    """
    return (
        "it may have hung or lost power: if the machine still moves, wait until it stops or "
        f"press its reset before going near it; {reconnect_next(profile, homing)}"
    )


class StreamFault(ScratchfabError):
    """The job stopped because of the machine or the link (exit status 3)."""

    exit_code = 3


class StreamStopped(Interrupted):
    """The user stopped the job: machine held and soft-reset, the journal says where."""


class StopSignal(KeyboardInterrupt):
    """SIGTERM or SIGHUP while streaming: taken as Ctrl-C answered with stop."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def _signals_stop(streamer: Streamer) -> Iterator[None]:
    """Turn SIGTERM and SIGHUP into :class:`StopSignal` for the duration (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    names = ("SIGTERM", "SIGHUP", "SIGBREAK")  # SIGBREAK: Ctrl-Break on Windows
    nums = [getattr(signal, n) for n in names if hasattr(signal, n)]

    def handler(signum: int, frame: object) -> None:
        if not streamer._stopping:  # already stopping: let the stop finish
            raise StopSignal(signum)

    previous = {n: signal.signal(n, handler) for n in nums}
    try:
        yield
    finally:
        for n, old in previous.items():
            signal.signal(n, old)


class Port(Protocol):
    """What the sender needs from a pyserial port."""

    timeout: float | None

    def write(self, data: bytes) -> int | None: ...  # noqa: D102

    def read(self, size: int = 1) -> bytes: ...  # noqa: D102

    @property
    def in_waiting(self) -> int: ...  # noqa: D102

    def reset_input_buffer(self) -> None: ...  # noqa: D102

    def close(self) -> None: ...  # noqa: D102


def open_port(port: str, baud: int) -> Any:
    """Open a serial device or pyserial URL (``grblsim://...`` included)."""
    # a real port is locked (flock) so that a second sender cannot interleave its lines;
    # pyserial offers that on POSIX only (a Windows COM port is exclusive anyway)
    extra = {"exclusive": True} if "://" not in port and os.name == "posix" else {}
    try:
        return serial.serial_for_url(port, baudrate=baud, timeout=0.01, write_timeout=5.0, **extra)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise ScratchfabError(f"cannot open port {port!r}: {port_trouble(port, exc)}") from None


#: How to list the serial ports, per ``sys.platform`` prefix.
_LIST_PORTS = {
    "linux": "list them with `ls /dev/ttyUSB* /dev/ttyACM*`",
    "darwin": "list them with `ls /dev/cu.*`",
    "win": "Windows names them COM3, COM4...: see the Device Manager's Ports (COM & LPT)",
}


def port_trouble(port: str, exc: BaseException, platform: str = sys.platform) -> str:
    """Why a serial device would not open, and what a maker does about it (one line).

    A missing port names the ports pyserial sees and how to list them; a refused one the
    Linux ``dialout`` group; a port held by another program says so. A ``://`` URL gets
    pyserial's message alone.
    """
    code = getattr(exc, "errno", None)
    text = str(exc)
    if "://" in port:
        return text
    windows = platform.startswith("win")
    if code == errno.ENOENT or "FileNotFoundError" in text:
        listing = next((v for k, v in _LIST_PORTS.items() if platform.startswith(k)), "")
        why = os.strerror(errno.ENOENT) if code else text
        return f"no such port ({why}); {_ports_seen()}" + (f"; {listing}" if listing else "")
    if (
        code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY)
        or "exclusively lock" in text
        or (windows and "PermissionError" in text)
    ):
        return (
            "another program has the port open (another stream, a serial monitor, a G-code "
            "sender): close it first"
        )
    if code in (errno.EACCES, errno.EPERM):
        if platform.startswith("linux"):
            return (
                f"{os.strerror(code)}: your user may not open serial ports; add it to the "
                "dialout group (sudo usermod -aG dialout $USER, then log out and in)"
            )
        return f"{os.strerror(code)}: your user may not open this port"
    return text


def _ports_seen() -> str:
    """The serial ports pyserial sees here, as a clause."""
    try:
        from serial.tools.list_ports import comports

        devices = sorted({p.device for p in comports()})
    except Exception:  # noqa: BLE001 (a listing that fails only loses the hint)
        return "the ports here could not be listed"
    if not devices:
        return (
            "no serial port is seen here: is the controller plugged in and powered? (a CH340 "
            "board may need its driver)"
        )
    more = f" and {len(devices) - 8} more" if len(devices) > 8 else ""
    return f"ports seen here: {', '.join(devices[:8])}{more}"


@dataclass
class Status:
    """A parsed status report; positions in mm and feed in mm/min, whatever $13 says."""

    state: str = "?"
    mpos: tuple[float, float, float] | None = None
    wpos: tuple[float, float, float] | None = None
    wco: tuple[float, float, float] | None = None
    feed: float = 0.0
    time: float = 0.0
    planner_free: int | None = None  # ``Bf:``'s planner blocks free (``$10`` value 2 on)
    mpos_given: bool = False  # the report gave ``MPos`` itself (else WPos was given, or none)
    #: ``wco`` is as a report printed it (``WCO:``, here or earlier), not summed from
    #: ``$#``'s offsets, each rounded to a digit
    wco_printed: bool = False


def parse_status(line: str, wco: tuple[float, float, float] | None, scale: float = 1.0) -> Status:
    """Parse ``<State|MPos:...|FS:...|WCO:...>``; WPos/MPos completed from the last WCO.

    Args:
        line: The report.
        wco: The last work offset known (mm), for a report without ``WCO:``.
        scale: Millimetres per reported unit (25.4 under ``$13=1``); positions, offset
            and feed come back in mm.
    """
    st = Status(time=time.monotonic(), wco=wco)
    parts = line.strip("<>").split("|")
    st.state = parts[0]
    for part in parts[1:]:
        key, _, value = part.partition(":")
        nums = value.split(",")
        try:
            if key in ("MPos", "WPos", "WCO"):
                xyz = (float(nums[0]) * scale, float(nums[1]) * scale, float(nums[2]) * scale)
                if key == "MPos":
                    st.mpos, st.mpos_given = xyz, True
                elif key == "WPos":
                    st.wpos = xyz
                else:
                    st.wco, st.wco_printed = xyz, True
            elif key in ("FS", "F"):
                st.feed = float(nums[0]) * scale
            elif key == "Bf":
                st.planner_free = int(nums[0])
        except (ValueError, IndexError):
            continue
    if st.wco is not None:
        if st.mpos is not None and st.wpos is None:
            st.wpos = tuple(m - w for m, w in zip(st.mpos, st.wco, strict=True))  # type: ignore[assignment]
        elif st.wpos is not None and st.mpos is None:
            st.mpos = tuple(p + w for p, w in zip(st.wpos, st.wco, strict=True))  # type: ignore[assignment]
    return st


@dataclass
class StreamProgress:
    """What the progress display shows."""

    acked: int
    total: int
    eta_s: float
    state: str
    wpos: tuple[float, float, float] | None
    final: bool = False  # the job is done: the controller reported Idle after the last ack
    ran: int | None = None  # blocks the machine has run (None: not known, ``acked`` shown)

    @property
    def done(self) -> int:
        """The blocks run, where known, else the blocks acknowledged."""
        return self.acked if self.ran is None else self.ran

    @property
    def fraction(self) -> float:
        """The share of the blocks run (acknowledged where that is not known)."""
        return self.done / self.total if self.total else 1.0


@dataclass
class ControllerInfo:
    """What the controller said about itself."""

    version: str = ""
    firmware: str = "Grbl"  # "Grbl" or "grblHAL" (banner, or $I's [FIRMWARE:grblHAL])
    rx_buffer: int = 128
    planner_blocks: int = 15
    settings: dict[int, float] = field(default_factory=dict)
    status: Status = field(default_factory=Status)
    wco: tuple[float, float, float] | None = None  # work offset in mm (None: unknown)
    wco_source: str = ""  # how it was read: "$#" or "status"
    g92: tuple[float, float, float] | None = None  # the G92 part of it in mm (None: unknown)
    wcs: str | None = None  # the active work system at connect ($G: "G54"...; None: unknown)
    tlo: float = 0.0  # the tool length offset on Z at connect (mm, $#'s [TLO:]; 0: unknown)
    booted: bool = False  # its banner came as the port opened: it booted then (no reset sent)

    @property
    def laser_mode(self) -> bool | None:
        """GRBL's laser mode ``$32``; None when ``$$`` did not tell (taken as maybe on)."""
        value = self.settings.get(32)
        return None if value is None else bool(value)

    @property
    def inch_reports(self) -> bool:
        """GRBL reports positions and offsets in inches (``$13=1``): the one place read."""
        return bool(self.settings.get(13, 0))


@dataclass
class StreamOptions:
    """Sender behaviour.

    Attributes:
        protocol: ``counting`` or ``simple``.
        margin: Bytes of the RX buffer left unused by character counting.
        rx_buffer: RX buffer size; ``None`` takes it from ``$I`` (128 on Grbl 1.1).
        poll_hz: Status polls per second (at most 5).
        banner_timeout: Seconds to wait for the banner before (and after) a soft reset.
        banner_settle: Seconds to read on after the banner for its ``[MSG:...]`` and
            startup-line results (shown to the user; later ones are skipped unshown).
        stall_timeout: Seconds with lines in flight, controller Idle and no answer.
        command_timeout: Seconds to wait for the answer to a line the sender sends alone
            (``$I``, ``$$``, ``$#``, ``$G``, ``$C``) before giving up on it.
        silence_timeout: Seconds without any byte from the controller while polling.
        hold_timeout: Seconds to wait for ``Hold:0`` when stopping.
        busy_timeout: Seconds to wait on connecting for a controller still running (another
            sender's queue, e.g. a killed one) to finish before it is held and reset.
        stroke_barrier: Send a stroke's first block only when the previous stroke is acked.
        rests: At most this many times a session, feed nothing after a move whose end
            GRBL's step rounding leaves open (the work offset is known to a digit) until
            the controller reports Idle at it: the step it stands on there is learnt, so
            that a stop at such an end is matched in whole steps (:meth:`Streamer._rest_at`),
            not cut again on ``--resume``. Each rest stops the machine at that end (a
            fraction of a second), only where the tool is up (a travel's or a lift's end,
            outside every stroke; none in a program whose strokes are not known). 0 (the
            default): never.
        lift: Raise the tool after a stop (an error, a stall, silence, the user's stop)
            that ended in a soft reset of a machine that stood still, once the controller
            is Idle with its position known; never after an alarm, a lost link or with
            the safety door open (see :meth:`Streamer._lift`). Off by default: a bare
            Streamer only holds and resets.
        profile: The job's machine profile, for the lift: its travel height
            ``z.safe_mm`` (else the highest Z of the file's own moves), the envelope's Z
            top, and for a servo scribe the up command (``tool_control.off``).
    """

    protocol: str = "counting"
    margin: int = 8
    rx_buffer: int | None = None
    poll_hz: float = 5.0
    banner_timeout: float = 2.5
    banner_settle: float = 0.1
    stall_timeout: float = 10.0
    command_timeout: float = 3.0
    silence_timeout: float = 5.0
    hold_timeout: float = 30.0
    busy_timeout: float = 120.0
    stroke_barrier: bool = True
    rests: int = 0
    lift: bool = False
    profile: MachineProfile | None = None


@dataclass
class CheckReport:
    """Errors found by check mode: (block, code) pairs, and an alarm if one came.

    ``meaning``: the alarm's, worded for the machine's ``$22`` as a streamed alarm's is;
    ``locked``: how to leave the Alarm the controller stays in after it ("" if it does not).
    """

    errors: list[tuple[Block, int]]
    alarm: tuple[Block, int] | None = None
    meaning: str = ""
    locked: str = ""


@dataclass
class _Item:
    text: str
    block: Block | None  # None for preamble/system lines of the sender
    pre: int = -1
    barrier: int = -1  # send only when blocks up to this index are acknowledged
    end_wait: bool = False  # the END_WAIT dwell after the file's last line


@dataclass(frozen=True)
class _Lifted:
    """What became of the tool after a stop: a clause for the stop's message, the journal's."""

    text: str
    record: dict[str, Any]


class _Unanswered(StreamFault):
    """A line got no answer in time: it may still be in GRBL's buffer, answered later."""


class _Fault(Exception):
    """A fault while talking to the controller; ``kind`` picks the safe reaction.

    Kinds: ``error`` and ``stall`` (hold, wait, reset), ``silent`` (hold, short wait, reset),
    ``alarm`` (reset), ``lock`` (Alarm reported without its message: reset, position not
    trusted), ``reset`` (the controller reset itself), ``link`` (connection lost).
    """

    def __init__(self, message: str, kind: str = "link") -> None:
        super().__init__(message)
        self.kind = kind


class Streamer:
    """Drives one controller through one program.

    Args:
        port: An open pyserial port (see :func:`open_port`).
        options: Sender behaviour.
        on_progress: Called with a :class:`StreamProgress` at most ``poll_hz`` times a second.
        on_message: Called with informational lines (warnings, controller messages).
        ask_interrupt: After Ctrl-C (machine held): return ``"resume"`` or ``"stop"``.
    """

    def __init__(
        self,
        port: Port,
        options: StreamOptions | None = None,
        on_progress: Callable[[StreamProgress], None] | None = None,
        on_message: Callable[[str], None] | None = None,
        ask_interrupt: Callable[[], str] | None = None,
    ) -> None:
        self.port = port
        self.options = options or StreamOptions()
        if self.options.protocol not in ("counting", "simple"):
            raise ScratchfabError(
                f"protocol must be 'counting' or 'simple', not {self.options.protocol!r}"
            )
        self.on_progress = on_progress or (lambda p: None)
        self.on_message = on_message or (lambda m: None)
        self.ask_interrupt = ask_interrupt
        self.info = ControllerInfo()
        self.status = Status()
        self._buf = bytearray()
        self._last_rx = time.monotonic()
        self._last_poll = 0.0
        self._wco: tuple[float, float, float] | None = None
        self._wco_printed = False  # ``_wco`` came from a report's ``WCO:`` (else ``$#``)
        self._acked_blocks: list[int] = []  # file blocks acknowledged, in order
        self._acks_at_status = 0  # how many of them were acknowledged before the last report
        self.sent_log: list[str] = []
        self.max_inflight_bytes = 0
        self.max_inflight_lines = 0

    # ------------------------------------------------------------------ I/O

    def _write(self, data: bytes) -> None:
        if data == REALTIME_HOLD:
            self._hold_unseen = True  # until a report shows the machine standing
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise _Fault(f"connection lost while writing: {exc}") from None

    def _read_lines(self, wait: float) -> list[str]:
        """Complete lines received within ``wait`` seconds (CR/LF stripped, blanks dropped)."""
        deadline = time.monotonic() + wait
        out: list[str] = []
        step = max(0.0, min(0.01, wait))
        while True:
            try:
                # pyserial reconfigures a real port (tcsetattr) on every timeout assignment
                if self.port.timeout != step:
                    self.port.timeout = step
                n = self.port.in_waiting
                data = self.port.read(n if n > 0 else 1)
            except (serial.SerialException, OSError) as exc:
                raise _Fault(f"connection lost: {exc}") from None
            if data:
                self._last_rx = time.monotonic()
                self._buf += data
                while b"\n" in self._buf:
                    raw, _, rest = self._buf.partition(b"\n")
                    self._buf = bytearray(rest)
                    line = raw.decode("ascii", "replace").strip()
                    if line:
                        out.append(line)
            if out or time.monotonic() >= deadline:
                return out

    def _poll(self, force: bool = False) -> None:
        now = time.monotonic()
        period = 1.0 / min(self.options.poll_hz, 5.0)
        if force or now - self._last_poll >= period:
            self._last_poll = now
            self._write(REALTIME_STATUS)

    @property
    def _mm_per_reported_unit(self) -> float:
        return MM_PER_INCH if self.info.inch_reports else 1.0

    def _note_status(self, line: str) -> None:
        self.status = parse_status(line, self._wco, self._mm_per_reported_unit)
        # answers arrive in order: the block running at this report was acknowledged before it
        self._acks_at_status = len(self._acked_blocks)
        if self.status.wco is not None:
            self._wco = self.status.wco
        if self.status.wco_printed:
            self._wco_printed = True
        else:
            self.status.wco_printed = self._wco_printed and self._wco is not None
        if self.status.state in ("Hold:0", "Idle") or self.status.state.startswith("Door"):
            self._hold_unseen = False  # stood still (a door's suspend reads no line either)

    def _command(self, text: str) -> list[str]:
        """Send a line alone and collect the lines before its ``ok``; error:N raises."""
        self._write(text.encode("ascii") + b"\n")
        got: list[str] = []
        timeout = self.options.command_timeout
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in self._read_lines(0.05):
                if line == "ok":
                    return got
                if line.startswith("error:"):
                    code = int(line[6:]) if line[6:].isdigit() else -1
                    raise StreamFault(f"{text}: error:{code} ({error_meaning(code)})")
                if line.startswith("ALARM:"):
                    code = int(line[6:]) if line[6:].isdigit() else -1
                    meaning = alarm_meaning(code, self._find_again())
                    raise StreamFault(f"{text}: ALARM:{code} ({meaning})")
                if line.startswith("<"):
                    self._note_status(line)
                else:
                    got.append(line)
        raise _Unanswered(f"no answer to {text!r} within {timeout:g} s")

    def _wait_banner(self, timeout: float) -> list[str] | None:
        """Lines after a banner, or None if no banner came within ``timeout``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            lines = self._read_lines(0.05)
            for k, line in enumerate(lines):
                firmware = banner_firmware(line)
                if firmware is not None:
                    self.info.firmware = firmware
                    self.info.version = line.split()[1]
                    after = lines[k + 1 :]
                    after += self._read_lines(self.options.banner_settle)
                    return after
        return None

    # ------------------------------------------------------------------ connect

    def connect(self) -> ControllerInfo:
        """Wake the controller, read ``$I``, ``$$`` and its state; refuse ALARM.

        Raises:
            StreamFault: No banner, not GRBL 1.1, or the controller is in ALARM/Sleep.
        """
        try:
            after = self._wait_banner(self.options.banner_timeout)
            self.info.booted = after is not None
            if after is None:
                self._wait_until_still()
                self.on_message("no banner; sending a soft reset")
                self._write(REALTIME_RESET)
                after = self._wait_banner(self.options.banner_timeout)
            if after is None:
                raise StreamFault(
                    "no GRBL banner ('Grbl 1.1...' or 'GrblHAL 1.1...'): is this a Grbl 1.1 or "
                    "grblHAL controller, and is the baud rate right?"
                )
            if self.info.version.startswith("0."):
                # <Idle,MPos:...> reports: Idle, Hold and the positions would never be read
                raise StreamFault(
                    f"controller reports Grbl {self.info.version}, whose status reports and "
                    "messages predate Grbl 1.1; flash Grbl 1.1 (nothing was sent)"
                )
            if not self.info.version.startswith("1.1"):
                self.on_message(
                    f"controller reports {self.info.firmware} {self.info.version}; written for "
                    "the Grbl 1.1 protocol"
                )
            for line in after:
                if line.startswith("[MSG:"):
                    self.on_message(f"controller: {line}")
            self._refuse_door(self._status_now().state)
            for line in self._command("$I"):
                if line == "[FIRMWARE:grblHAL]":
                    self.info.firmware = "grblHAL"
                if line.startswith("[OPT:"):
                    parts = line[5:-1].split(",")
                    if len(parts) >= 3 and parts[1].isdigit() and parts[2].isdigit():
                        self.info.planner_blocks = int(parts[1])
                        self.info.rx_buffer = int(parts[2])
            for line in self._command("$$"):
                key, _, value = line.partition("=")
                if key.startswith("$") and key[1:].isdigit():
                    try:
                        self.info.settings[int(key[1:])] = float(value)
                    except ValueError:
                        continue
            self.info.status = self._status_now()
        except _Fault as fault:
            raise StreamFault(str(fault)) from None
        if self.info.status.state.startswith(("Alarm", "Sleep")):
            leave = self._leave_alarm(
                None, "home it ($H) or, if the position is known, unlock it ($X)"
            )
            raise StreamFault(
                f"controller is in {self.info.status.state}: {leave}; nothing was sent"
            )
        try:
            self._read_work_offset()
        except _Fault as fault:
            raise StreamFault(str(fault)) from None
        return self.info

    @staticmethod
    def _refuse_door(state: str, done: str = "nothing was sent") -> None:
        """Refuse a safety door state: GRBL reads no line until the door is dealt with."""
        if state.startswith("Door"):
            raise StreamFault(
                f"controller reports {state}: its safety door is open (or was, and it "
                "waits for cycle start); it reads no line meanwhile. Close the door, press "
                f"cycle start if it asks, then stream again; {done}"
            )

    def _wait_until_still(self) -> None:
        """Before a soft reset: let a controller that is still moving finish first.

        A port without DTR reset (a pty, some USB bridges) keeps the controller running
        what an earlier sender queued, e.g. one that was killed. A reset now would stop it
        mid-move (``ALARM:3``, position lost). Waits up to ``busy_timeout`` for Idle (or
        Hold:0, where a reset is safe), then holds it and waits for Hold:0. A safety door
        that stopped it (``Door:0``/``Door:1``, at connect or meanwhile) stands it still as
        well: it is told, and the reset comes at once.
        """
        try:
            state = self._status_now().state
        except _Fault:
            return  # no status: nothing is known to be moving; reset as before
        moving = ("Run", "Jog", "Hold:1", "Home", "Door:2", "Door:3", "Door:4")
        if state in DOOR_STOPPED:
            self._tell_door_stopped(state)
            return
        if not state.startswith(moving):
            return
        timeout = self.options.busy_timeout
        self.on_message(
            f"controller is still moving ({state}): an earlier sender's queue; waiting up to "
            f"{timeout:g} s for it to finish before the soft reset"
        )
        deadline = time.monotonic() + timeout
        period = 1.0 / min(self.options.poll_hz, 5.0)
        while time.monotonic() < deadline:
            time.sleep(max(0.0, self._last_poll + period - time.monotonic()))
            with contextlib.suppress(_Fault):
                state = self._status_now().state
            if state in DOOR_STOPPED:
                self._tell_door_stopped(state)
                return
            if not state.startswith(moving):
                self.on_message(f"controller is {state} now")
                return
        self.on_message(
            f"controller still {state} after {timeout:g} s: feed hold, then a soft reset"
        )
        self._write(REALTIME_HOLD)
        deadline = time.monotonic() + self.options.hold_timeout
        while time.monotonic() < deadline and state not in ("Hold:0", "Idle", *DOOR_STOPPED):
            time.sleep(max(0.0, self._last_poll + period - time.monotonic()))
            with contextlib.suppress(_Fault):
                state = self._status_now().state
        if state in DOOR_STOPPED:
            self._tell_door_stopped(state)

    def _tell_door_stopped(self, state: str) -> None:
        """Say why a controller stopped by its safety door is reset at once."""
        door = "is open" if state == "Door:1" else "was opened and is closed again"
        self.on_message(
            f"controller is in {state}: its safety door {door} and the machine stands "
            "still, so the soft reset comes now (what an earlier sender had queued is "
            "dropped; the spindle stays off)"
        )

    def _read_work_offset(self, reports: int = 12) -> None:
        """Fill ``info.wco``: from ``$#`` and ``$G``, else from a status report's ``WCO:``.

        A status report carries ``WCO:`` only every 10 (idle) to 30 (busy) reports, after
        a change, and not at all on builds without the field, so the first report cannot be
        relied on. ``$#`` prints every offset: GRBL's work offset is the active system's
        (``$G``) plus G92, plus the tool length offset on Z. Without ``$#`` (a firmware
        that refuses it), up to ``reports`` status reports are polled for a ``WCO:``. Values
        in inches (``$13=1``) are converted to mm. Leaves ``info.wco`` None when neither
        works.
        """
        scale = self._mm_per_reported_unit
        try:
            params = self._command("$#")
            modal = self._command("$G")
        except _Unanswered:
            raise  # still queued: its late ok would pair with the next line sent
        except StreamFault as exc:
            self.on_message(f"cannot read the work offsets with $# ({exc}); polling status")
        else:
            found: dict[str, list[float]] = {}
            for line in params:
                name, _, value = line.strip("[]").partition(":")
                try:
                    found[name] = [float(v) for v in value.split(":")[0].split(",")]
                except ValueError:
                    continue
            words = next((ln[4:-1].split() for ln in modal if ln.startswith("[GC:")), [])
            wcs = next((w for w in words if w in ("G54", "G55", "G56", "G57", "G58", "G59")), "")
            self.info.wcs = wcs or None
            base, g92, tlo = found.get(wcs), found.get("G92"), found.get("TLO", [0.0])
            if base is not None and g92 is not None and min(len(base), len(g92)) >= 3:
                xyz = [base[k] + g92[k] for k in range(3)]
                if len(tlo) >= 3:  # grblHAL built with a tool offset on every axis
                    xyz = [xyz[k] + tlo[k] for k in range(3)]
                else:
                    xyz[2] += tlo[0]
                self.info.wco = (xyz[0] * scale, xyz[1] * scale, xyz[2] * scale)
                self.info.tlo = (tlo[2] if len(tlo) >= 3 else tlo[0]) * scale
                self.info.g92 = (g92[0] * scale, g92[1] * scale, g92[2] * scale)
                self.info.wco_source = "$#"
                # Status reports without WCO: (most of them) derive positions from it too.
                self._wco, self._wco_printed = self.info.wco, False
                return
            self.on_message(f"$# or $G did not name the active work offset ({wcs or '?'})")
        period = 1.0 / min(self.options.poll_hz, 5.0)
        for _ in range(reports):
            if self._wco is not None:
                break
            time.sleep(max(0.0, self._last_poll + period - time.monotonic()))
            self._status_now()
        if self._wco is not None:  # in mm already (parse_status)
            self.info.wco = self._wco
            self.info.wco_source = "status"

    def _status_now(self, timeout: float = 2.0) -> Status:
        self._write(REALTIME_STATUS)
        self._last_poll = time.monotonic()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in self._read_lines(0.05):
                if line.startswith("<"):
                    self._note_status(line)
                    return self.status
        raise _Fault("no status report from the controller", kind="silent")

    def set_work_zero(self, command: str) -> tuple[float, float, float] | None:
        """Send ``command`` (a ``G10 L20`` that zeroes where the tool stands), read the offset.

        Returns:
            The work offset read back (mm; None where neither ``$#`` nor a report tells).

        Raises:
            StreamFault: The controller refused the line or did not answer; nothing moved.
        """
        try:
            self._command(command)
            self._wco = self.info.wco = None  # read anew, not the offset before the line
            self._read_work_offset()
            self.info.status = self._status_now()
        except _Fault as fault:
            raise StreamFault(f"{command}: {fault}; nothing moved") from None
        return self.info.wco

    # ------------------------------------------------------------------ check mode

    def check(self, program: Program) -> CheckReport:
        """Run the program through check mode (``$C``), one line at a time; no motion."""
        report = CheckReport(errors=[])
        try:
            with _signals_stop(self):
                return self._check(program, report)
        except _Fault as fault:
            # (a controller left in check mode leaves it at the next connect's soft reset)
            raise StreamFault(f"{fault}; nothing was cut (check mode)") from None
        except BaseException as exc:
            # Ctrl-C, a signal or a bug: do not leave the controller in check mode ($C)
            self._stopping = True
            try:
                self._write(REALTIME_RESET)
                self._wait_banner(self.options.banner_timeout)
            except (Exception, KeyboardInterrupt):
                pass
            if isinstance(exc, StopSignal):
                raise StreamStopped(
                    f"check mode stopped by {exc}; controller soft-reset, nothing moved"
                ) from None
            raise
        finally:
            self._stopping = False

    def _check(self, program: Program, report: CheckReport) -> CheckReport:
        """Check mode proper: ``$C``, every line, ``$C`` again (reset and banner)."""
        # A StreamFault raised here is soft-reset by check() (out of check mode, if in it).
        if "[MSG:Enabled]" not in self._command("$C"):
            # $C toggles: one that did not say Enabled left check mode (or never entered it)
            raise StreamFault(
                f"{program.path}: the controller did not enter check mode ($C answered "
                "without [MSG:Enabled]); nothing was checked or sent"
            )
        total = sum(not block.system for block in program.blocks)
        began, checked, told = time.monotonic(), 0, 0
        for block in program.blocks:
            if block.system:
                continue
            tenth = 10 * checked // total
            # a line at each tenth once it takes a while: a long file checks for minutes
            if tenth > told and time.monotonic() - began >= CHECK_QUIET_S:
                told = tenth
                self.on_message(
                    f"check mode: {tenth * 10}% {checked}/{total} lines  elapsed "
                    f"{clock(time.monotonic() - began)}"
                )
            checked += 1
            self._write(block.text.encode("ascii") + b"\n")
            answered = False
            deadline = time.monotonic() + 5.0
            while not answered:
                if time.monotonic() > deadline:
                    raise StreamFault(f"check mode: no answer to line {block.lineno}")
                lines = self._read_lines(0.05)
                if any(banner_firmware(line) for line in lines):
                    # a reset ends check mode: what is sent from now on would run for real
                    raise StreamFault(
                        f"{program.path}:{block.lineno}: the controller reset itself during "
                        "check mode (banner received), which ends check mode; soft-reset it "
                        "so that no line sent meanwhile runs; nothing more was sent"
                    )
                for line in lines:
                    if line == "ok":
                        answered = True
                    elif line.startswith("error:"):
                        report.errors.append((block, _code(line)))
                        answered = True
                    elif line.startswith("ALARM:"):
                        report.alarm = (block, _code(line))
                        answered = True
            if report.alarm is not None:
                self._write(REALTIME_RESET)
                self._wait_banner(self.options.banner_timeout)
                report.meaning = alarm_meaning(report.alarm[1], self._find_again())
                try:
                    locked = self._status_now().state.startswith("Alarm")
                except _Fault:  # no report: the ALARM's own error stands, as locked as it left it
                    locked = True  # (ALARM:1 and 2, all check mode meets, lock it)
                if locked:  # nothing moved: no raise to say
                    report.locked = self._leave_alarm(False, "unlock it ($X)", moved=False)
                return report
        self._write(b"$C\n")
        if self._wait_banner(self.options.banner_timeout) is None:
            raise StreamFault("check mode: no reset after leaving check mode")
        # GRBL ignores the door in check mode; the reset comes back in Door if it is open
        self._refuse_door(self._status_now().state, "nothing moved")
        self._check_offset_kept(program)
        return report

    def _check_offset_kept(self, program: Program) -> None:
        """After the reset that ends check mode: refuse if the work offset changed.

        GRBL's soft reset clears G92 and G43.1 (the tool length offset), so a zero set with
        G92 is gone and the job would run that far off. G54-G59 (G10 L2/L20) survive.
        """
        before = self.info.wco
        self.info.wco, self.info.g92, self._wco = None, None, None
        self._wco_printed = False
        self._read_work_offset()
        after = self.info.wco
        inches = self.info.inch_reports
        if before is None or (after is not None and same_offset(before, after, inches)):
            return
        now = "unknown" if after is None else xyz_text(after)
        raise StreamFault(
            f"{program.path}: leaving check mode soft-resets GRBL, which cleared its G92 or "
            f"tool length offset: the work offset was {xyz_text(before)}, now {now} mm, so "
            f"the job would run elsewhere; {zero_kept_advice(self.options.profile, offset=before)}"
            " and "
            "stream again; nothing moved"
        )

    # ------------------------------------------------------------------ streaming

    def stream(
        self,
        program: Program,
        journal: Journal,
        start: int = 0,
        preamble: Sequence[str] = (),
        resume: bool = False,
        zeroed: str | None = None,
    ) -> None:
        """Send ``program.blocks[start:]`` after ``preamble``; returns when the job is done.

        ``resume`` marks the journal session as a continuation of the earlier ones;
        ``zeroed``: the work zero command sent at connect (``--zero-here``), journaled.

        Raises:
            StreamFault: A controller error, alarm, reset, stall or lost connection (the
                message names the file line and the code's meaning).
            StreamStopped: The user chose to stop after Ctrl-C.
        """
        self._refuse_tool_change(program, start)
        try:  # the door may have opened since connect (the user setting up the board)
            now = self._status_now()
            self._refuse_door(now.state)
        except _Fault as fault:
            raise StreamFault(str(fault)) from None
        if start == 0 and now.wpos is not None:  # the job's first moves start from here
            program = program.placed_at(now.wpos[:2], self.info.wcs)
        items = self._items(program, start, preamble)
        name = getattr(self.port, "port", None)  # a pyserial port's device or URL
        journal.start(
            program,
            resume,
            start,
            self.options.protocol,
            preamble,
            self.info.planner_blocks,
            name if isinstance(name, str) else None,
            self.info.laser_mode,
            self.info.wco,
            self.info.g92,
            self.info.inch_reports,
            self._step_mm(),
            self._homing(),
            zeroed,
        )
        self._journal = journal
        self._program = program
        self._acked_blocks = []
        self._acks_at_status = 0
        self._rests = ({}, {}, {})
        self._counted = steps_counted_until(program.blocks)
        self._repeated = _repeated_targets(program.blocks[start : self._counted])
        self._given_from = _first_given(program.blocks, start)
        self._down = _tool_down(program.strokes)
        self._rests_left = self.options.rests
        self._rested_through = -1
        self._resting = -1
        self._hold_alarm = None
        self._session_start = start
        self._stopped_through = None
        self._hold_unseen = False  # a hold before the connect's reset is over
        self._all_ran = False  # END_WAIT acknowledged: every acknowledged block ran
        try:
            with _signals_stop(self):
                self._run(items, program, journal)
        except _Fault as fault:
            try:
                self._stop_after_fault(fault)
            except KeyboardInterrupt as again:
                # a further Ctrl-C (or signal) while stopping: finish the stop, then say so
                self._stop_on_escape(
                    again, reason=f"{fault}; {_interrupt_name(again)} while stopping"
                )
                raise StreamStopped(
                    f"{fault}; {_interrupt_name(again)} while stopping: {self._held_text()}; "
                    f"{self._go_on()}"
                ) from None
            raise StreamFault(str(fault)) from None
        except StreamStopped:
            raise  # stopped safely already
        except BaseException as exc:
            # anything else (a second Ctrl-C, a closed prompt, a journal write error,
            # SystemExit, a bug) must not leave the machine running or held
            self._stop_on_escape(exc)
            if isinstance(exc, StopSignal):
                raise StreamStopped(
                    f"stopped by {exc} {self._after_line()}; {self._held_text()}; {self._go_on()}"
                ) from None
            raise
        journal.write("end", complete=True)

    def _refuse_tool_change(self, program: Program, start: int) -> None:
        """Refuse M6 before sending anything.

        Grbl 1.1 answers ``error:20`` (the job stops part-way); grblHAL stops in its ``Tool``
        state, also when it presents itself as ``Grbl 1.1f`` (its compatibility levels above
        0, where ``$I`` does not name it).
        """
        for block in program.blocks[start:]:
            if ("M", 6.0) in block_words(block.text):
                raise StreamFault(
                    f"{program.path}:{block.lineno}: M6 (tool change): Grbl 1.1 refuses it "
                    "(error:20, the job would stop there) and grblHAL would stop in its Tool "
                    "state for a manual tool change, which this sender does not handle; remove "
                    "the line (change tools between files); nothing was sent"
                )

    def _items(self, program: Program, start: int, preamble: Sequence[str]) -> list[_Item]:
        items = [_Item(text, None, pre=k) for k, text in enumerate(preamble)]
        stroke_of = program.stroke_of()
        prev_last = -1
        for block in program.blocks[start:]:
            barrier = -1
            s = stroke_of[block.index]
            if self.options.stroke_barrier and s >= 0 and program.strokes[s][0] == block.index:
                barrier = prev_last
            if s >= 0:
                prev_last = program.strokes[s][1]
            items.append(_Item(block.text, block, barrier=barrier))
        items.append(_Item(END_WAIT, None, end_wait=True))
        return items

    def _run(self, items: list[_Item], program: Program, journal: Journal) -> None:
        budget = (self.options.rx_buffer or self.info.rx_buffer) - self.options.margin
        simple = self.options.protocol == "simple"
        self._inflight: collections.deque[tuple[_Item, int]] = collections.deque()
        self._inflight_bytes = 0
        # highest block index acknowledged (acks come in order); a resumed job's first
        # report counts the blocks before its start as done, as its later ones do
        first = next((it.block.index for it in items if it.block is not None), len(program.blocks))
        self._acked_through = first - 1
        self._left = TimeLeft(
            program,
            first,
            self.info.planner_blocks,
            self.info.laser_mode,
            self._step_tol(),
            self._step_mm(),
        )
        self._acked_items = 0
        self._last_answer = time.monotonic()
        self._last_ack_time = 0.0
        nxt = 0
        idle_since: float | None = None
        paused_since: float | None = None
        door = ""  # the last Door:N reported, "" when not in a door state
        last_report = 0.0
        self._last_rx = time.monotonic()
        total = len(items)
        while self._acked_items < total or not self._finished():
            try:
                # ---- feed
                while nxt < total and self._resting < 0:
                    item = items[nxt]
                    size = len(item.text) + 1
                    one_at_a_time = simple or (item.block is not None and item.block.system)
                    if one_at_a_time and self._inflight:
                        break
                    if self._inflight and self._inflight_bytes + size > budget:
                        break
                    if item.barrier >= 0 and self._acked_through < item.barrier:
                        break
                    if item.text in _IDLE_ONLY and (self._inflight or not self._finished()):
                        break  # GRBL answers error:8 to these unless Idle
                    self._write(item.text.encode("ascii") + b"\n")
                    self.sent_log.append(item.text)
                    self._inflight.append((item, size))
                    self._inflight_bytes += size
                    self.max_inflight_bytes = max(self.max_inflight_bytes, self._inflight_bytes)
                    self.max_inflight_lines = max(self.max_inflight_lines, len(self._inflight))
                    nxt += 1
                    if item.block is not None and self._wants_rest(item.block.index):
                        self._resting = item.block.index
                        self._rest_reports = 0  # reports after its answer
                    if one_at_a_time:
                        break
                # ---- answers
                # all answered: ask for the report that ends the job now, not a period later
                # resting: ask every 20 ms once the move is acknowledged, to go on soon
                waiting = self._resting >= 0 and not self._inflight
                self._poll(
                    force=(self._acked_items >= total and self._last_poll < self._last_ack_time)
                    or (waiting and time.monotonic() - self._last_poll >= 0.02)
                )
                for line in self._read_lines(0.005 if self._inflight else 0.02):
                    if self._answer(line):
                        idle_since = None
                    elif line.startswith("<"):
                        self._note_status(line)
                        if self.status.state.startswith("Alarm"):
                            raise self._lock_fault()
                        if self._resting >= 0 and self._rest_at(self.status):
                            self._resting = -1
                        if self._inflight and self.status.state == "Idle":
                            idle_since = idle_since or time.monotonic()
                        else:
                            idle_since = None
                        if self.status.state == "Hold:0":
                            paused_since = paused_since or time.monotonic()
                        else:
                            paused_since = None
                        door = self._tell_door(door, self.status.state)
                    elif line.startswith("ALARM:"):
                        raise self._alarm_fault(_code(line))
                    elif banner_firmware(line):
                        raise self._reset_fault("mid-job")
                    elif line.startswith("[MSG:"):
                        self.on_message(f"controller: {line}")
                # ---- watchdogs
                now = time.monotonic()
                # GRBL answers a dwell (G4) only when it ends, Idle all the while
                if idle_since is not None and now - idle_since > self.options.stall_timeout + max(
                    0.0, dwell_seconds(self._inflight[0][0].text)
                ):
                    item = self._inflight[0][0]
                    where = (
                        f"line {item.block.lineno}"
                        if item.block
                        else f"the end-of-job {item.text}"
                        if item.end_wait
                        else f"preamble {item.text}"
                    )
                    raise _Fault(
                        f"stalled: no answer to {where} for {now - self._last_answer:.1f} s "
                        "while the controller is Idle (answer lost?)",
                        kind="stall",
                    )
                if now - self._last_rx > self.options.silence_timeout:
                    raise _Fault(
                        f"the controller has not answered for {now - self._last_rx:.1f} s "
                        "(no status reports)",
                        kind="silent",
                    )
                if paused_since is not None and now - paused_since > 2.0:
                    self.on_message(
                        "controller paused (M0 or hold): press Ctrl-C to resume or stop"
                    )
                    paused_since = math.inf
                # a report follows each status report (its position is the one it shows),
                # and comes on its own when none came for two periods
                period = 1.0 / min(self.options.poll_hz, 5.0)
                fresh = self.status.time > last_report
                if now - last_report >= (period / 2 if fresh else 2 * period):
                    last_report = now
                    self._report(self._acked_through, len(program.blocks))
            except KeyboardInterrupt as exc:
                self._interrupted(exc)
                self._last_rx = time.monotonic()
                idle_since = None
        self._report(len(program.blocks) - 1, len(program.blocks), final=True)

    def _tell_door(self, door: str, state: str) -> str:
        """Say what a change of the safety door state means; returns the new door state."""
        now = state if state.startswith("Door") else ""
        if now == door:
            return door
        if now == "Door:1":
            self.on_message(
                "safety door open (Door:1): the controller paused the job and turned the "
                "spindle off; close the door, then press cycle start on the controller (or "
                "Ctrl-C here to stop)"
            )
        elif now == "Door:0":
            self.on_message(
                "safety door closed (Door:0): the job goes on when you press cycle start on "
                "the controller (or Ctrl-C here to resume or stop)"
            )
        elif now:
            self.on_message(f"safety door: controller in {now} (stopping or restoring)")
        else:
            self.on_message(f"controller resumed after the safety door ({state})")
        return now

    def _answer(self, line: str) -> bool:
        """Handle ``ok``/``error:N`` for the oldest line in flight; False for other lines."""
        if line != "ok" and not line.startswith("error:"):
            return False
        if not self._inflight:
            self.on_message(f"unexpected answer {line!r} with nothing in flight")
            return True
        item, size = self._inflight.popleft()
        self._inflight_bytes -= size
        self._last_answer = time.monotonic()
        if line != "ok":
            code = _code(line)
            if code == GC_LOCKED and not self._stopping:
                # the lines in flight with the lost alarm got no answer: not this item's
                self._journal.write("error", code=code)
                raise self._lock_fault(f"error:{code} ({error_meaning(code)})")
            text = self._error_text(item, code)
            if self._stopping:
                self.on_message(text)
                return True
            raise _Fault(text, kind="error")
        self._acked_items += 1
        self._last_ack_time = time.monotonic()
        if item.block is not None:
            self._acked_through = item.block.index
            self._acked_blocks.append(item.block.index)
            self._journal.write("ack", i=item.block.index, line=item.block.lineno)
        elif item.end_wait:
            self._all_ran = True
        else:
            self._journal.write("ack", pre=item.pre)
        return True

    _stopping = False
    _all_ran = False
    _hold_unseen = False  # a feed hold was sent and no report since shows the machine still
    _alarm_lost = False  # the last alarm stopped the machine at speed: position likely lost
    _hold_alarm: _Fault | None = None  # an alarm that came while waiting for a hold
    _alarm_text = ""  # the last alarm: its code, meaning and line
    _session_start = 0  # the first file block of this session (a resume's restart)
    # rests (StreamOptions.rests), each session's own (stream() sets them): per axis, the
    # work targets (mm) seen at rest and their step; none here (a Streamer not streaming)
    _rests: tuple[dict[float, int], ...] = ({}, {}, {})
    _rests_left = 0
    _resting = -1  # the block rested at, -1 while none
    _rest_reports = 0  # the reports since its answer
    _rested_through = -1  # the last block rested at: it and all before it ran
    _counted = 0  # steps_counted_until of the program streamed
    _repeated: tuple[set[float], ...] = (set(), set(), set())  # targets met twice, per axis
    _given_from = (0, 0, 0)  # per axis, the session's first block giving it (_first_given)
    _down: frozenset[int] = frozenset()  # blocks leaving the tool down (_tool_down)
    _stopped_through: int | None = None  # the safe stop's executed-through

    def _alarm_fault(self, code: int) -> _Fault:
        """The fault of GRBL's ``ALARM:code`` mid-job, journaled (``lost``: see below).

        A soft limit (``ALARM:2``) keeps the position where GRBL raises it in a cycle
        (``limits_soft_check`` feeds a hold, ``Hold:1``, waits for it, then resets) or
        standing still. But GRBL reads lines while a feed hold still slows the machine down
        (``Hold:1``), and one whose target lies outside resets at once: ``mc_reset`` sees
        the hold running, kills the steppers at speed ("position has likely been lost") and
        only ``ALARM:2`` is reported. The sender takes the position as likely lost where it
        sent a feed hold that no report since showed complete (journaled ``lost: true``),
        and as unsure where the last report said ``Hold:1`` or ``Run`` without one (GRBL's
        own soft-limit hold, or the controller's feed hold button, whose hold may have
        begun and ended between two reports: ``lost: "maybe"``). A hard
        limit (``ALARM:1``) and a reset in motion (``ALARM:3``) lose it (``lost: true``).
        The message names the line whose target left the travel (:meth:`_soft_limit_line`).
        """
        own = self._hold_unseen
        slowing = own or self.status.state in ("Hold:1", "Run")
        lost: bool | str = code in (1, 3) or (code == 2 and own)
        if code == 2 and slowing and not own:
            lost = "maybe"
        self._alarm_lost = bool(lost)
        meaning = alarm_meaning(code, self._find_again())
        if code == 2 and own:
            meaning = (
                "soft limit: a target beyond the machine travel, read while the feed hold "
                "the sender sent was still slowing the machine down, so GRBL stopped the "
                "motors at speed: its position is likely lost, home it ($H) before --resume"
            )
        elif lost == "maybe":
            meaning = (
                f"soft limit: a target beyond the machine travel, while the machine was "
                f"{'slowing down (Hold:1)' if self.status.state == 'Hold:1' else 'moving'}: "
                "the position is kept if that was GRBL's own "
                "soft-limit hold, but likely lost if the controller's feed hold button "
                "was slowing it (GRBL then stopped the motors at speed); home it ($H) "
                "before --resume unless you know which"
            )
        self._journal.write("alarm", code=code, **({"lost": lost} if lost else {}))
        where = self._soft_limit_line() if code == 2 else self._after_line()
        self._alarm_text = f"ALARM:{code} ({meaning}) {where}"
        return _Fault(f"{self._alarm_text}; the controller stopped the job", kind="alarm")

    def _lock_fault(self, error: str = "") -> _Fault:
        """The fault of a controller found in Alarm mid-job without its ALARM or reset message.

        A status report says Alarm, or ``error:9`` came (``error``: it and its meaning),
        which GRBL answers only in Alarm (the sender never jogs) and which can come before
        the next report. The ALARM:N or reset banner was lost on the line, and GRBL's reset
        flushed the lines in flight unanswered: they never run, the ``error:9`` answers a
        later line (which one is not known), and the position may be lost. Nothing runs:
        the stop resets without a feed hold (kind ``lock``).
        """
        after = self._after_line()
        said = (
            f"{error} came {after}, so the controller is in Alarm"
            if error
            else f"the controller reports Alarm {after}"
        )
        # homing off: unlock, raise the tool, then re-zero (not dragged to the origin)
        off = unlock_advice(self.options.profile, self._homing(), None, self._raise_it())
        find = off or (
            "home it" if machine_coordinates(self.options.profile) else "home it or check the zero"
        )
        return _Fault(
            f"{said} (its ALARM or reset message was lost on the line); it stopped the job: "
            f"{find}, then --resume",
            kind="lock",
        )

    def _soft_limit_line(self) -> str:
        """Which line's target left GRBL's travel, for ``ALARM:2``'s message.

        GRBL checks a line's target when it plans it (``mc_line``) and answers it only
        after, so the line it raised the alarm on is the oldest one not yet answered.
        Named where its target, placed in machine coordinates with the work offset, lies
        outside the soft limits' ``-$13x..0`` on an axis (the frame unchanged since the
        connect, :func:`steps_counted_until`, and no move the sender does not follow, such
        as G53 or G28, before it); else the line is said to be unknown.
        """
        after = self._after_line()
        item = self._inflight[0][0] if getattr(self, "_inflight", None) else None
        block = None if item is None else item.block
        if block is None:
            reading = "" if item is None else f"; GRBL was reading the sender's {item.text!r}"
            return f"{after} (which line's target left the travel is not known{reading})"
        blocks = self._program.blocks
        known = known_xyz(block.modal)
        wco = self._wco
        travel = [self.info.settings.get(130 + k) for k in range(3)]
        outside = []
        frame_known = block.index < steps_counted_until(blocks) and not any(
            b.unfollowed for b in blocks[: block.index + 1]
        )
        if wco is not None and frame_known:
            for k, axis in enumerate("XYZ"):
                v, t = known[k], travel[k]
                if v is None or t is None:
                    continue
                m = v + wco[k]
                if m > 0.001 or m < -t - 0.001:
                    outside.append(f"machine {axis} {m:.3f} outside -{t:g}..0 (${130 + k})")
        if not outside:
            return (
                f"{after} (which line's target left the travel is not known: GRBL was "
                f"reading line {block.lineno}, whose target the sender does not place "
                "outside the travel)"
            )
        return (
            f"on line {block.lineno} ({block.text!r}), whose target lies beyond the travel "
            f"({', '.join(outside)})"
        )

    def _finished(self) -> bool:
        """After the last ack: done once a status report after it says Idle.

        The last ack of a job is END_WAIT's, which GRBL sends once the motion has ended;
        an Idle report after an earlier ``ok`` may predate the cycle start of its block.
        """
        return self.status.state == "Idle" and self.status.time > self._last_ack_time

    def _report(self, acked_through: int, total: int, final: bool = False) -> None:
        """Report progress: the lines acknowledged, and what the machine ran and has left.

        GRBL acknowledges a move when it is queued, so the time left counts the queued
        moves too, from the last status report's position and planner blocks free
        (:class:`TimeLeft`).
        """
        seen = self._acks_at_status  # the blocks acknowledged before the last status report
        left = self._left.update(
            acked_through,
            self._acked_blocks[seen - 1] if seen else -1,
            self.status.wpos,
            self.status.planner_free,
            all_ran=self._all_ran or final,
        )
        self.on_progress(
            StreamProgress(
                acked=acked_through + 1,
                total=total,
                eta_s=left,
                state=self.status.state,
                wpos=self.status.wpos,
                final=final,
                ran=self._left.ran,
            )
        )

    def _step_tol(self, unknown: float = 0.0) -> float:
        """How far (mm) a reported position may lie off a move's line: rounding and a step.

        GRBL's steps leave the ideal line by up to one step per axis (``$100``-``$102``
        steps/mm; unknown: ``unknown`` mm counted).
        """
        return 0.01 + max(self._step_mm(unknown)) * math.sqrt(3.0)

    def _step_mm(self, unknown: float = 0.0) -> tuple[float, float, float]:
        """GRBL's step per axis (mm, ``$100``-``$102``; ``unknown`` where not known)."""
        steps = [self.info.settings.get(100 + k) for k in range(3)]
        x, y, z = (1.0 / s if s and s > 0 else unknown for s in steps)
        return x, y, z

    def _reset_fault(self, when: str) -> _Fault:
        """The fault of a controller that reset itself (its banner came) ``when``.

        Lines already on the way would run from a lost position: a soft reset flushes them.
        Named as a stop names them: the last line GRBL accepted, the last it surely ran (no
        position to judge by: a planner full and the stepper's few before the last
        acknowledgement, :meth:`_executed_guess`) and where a resume restarts.
        """
        with contextlib.suppress(_Fault):
            self._write(REALTIME_RESET)
        self._stopped_through = self._executed_guess(None)
        return _Fault(
            f"the controller reset itself {when} (its banner came) {self._after_line()}"
            f"{self._ran_clause()}; its position may be lost: {self._rehome()}, "
            "then --resume",
            kind="reset",
        )

    def _after_line(self) -> str:
        """``after line N`` (the last file line GRBL accepted), or before which line it stopped.

        Where no file line was accepted yet: before the file's first line, or in a resumed
        session before the line it restarts at.
        """
        blocks = self._program.blocks
        if self._acked_blocks:
            return f"after line {blocks[self._acked_blocks[-1]].lineno}"
        start = self._session_start
        if start <= 0 or start >= len(blocks):
            return "before GRBL accepted the file's first line"
        return (
            f"before GRBL accepted line {blocks[start].lineno}, the first line of this resumed "
            "session"
        )

    def _error_text(self, item: _Item, code: int) -> str:
        if item.block is not None:
            self._journal.write("error", i=item.block.index, line=item.block.lineno, code=code)
            return (
                f"{self._program.path}:{item.block.lineno}: error:{code} ({error_meaning(code)}) "
                f"on {item.block.text!r}"
            )
        if item.end_wait:
            self._journal.write("error", code=code)
            return (
                f"{self._program.path}: after the last line, the wait for the end of motion "
                f"({END_WAIT}) got error:{code} ({error_meaning(code)})"
            )
        self._journal.write("error", pre=item.pre, code=code)
        return f"resume preamble {item.text!r}: error:{code} ({error_meaning(code)})"

    # ------------------------------------------------------------------ stopping

    def _interrupted(self, exc: KeyboardInterrupt) -> None:
        self._write(REALTIME_HOLD)
        self._tell("feed hold sent")
        choice = "stop"
        by = "the user"
        if isinstance(exc, StopSignal):
            by = str(exc)  # no prompt: nobody may be there to answer
        elif self.ask_interrupt is not None:
            try:
                choice = self.ask_interrupt()
            except (Exception, KeyboardInterrupt):
                # a second Ctrl-C, stdin closed or not a terminal (click's Abort): stop
                choice = "stop"
        if choice == "resume":
            # GRBL ignores ~ until the hold is complete (Hold:0)
            held = self._wait_held(self.options.hold_timeout)
            if self._hold_alarm is not None:
                raise self._hold_alarm  # GRBL is locked: the alarm's stop
            if held is not None and held.state == "Door:1":
                self.on_message(
                    "the safety door is open: close it, then press cycle start on the "
                    "controller (it ignores a resume while the door is open)"
                )
                return
            self._write(REALTIME_RESUME)
            self.on_message("resumed")
            return
        tool = self._safe_stop(f"stopped by {by}", wait=self.options.hold_timeout)
        raise StreamStopped(
            f"stopped by {by} {self._after_line()}{self._ran_clause()}; "
            f"{self._held_text()}{tool}; {self._go_on()}"
        )

    def _held_text(self) -> str:
        """How the stop left the machine: held then reset, or held until an alarm came.

        An alarm while the hold was awaited (:attr:`_hold_alarm`) means GRBL stopped the
        job itself (at speed where the hold still slowed it down): its message says what
        became of the position.
        """
        if self._hold_alarm is None:
            return "machine held, then soft-reset (spindle off)"
        return (
            f"the feed hold was cut short: {self._alarm_text}; GRBL stopped the machine "
            "itself and is locked, and the sender soft-reset it (spindle off)"
        )

    def _servo(self) -> bool:
        """Whether the tool is a servo scribe (the profile's, else the program's pen mode)."""
        profile = self.options.profile
        if profile is not None:
            return profile.tool_control.mode == "servo"
        program = getattr(self, "_program", None)
        return program is not None and program.pen_mode

    def _raise_it(self) -> str:
        """How a person raises a tool the sender did not: ``jog Z up``, or a servo's up command.

        A servo scribe has no Z to jog: its up command is the profile's ``off`` (M5 without
        a profile), which a soft reset has already sent where it is M5.
        """
        if not self._servo():
            return "jog Z up"
        up = self._servo_up()
        done = " (a reset switches the spindle output off: check that it is up)"
        return f"raise the scribe with its up command {up}{done if up == 'M5' else ''}"

    def _servo_up(self) -> str:
        """A servo's up command (:func:`~scratchfab.machine.sender_program.servo_up`)."""
        profile = self.options.profile
        off = profile.tool_control.command("off") if profile is not None else None
        return servo_up(getattr(self, "_program", None), off)

    def _homing(self) -> bool | None:
        """GRBL's ``$22`` as the connect's ``$$`` gave it (None: not read)."""
        return homing_of(self.info.settings)

    def _rehome(self) -> str:
        """:func:`rehome` for this machine's profile and ``$22``."""
        return rehome(self.options.profile, self._homing())

    def _find_again(self) -> str:
        """How an alarm's meaning says a lost position is found again.

        ``re-home``; where homing is off (``$22=0``), :func:`rehome`'s words instead.
        """
        return self._rehome() if self._homing() is False else "re-home"

    def _leave_alarm(self, lost: bool | None, homed: str, moved: bool = True) -> str:
        """How a person leaves an Alarm and raises a tool that may be down, in that order.

        Where homing is off (``$22=0``): unlock, raise the tool, then set the work zero
        (:func:`unlock_advice`). Else with a servo scribe: unlock, raise it, then home
        (``$H`` moves X and Y with the scribe as it stands, and GRBL in Alarm takes no
        G-code, the up command included). With a Z tool where homing is on (``$22=1``):
        home it, which raises Z first (:data:`HOME_RAISES`; GRBL in Alarm takes no jog),
        or, where the position may be known (``lost`` not True), unlock it and jog Z up;
        where homing is not known, ``homed`` (homing or an unlock) and the raise.
        ``moved`` False (check mode, which moves nothing): no raise is said.
        """
        raise_it = self._raise_it() if moved else None
        off = unlock_advice(self.options.profile, self._homing(), lost, raise_it)
        if off is not None:
            return off
        if raise_it is None:
            return f"{homed} yourself"
        if self._homing() and not self._servo():
            if lost:
                return f"{HOME_RAISES}, not just unlock it: its position may be lost"
            return f"{HOME_RAISES}; or, if its position is known, unlock it ($X), then {raise_it}"
        if self._servo():
            home = "home it ($H)" + (
                " (its position may be lost: not just unlock it)"
                if lost
                else " if its position may be lost"
            )
            return f"unlock it ($X) yourself, {raise_it}, then {home}"
        return f"{homed} yourself, then {raise_it}"

    def _raise_after_reset(self) -> str:
        """How a person raises the tool after a reset (:meth:`_raise_it`).

        Where homing is on (``$22=1``) the controller is back in Alarm, which takes no jog
        or G-code until unlocked: homing, which raises a Z tool first (:data:`HOME_RAISES`),
        or a servo's unlock, up command and homing (:meth:`_leave_alarm`).
        """
        if not self._homing():
            return self._raise_it()
        return self._leave_alarm(True, "home it ($H)") if self._servo() else HOME_RAISES

    def _go_on(self) -> str:
        """The stop's advice on going on: after an alarm, once it is cleared."""
        if self._hold_alarm is None:
            return "continue later with --resume"
        return "clear the alarm as it says, then continue with --resume"

    def _ran_clause(self) -> str:
        """Where the machine stopped, as the stop's journal has it.

        The last line it surely ran and the line a resume restarts at (the first
        stroke not run to its end); "" before the safe stop judged it.
        """
        through = self._stopped_through
        if through is None or not self._acked_blocks:
            return ""
        blocks = self._program.blocks
        restart = resume_point(self._program, set(range(through + 1)))
        if restart >= len(blocks):
            return " (the last one GRBL accepted; the machine had run every line)"
        ran = f"through line {blocks[through].lineno}" if through >= 0 else "no line"
        return (
            f" (the last one GRBL accepted; the machine had run {ran}: a resume restarts at line "
            f"{blocks[restart].lineno})"
        )

    def _tell(self, text: str) -> None:
        """``on_message`` on a stop path: a closed terminal must not keep the machine held."""
        try:
            self.on_message(text)
        except Exception:  # noqa: BLE001, S110
            pass

    def _stop_on_escape(self, exc: BaseException, reason: str = "") -> None:
        """The safe stop when anything but a fault or a user's stop escapes the stream.

        Feed hold, a short wait for ``Hold:0`` (a further Ctrl-C cuts it short), soft reset
        (spindle off, queue flushed), then ``stop`` in the journal, or ``lost`` when the port
        is gone. Errors on the way are swallowed: the caller re-raises ``exc``.
        """
        self._stopping = True
        reason = reason or (
            f"sender interrupted ({type(exc).__name__}: {exc})"
            if str(exc)
            else (f"sender interrupted ({type(exc).__name__})")
        )
        try:
            held = self._hold_briefly_then_reset()
        except _Fault:
            self._journal_quietly(
                "lost",
                reason=reason,
                executed_through=self._executed_guess(self.status),
                **_where(self.status),
            )
            return
        why = f"{reason} cut the stop short; {self._raise_after_reset()}"
        lifted = self._no_lift(why)
        if lifted is not None:  # no message carries its clause
            self._tell(f"the tool was NOT raised: {why}")
        self._journal_stop(reason, self._executed_guess(held), lifted, quietly=True)
        self._tell(self._held_text())

    def _write_surely(self, data: bytes) -> None:
        """Write ``data`` even if Ctrl-C arrives meanwhile (a stop must reach the machine)."""
        for _ in range(3):
            try:
                self._write(data)
                return
            except KeyboardInterrupt:
                continue

    def _journal_stop(
        self,
        reason: str,
        through: int,
        lifted: _Lifted | None,
        lost: bool = False,
        quietly: bool = False,
    ) -> None:
        """Journal a ``stop``, with where the machine stood by the last report.

        Its reason, the last block surely run, :func:`_where` and what became of the tool;
        ``lost`` where the controller reset itself (a resume then asks whether it was homed
        since); ``quietly`` where the journal's own failure must not hide the stop's cause.
        """
        data = {"reason": reason, "executed_through": through, **({"lost": True} if lost else {})}
        data |= {**_where(self.status), **_journaled(lifted)}
        if quietly:
            self._journal_quietly("stop", **data)
        else:
            self._journal.write("stop", **data)

    def _journal_quietly(self, event: str, **data: Any) -> None:
        try:
            self._journal.write(event, **data)
        except (Exception, KeyboardInterrupt):
            pass

    def _stop_after_fault(self, fault: _Fault) -> None:
        """Bring the machine to a safe state after a fault and journal what surely ran."""
        try:
            if fault.kind in ("error", "stall"):
                self._write(REALTIME_HOLD)
                tool = self._safe_stop(str(fault), wait=self.options.hold_timeout)
                fault.args = (f"{fault}; feeding stopped, {self._held_text()}{tool}",)
            elif fault.kind == "silent":
                self._write(REALTIME_HOLD)
                tool = self._safe_stop(str(fault), wait=2.0)
                if self._hold_alarm is None:
                    fault.args = (
                        f"{fault}{tool}; {silent_next(self.options.profile, self._homing())}",
                    )
                else:  # it answered after all, with an alarm
                    fault.args = (f"{fault}; {self._held_text()}{tool}; {self._go_on()}",)
            elif fault.kind == "alarm":
                # the alarm already stopped motion and flushed the queue; a critical alarm
                # answers nothing until reset
                leave = self._leave_alarm(
                    self._alarm_lost,
                    "home it ($H)"
                    + (
                        " (its position may be lost: not just unlock it)"
                        if self._alarm_lost
                        else " or unlock it ($X)"
                    ),
                )
                lifted = self._no_lift(
                    "after an alarm GRBL is locked and the sender never unlocks it; check the "
                    f"machine, {leave}"
                )
                self._reset(str(fault), self.status, lifted)
                fault.args = (str(fault) + _clause(lifted),)
            elif fault.kind == "lock":
                leave = self._leave_alarm(True, "home it ($H) or unlock it ($X)")
                lifted = self._no_lift(
                    f"the controller is in Alarm and its position may be lost; {leave}"
                )
                self._reset(str(fault), None, lifted)  # a reset may have lost the position
                fault.args = (str(fault) + _clause(lifted),)
            elif fault.kind == "reset":
                self._wait_banner(self.options.banner_timeout)  # the reset sent on the banner
                lifted = self._no_lift(
                    "the controller reset itself and its position may be lost; "
                    + self._raise_after_reset()
                )
                self._journal_stop(str(fault), self._executed_guess(None), lifted, lost=True)
                fault.args = (str(fault) + _clause(lifted),)
            elif fault.kind == "link":
                # nothing can be sent. A powered controller runs what it acknowledged;
                # journal what surely ran by the last position report, for --recut-unsure.
                lifted = self._no_lift("the connection is lost, nothing can be sent")
                self._journal.write(
                    "lost",
                    reason=str(fault),
                    executed_through=self._executed_guess(self.status),
                    **_where(self.status),
                    **_journaled(lifted),
                )
                # the spindle only where the file starts one (a Z drag bit's never does)
                spins = any(b.modal.spindle in ("M3", "M4") for b in self._program.blocks)
                fault.args = (
                    f"{fault}; a controller that kept power goes on running the lines it had "
                    f"received (up to a planner full of moves{', spindle on' if spins else ''}): "
                    "wait until it stops "
                    f"or press its reset before going near it{_clause(lifted)}; "
                    f"{link_lost_next(self.options.profile, self._homing())}",
                )
        except _Fault:
            self._journal.write(
                "stop", reason=str(fault), executed_through=self._executed_guess(None)
            )

    def _wait_held(self, wait: float) -> Status | None:
        """Poll until the controller stands still: Hold:0, Idle, or a stopped door state.

        Called after a feed hold was sent. GRBL drops a hold that comes in a door state, and
        one that restores (``Door:3``, grblHAL ``Door:4``) then resumes the cycle: after a
        door state the hold is sent again once a report says the machine runs, with reports
        asked for at 20 Hz meanwhile so that it runs as briefly as can be.
        """
        deadline = time.monotonic() + wait
        door = self.status.state.startswith("Door")
        while time.monotonic() < deadline:
            self._poll(force=door and time.monotonic() - self._last_poll >= 0.05)
            for line in self._read_lines(0.02):
                if self._answer(line):
                    continue
                if line.startswith("<"):
                    self._note_status(line)
                    state = self.status.state
                    if state in ("Hold:0", "Idle", "Check", *DOOR_STOPPED):
                        return self.status
                    if state.startswith("Door"):
                        door = True
                    elif door and state.startswith(("Run", "Jog")):
                        self._write(REALTIME_HOLD)  # the door resumed the cycle: hold it
                        door = False
                elif line.startswith("ALARM:"):
                    self._hold_alarm = self._alarm_fault(_code(line))
                    return None
                elif banner_firmware(line):
                    # a reset while held: its Idle and position are not the hold's
                    raise self._reset_fault("while held")
        return None

    def _safe_stop(self, reason: str, wait: float) -> str:
        """Wait for Hold:0 (or Idle) after a feed hold, soft reset, raise the tool; journal it.

        What surely ran is judged before the lift (its status reports would pass for the
        hold's); the ``stop`` event follows the lift and says what became of the tool. A
        sender killed during the lift leaves a session without a closing event, which a
        resume reads more cautiously (a planner full of blocks cut again).

        Returns:
            A clause for the stop's message ("" with the lift off).
        """
        self._stopping = True
        held = self._wait_held(wait)
        frame = self._wco  # the work offset the job ran under (a reset may clear G92)
        self._write(REALTIME_RESET)
        banner = self._wait_banner(self.options.banner_timeout) is not None
        # an alarm that cut the hold short: the last report's position was passed all the same
        seen = held if self._hold_alarm is None else self.status
        through = self._stopped_through = self._executed_guess(seen)
        lifted = self._lift(held, banner, frame)
        self._journal_stop(reason, through, lifted)
        return _clause(lifted)

    # ------------------------------------------------------------------ lifting the tool

    def _lift(
        self, held: Status | None, banner: bool, frame: tuple[float, float, float] | None
    ) -> _Lifted | None:
        """Raise the tool after the safe stop's soft reset, when that is known to be safe.

        Only with the controller Idle after the reset (GRBL keeps its position over a
        reset from Hold:0 or Idle: ``mc_reset`` stops the steppers, raising ALARM:3, only
        in a cycle, a jog, homing or a hold still decelerating), never in Alarm (the
        sender never unlocks it), with the safety door open, or without a banner. A Z tool
        goes up to the travel height by a rapid in machine coordinates (``G53``, placed
        with the work offset the job ran under: the reset may have cleared G92, a
        startup line may have chosen another system), only up, never above the profile's
        envelope nor, with soft limits on, machine Z 0 (``-$27`` with hard limits on:
        :func:`_soft_limit_top`). A servo scribe gets the profile's up command, unless
        it is M5, which the reset has just done. The sender waits for Idle after it; a
        failure is told and nothing is tried again. A Ctrl-C during the lift holds and
        resets the machine where it is.

        Returns:
            What became of the tool, or None with the lift off.
        """
        if not self.options.lift:
            return None
        try:
            return self._lift_now(held, banner, frame)
        except KeyboardInterrupt:
            self._halt_lift()
            return self._not_raised(
                "interrupted while raising it (feed hold, then soft reset: it stopped part-way)",
                "interrupted",
            )
        except _Fault as fault:
            return self._not_raised(f"{fault} while raising it", "failed")

    def _no_lift(self, reason: str) -> _Lifted | None:
        """A stop after which the tool is never raised, and why (None with the lift off).

        Not told as it happens (no lift was tried): the fault's message carries its clause.
        """
        return self._not_raised(reason, tell=False) if self.options.lift else None

    def _not_raised(self, reason: str, result: str = "skipped", tell: bool = True) -> _Lifted:
        if tell:  # the lift's own account, as it happens
            self._tell(f"the tool was NOT raised: {reason}")
        return _Lifted(
            f"; the tool was NOT raised ({reason})", {"result": result, "reason": reason}
        )

    def _lift_now(
        self, held: Status | None, banner: bool, frame: tuple[float, float, float] | None
    ) -> _Lifted:
        if not banner:
            return self._not_raised("no banner came after the soft reset; state unknown")
        status = self._status_after_reset()
        state = status.state
        if state.startswith("Alarm"):
            leave = self._leave_alarm(
                True, "home it ($H) (or unlock it ($X) if the position is known)"
            )
            return self._not_raised(
                f"the controller is in {state} after the reset (position lost); {leave}"
            )
        if state.startswith("Door"):
            return self._not_raised(
                f"the safety door is open ({state}) and GRBL moves nothing while it is; "
                f"close it, then {self._raise_it()}"
            )
        if state != "Idle":
            return self._not_raised(f"the controller reports {state} after the reset, not Idle")
        profile = self.options.profile
        if self._servo():
            return self._lift_servo(profile)
        if held is None:
            return self._not_raised(
                "the machine did not report standing still (Hold:0 or Idle) before the "
                "reset, so its position may be lost; jog Z up"
            )
        return self._lift_z(status, frame, profile)

    def _status_after_reset(self) -> Status:
        """A status report after the reset, with the machine position where reports give it.

        A reset may clear G92 (Grbl 1.1's ``gc_init``), so the work offset from before
        no longer turns a ``WPos`` into a machine position: only a report's own ``WCO``
        does (Grbl sends one in the first report after a reset). ``MPos`` needs none.
        """
        self._wco, self._wco_printed = None, False
        period = 1.0 / min(self.options.poll_hz, 5.0)
        status = self._status_now()
        for _ in range(11):  # Grbl adds WCO to every 10th report while Idle
            if status.mpos is not None or status.state != "Idle":
                break
            time.sleep(max(0.0, self._last_poll + period - time.monotonic()))
            status = self._status_now()
        return status

    def _lift_servo(self, profile: MachineProfile | None) -> _Lifted:
        """The servo's up command after the reset (which switched the spindle output off)."""
        up = self._servo_up()
        block = strip_block(up)
        if block_words(block) == [("M", 5.0)]:
            self._tell(
                "the soft reset switched the spindle output off (M5), the up command of "
                "this servo job: the scribe is up"
            )
            return _Lifted("; the reset's M5 lifted the scribe", {"result": "reset", "up": "M5"})
        dwell = profile.tool_control.dwell_s if profile is not None else 0.0
        whose = "the file's" if profile is None else "the profile's"
        self._tell(f"raising the scribe with {whose} up command {up!r}")
        failure = self._send_lift(
            [block, f"G4P{gcode_number(dwell, 3)}"], self.options.command_timeout + dwell
        )
        if failure:
            return self._not_raised(failure, "failed")
        self._tell(f"scribe raised ({up})")
        return _Lifted(f"; scribe raised ({up})", {"result": "raised", "up": block})

    def _lift_z(
        self,
        status: Status,
        frame: tuple[float, float, float] | None,
        profile: MachineProfile | None,
    ) -> _Lifted:
        """Z up to the travel height by a rapid in machine coordinates."""
        program = self._program
        moved = next((b for b in program.blocks if b.unfollowed), None)
        if moved is not None:
            return self._not_raised(
                f"line {moved.lineno} ({moved.unfollowed}) leaves the job's coordinate frame "
                "unknown; jog Z up"
            )
        if frame is None:
            return self._not_raised(
                "the work offset is unknown ($# and the status reports' WCO gave none), so "
                "the travel height cannot be placed in machine coordinates; jog Z up"
            )
        if profile is not None:
            z: float | None = profile.z.safe_mm
        else:
            z = travel_height(program)
        if z is None:
            return self._not_raised(
                "the file shows no travel height (no Z above its cutting height) and no "
                "machine profile was given; jog Z up"
            )
        capped = ""
        if profile is not None and profile.envelope.z_mm != Z_UNLIMITED_MM:
            top = profile.envelope.z_mm[1]
            if z > top:
                z, capped = top, f", capped at the envelope's top Z {top:.3f}"
        # floor to the digits sent: never above the height asked for
        mz = math.floor((z + frame[2]) * 1000.0 + 1e-6) / 1000.0
        limit = _soft_limit_top(self.info.settings)
        if limit is not None and mz > limit[0]:
            mz, capped = limit
            z = mz - frame[2]
        now = status.mpos
        if now is None:
            if status.wpos is not None:
                return self._not_raised(
                    "the status reports after the reset give the work position (WPos, $10=0) "
                    "without the WCO field (a build without it), so the machine position is "
                    "unknown; jog Z up (with $10=1, MPos reports, the tool is raised)"
                )
            return self._not_raised(
                "the status reports after the reset gave no machine position (MPos, or "
                "WPos with WCO); jog Z up"
            )
        record: dict[str, Any] = {
            "z": round(z, 4),
            "machine_z": mz,
            "from_machine_z": round(now[2], 4),
        }
        # the work Z, and the machine Z where the work offset makes it another number
        height = f"Z {z:.3f}" + (f" (machine Z {mz:.3f})" if f"{z:.3f}" != f"{mz:.3f}" else "")
        if now[2] >= mz - 0.001:
            self._tell(
                f"the tool is at machine Z {now[2]:.3f}, already at or above the travel "
                f"height {height}{capped}: not moved"
            )
            return _Lifted("; the tool was already up", {"result": "up", **record})
        self._tell(f"raising the tool to {height}{capped}")
        rate = self.info.settings.get(112) or DEFAULT_RAPID_MM_MIN[2]
        timeout = self.options.command_timeout + 3.0 * 60.0 * (mz - now[2]) / rate
        failure = self._send_lift([f"G21G53G0Z{gcode_number(mz, 3)}", END_WAIT], timeout)
        if failure:
            return self._not_raised(failure, "failed")
        final = self.status.mpos
        if final is None or abs(final[2] - mz) > 0.01:
            where = "unknown" if final is None else f"{final[2]:.3f}"
            return self._not_raised(
                f"after the lift the controller reports machine Z {where}, not {mz:.3f}",
                "failed",
            )
        self._tell(f"tool raised to {height}")
        return _Lifted(f"; tool raised to {height}", {"result": "raised", **record})

    def _send_lift(self, lines: Sequence[str], timeout: float) -> str:
        """Send the lift's lines one at a time, then wait for Idle; "" or why it failed.

        The last line is a dwell, answered once the motion before it has run. A timeout
        holds and resets the machine where it is; an alarm gets the reset GRBL asks for
        (it stays locked); nothing is sent again.
        """
        deadline = time.monotonic() + timeout
        answered_at = 0.0
        for k, text in enumerate(lines):
            self._write(text.encode("ascii") + b"\n")
            self.sent_log.append(text)
            answered = False
            while not answered or (k == len(lines) - 1 and not self._idle_since(answered_at)):
                if time.monotonic() > deadline:
                    self._halt_lift()
                    return (
                        f"the lift ({' '.join(lines)}) did not finish within {timeout:.1f} s; "
                        "feed hold and soft reset sent, the tool stopped where it was"
                    )
                self._poll(force=answered and self._last_poll < answered_at)
                for line in self._read_lines(0.02):
                    if line == "ok":
                        answered, answered_at = True, time.monotonic()
                    elif line.startswith("error:"):
                        code = _code(line)
                        return f"GRBL answered error:{code} ({error_meaning(code)}) to {text!r}"
                    elif line.startswith("ALARM:"):
                        code = _code(line)
                        with contextlib.suppress(_Fault):
                            self._write(REALTIME_RESET)
                            self._wait_banner(self.options.banner_timeout)
                        return (
                            f"ALARM:{code} ({alarm_meaning(code, self._find_again())}) on {text!r}; "
                            "soft reset "
                            "sent, the controller stays locked: check the machine: "
                            f"{self._leave_alarm(None, 'home it ($H) or unlock it ($X)')}"
                        )
                    elif line.startswith("<"):
                        self._note_status(line)
                        if self.status.state.startswith("Door"):
                            return (
                                f"the safety door opened during the lift ({self.status.state}); "
                                "close it and press cycle start to finish raising the tool"
                            )
                    elif banner_firmware(line):
                        return "the controller reset itself during the lift"
        return ""

    def _idle_since(self, when: float) -> bool:
        """The last status report says Idle and came after ``when``."""
        return when > 0.0 and self.status.state == "Idle" and self.status.time > when

    def _halt_lift(self) -> None:
        """Stop a lift where it is (:meth:`_hold_briefly_then_reset`, nothing raised)."""
        with contextlib.suppress(Exception, KeyboardInterrupt):
            self._hold_briefly_then_reset()

    def _hold_briefly_then_reset(self) -> Status | None:
        """Feed hold, a short wait for ``Hold:0``, soft reset and its banner.

        A Ctrl-C or a fault cuts the wait short, and the banner's wait is not checked; both
        writes go out even if Ctrl-C comes meanwhile.

        Returns:
            The held status, or None where none came.

        Raises:
            _Fault: The hold or the reset could not be written (the port is gone).
        """
        self._write_surely(REALTIME_HOLD)
        try:
            held = self._wait_held(min(self.options.hold_timeout, 5.0))
        except (Exception, KeyboardInterrupt):
            held = None
        self._write_surely(REALTIME_RESET)
        with contextlib.suppress(Exception, KeyboardInterrupt):
            self._wait_banner(self.options.banner_timeout)
        return held

    def _reset(
        self,
        reason: str,
        report: Status | None,
        lifted: _Lifted | None = None,
    ) -> None:
        self._write(REALTIME_RESET)
        self._wait_banner(self.options.banner_timeout)
        self._journal_stop(reason, self._executed_guess(report), lifted)

    def _executed_guess(self, report: Status | None) -> int:
        """The last acknowledged block that surely ran, judged from the position at the stop.

        The controller may still hold up to ``planner_blocks`` motion blocks, and its
        stepper a few more (:func:`last_surely_run`), after the last acknowledgement; an
        acknowledged sync block (a spindle change, G4, ...; an S change only with laser
        mode ``$32`` known off) means everything before it ran. The first candidate move
        the hold position (``report``'s work position) may lie on is the interrupted one:
        within :meth:`_step_tol` of its line (GRBL reports whole steps, up to a step off
        the sender's line on each axis; an unknown step counted as COARSE_STEP_MM), of its
        start, or of its end short of where it surely ended (:meth:`_at_end`), unless its
        steps show the machine is not on it (:meth:`_off_move`); a wider match only finds
        an earlier move (cut again). Standing at the end of the last candidate, every
        candidate ran. Without a position or a match the earliest candidate is taken as
        interrupted (a stroke is cut again rather than skipped), and so is a candidate
        move whose path the sender does not follow (:func:`followed_move`: an arc, G28,
        G53, a move whose start is not known after a change of the work frame...: the
        machine may stand anywhere in it, even on a later move's segment), and a resumed
        session's first move unless the machine stands at its end (it may still be on the
        resume preamble's moves, which the sender does not follow). Only blocks
        acknowledged before the position report can match it: a later block passing
        through the same point (an old report) had not run. Once END_WAIT is acknowledged
        every acknowledged block ran, and so did every block up to the last rest.
        """
        acked = self._acked_blocks
        if not acked:
            return -1
        if self._all_ran:
            return acked[-1]
        blocks = self._program.blocks
        surely = last_surely_run(
            blocks, acked, self.info.planner_blocks, self.info.laser_mode, self._step_mm()
        )
        surely = max(surely, self._rested_through)  # Idle there (:meth:`_rest_at`)
        window = [i for i in acked if i > surely]
        wpos = None if report is None else report.wpos
        if report is None or wpos is None or self._acks_at_status == 0:
            return surely
        reported = [i for i in window if i <= acked[self._acks_at_status - 1]]
        tol = self._step_tol(COARSE_STEP_MM)
        moves = [i for i in reported if blocks[i].motion]
        counted = steps_counted_until(blocks)
        # a resumed session's first move: the machine may still be on the resume preamble's
        # moves (not the file's), which may cross a later move
        resumed = next((j for j in acked if blocks[j].motion), -1) if acked[0] > 0 else -1
        for i in moves:
            if not followed_move(blocks, i):  # an arc, G28, a move after G55...
                return i - 1
            steps = self._move_steps(i, report) if i < counted else None
            end = self._at_end(i, report, steps)
            if end == "ran" or _off_move(steps):
                continue  # the next move's start, or the check below, takes it
            if (
                end == "short"
                or i == resumed
                or along_move(blocks, i, wpos, tol) is not None
                or (i > 0 and stands_at_end(blocks[i - 1], wpos, tol))  # at its start
            ):
                return i - 1
        last = moves[-1] if moves else -1
        if last >= 0:
            steps = self._move_steps(last, report) if last < counted else None
            if self._at_end(last, report, steps) == "ran" and stands_at_end(
                blocks[last], wpos, tol
            ):
                return reported[-1]
        return surely

    def _move_steps(self, i: int, report: Status) -> list[_AxisSteps] | None:
        """Move ``i`` and ``report``'s position per axis in GRBL's whole steps.

        GRBL ends a move on whole steps: its target in machine mm (work plus the work
        offset ``WCO``) times ``$100``-``$102``, rounded (``lround``), and reports the steps
        it stands on. Each is known to a span of steps (:func:`step_span`): the report's
        ``WCO`` and ``MPos`` are rounded to a digit (0.001 mm; 0.00254 mm in inch reports),
        a machine position counted as ``WPos`` plus ``WCO`` to two. The start of the
        session's first move is not counted (a resume preamble's end). An offset summed from
        ``$#`` (no report printed ``WCO:`` yet: a build without the field, or early in a
        job) adds up to three rounded parts (the system's, G92, the tool length offset).
        None where a step or the report's offset is not known, or the position lies on no
        step (the offset is not the one the machine ran under). The steps learnt at rest
        (:meth:`_rest_at`) narrow the offset, and tell the step of a target met there.
        """
        if report.wco is None or report.wpos is None or min(self._step_mm()) <= 0.0:
            return None
        blocks = self._program.blocks
        end = self._session_xyz(i)
        # a session's first move starts where the resume preamble took the machine, its
        # numbers rounded to 4 decimals: maybe not block i - 1's step
        first = i == next((j for j in self._acked_blocks if blocks[j].motion), i)
        start = self._session_xyz(i - 1) if i > 0 and not first else (None, None, None)
        out = []
        for k in range(3):
            at = self._report_steps(k, report)
            if at[0] > at[1]:
                return None
            u, v = start[k], end[k]
            ends = [None if e is None else self._target_steps(k, e, report) for e in (u, v)]
            way = 0 if u is None or v is None else (v > u) - (v < u)
            out.append(_AxisSteps(at, ends[0], ends[1], way))
        return out

    def _offset_window(self, k: int, report: Status) -> tuple[float, float]:
        """The work offset's span (mm) on axis ``k``: ``report``'s, narrowed by the rests.

        ``report``'s ``WCO`` is rounded to a digit (0.001 mm; 0.00254 mm in inch reports);
        one summed from ``$#`` (no report printed ``WCO:`` yet: a build without the field,
        or early in a job) adds up to three rounded parts (the system's, G92, the tool
        length offset). Each rest (a target ``t`` whose step ``n`` was seen) puts the
        offset where ``t`` rounds to ``n`` (GRBL's ``lround``, in single precision: its
        error grows with ``t`` and the offset, not with their sum). Where
        they leave no offset (one changed behind the sender's back), none is counted.
        """
        assert report.wco is not None
        digit = REPORT_DIGIT_MM[self.info.inch_reports]
        w = report.wco[k]
        off = digit / 2.0 if report.wco_printed else 1.5 * digit
        step = self._step_mm()[k]
        lo, hi = w - off, w + off
        for t, n in self._rests[k].items():
            slack = FLOAT32_SLACK * (abs(t) + abs(w) + 1.0)
            lo, hi = max(lo, (n - 0.5) * step - t - slack), min(hi, (n + 0.5) * step - t + slack)
        return (lo, hi) if lo <= hi else (w - off, w + off)

    def _target_steps(self, k: int, mm: float, report: Status) -> tuple[int, int]:
        """The steps (first, last) GRBL may round work target ``mm`` on axis ``k`` to.

        A target the machine was seen at rest on (:meth:`_rest_at`) is that step: GRBL
        reckons the same number under the same offset the same way.
        """
        if mm in self._rests[k]:
            n = self._rests[k][mm]
            return n, n
        lo, hi = self._offset_window(k, report)
        w = (lo + hi) / 2.0
        # GRBL sums target and offset in single precision: an error of the operands' size
        # (a work X290 with an offset of -290 lands near 0 but is rounded as 290 is)
        f32 = FLOAT32_SLACK * (abs(mm) + abs(w) - abs(mm + w))
        return step_span(mm + w, (hi - lo) / 2.0 + f32, self._step_mm()[k], True)

    def _report_steps(self, k: int, report: Status) -> tuple[int, int]:
        """The steps (first, last) ``report``'s position on axis ``k`` may stand for.

        ``MPos`` is rounded to a digit; a machine position counted as ``WPos`` plus the
        offset is known to the offset's span as well (:meth:`_offset_window`).
        """
        assert report.wpos is not None and report.wco is not None
        half = REPORT_DIGIT_MM[self.info.inch_reports] / 2.0
        step = self._step_mm()[k]
        if report.mpos_given:
            return step_span(report.wpos[k] + report.wco[k], half, step)
        lo, hi = self._offset_window(k, report)
        return step_span(report.wpos[k] + (lo + hi) / 2.0, half + (hi - lo) / 2.0, step)

    def _wants_rest(self, j: int) -> bool:
        """Whether to feed nothing after block ``j`` until the machine rests at its end.

        So where GRBL's rounding of a target to a step is open on an axis (a stop at that
        end could not be told from one a step short of it, and its move would be cut
        again), with the tool up after it (:func:`_tool_down`), while rests are left (``StreamOptions.rests``): a followed move before
        the steps stop telling (:func:`steps_counted_until`), where a report tells its
        step, and the rest narrows the offset or the target is met again later (a rest
        that tells nothing more is not taken).
        """
        blocks = self._program.blocks
        if (
            self._rests_left <= 0
            or self._wco is None
            or min(self._step_mm()) <= 0.0
            or not blocks[j].motion
            or not self._program.strokes  # where the tool is, is not known
            or j in self._down  # the tool stays down and still while the machine rests
            or j >= self._counted
            or not followed_move(blocks, j)
        ):
            return False
        report = Status(wco=self._wco, wco_printed=self._wco_printed)
        step = self._step_mm()
        # a report tells the step where its rounding is finer than a step (a WPos report
        # counts the offset's as well, :meth:`_report_steps`)
        digit = REPORT_DIGIT_MM[self.info.inch_reports]
        seen = digit if self.status.mpos_given else 4.0 * digit
        for k, t in enumerate(self._session_xyz(j)):
            if t is None or t in self._rests[k] or seen >= step[k] or j < self._given_from[k]:
                continue
            first, last = self._target_steps(k, t, report)
            lo, hi = self._offset_window(k, report)
            flip = (first + 0.5) * step[k] - t  # the offset where t's step turns to first + 1
            slack = 2.0 * FLOAT32_SLACK * (abs(t) + abs(flip) + 1.0)
            if last > first + 1 or (
                last > first and (lo + slack < flip < hi - slack or t in self._repeated[k])
            ):
                self._rests_left -= 1
                return True
        return False

    def _rest_at(self, report: Status) -> bool:
        """Learn the steps of the resting block's end from ``report``, once it shows them.

        The machine stands at the end of the block rested at (the last one sent) once it
        is acknowledged and a later report than the first after its answer says Idle:
        GRBL answers a move once it is queued, and Idle has nothing queued, but the first
        report may come from the pass that answered it, before that pass starts the cycle
        (``protocol_auto_cycle_start``: its report comes first). Each axis whose target is
        known and whose step the report tells is kept (:meth:`_target_steps`), where a
        block of the session gave it (GRBL's target; not the position the job was placed
        at, which the machine stands on unrounded: :func:`_first_given`).

        Returns:
            Whether the rest is over (learnt, or the block was not the last answered).
        """
        acked = self._acked_blocks
        if self._inflight or not acked or self._acks_at_status < len(acked):
            return False
        if acked[-1] != self._resting:
            return True  # not met (cannot happen: nothing is sent after it)
        self._rest_reports += 1
        if report.state != "Idle" or self._rest_reports < 2:
            return False
        self._rested_through = self._resting  # it and every block before it ran
        if report.wpos is None or report.wco is None:
            return True
        for k, t in enumerate(self._session_xyz(self._resting)):
            at = self._report_steps(k, report)
            if t is not None and at[0] == at[1] and self._resting >= self._given_from[k]:
                self._rests[k][t] = at[0]
        return True

    def _session_xyz(self, j: int) -> tuple[float | None, float | None, float | None]:
        """Where block ``j`` leaves the machine (work mm) in this session, where known.

        As :func:`known_xyz`, but a resumed session starts where the resume preamble took
        the machine, its numbers written to 4 decimals, and GRBL keeps them on each axis no
        block of the session has given since (a plunge's X and Y, a cut along Y's X): where
        the file's number has more decimals (X0.00006 written X0.0001, maybe another step)
        that axis is not known there.
        """
        blocks = self._program.blocks
        xyz = list(known_xyz(blocks[j].modal))
        first = self._acked_blocks[0] if self._acked_blocks else 0
        if first == 0:  # a stream from the top: no preamble
            return xyz[0], xyz[1], xyz[2]
        for k, (axis, v) in enumerate(zip("XYZ", xyz, strict=True)):
            if v is None or float(gcode_number(v, 4)) == v:
                continue
            given = any(
                a == axis for b in blocks[j : first - 1 : -1] for a, _ in block_words(b.text)
            )
            xyz[k] = v if given else None
        return xyz[0], xyz[1], xyz[2]

    def _at_end(self, i: int, report: Status, steps: list[_AxisSteps] | None = None) -> str:
        """Where ``report``'s work position stands about move ``i``'s end.

        In whole steps where they are known (``steps``, :meth:`_move_steps`): GRBL's
        stepper steps the axis with the most steps at every step of a move, so the move
        ran where that axis stands at its end, or has gone on past it (each of the axes
        that may have the most, where rounding leaves that open; an axis whose position is
        unknown at an end never has). Elsewhere by mm on every axis the move moves
        (:meth:`_reached`). A stop short of the end stands within :meth:`_step_tol` of it
        on the moved axes, and within half a step and a report's rounding on the others.

        Returns:
            ``"ran"`` (at its end), ``"short"`` (maybe stopped a step or so before it),
            or ``""`` (neither).
        """
        blocks = self._program.blocks
        p = report.wpos
        assert p is not None
        end = known_xyz(blocks[i].modal)
        before = known_xyz(blocks[i - 1].modal) if i > 0 else (None, None, None)
        given = {letter for letter, _ in block_words(blocks[i].text)}
        moved = [  # an axis the block gives, unknown at an end, may move too
            k
            for k, (a, u, v) in enumerate(zip("XYZ", before, end, strict=True))
            if u != v or (a in given and None in (u, v))
        ]
        still = [k for k in range(3) if k not in moved]
        if steps is not None:
            if all(_step_reached(steps[k]) for k in _most_steps(steps, moved)):
                return "ran"
        elif all(self._reached(i, k, p[k]) for k in moved):
            return "ran"

        def near(axes: list[int], tol: float) -> bool:
            """Within ``tol`` of the end on ``axes`` (the others taken as at it)."""
            q = [e if e is not None and k not in axes else p[k] for k, e in enumerate(end)]
            return stands_at_end(blocks[i], q, tol)

        coarse = self._step_mm(COARSE_STEP_MM)
        off = 0.002 + max((coarse[k] for k in still), default=0.0) / 2.0
        return "short" if near(moved, self._step_tol(COARSE_STEP_MM)) and near(still, off) else ""

    def _reached(self, i: int, k: int, v: float) -> bool:
        """Whether axis ``k`` at ``v`` (work mm) is at move ``i``'s end there, or past it.

        By mm, where the steps are not known (:meth:`_move_steps`). Past it in the move's
        direction; either way where its start is not known. Never where the end is not
        known (an axis counted from the assumed start, as ``sender_program``'s placement
        counts it). GRBL ends a move within half a step of the sender's end; anywhere
        else on the move it stands at least a step behind that end on the axis with the
        most steps, so at least half a step behind the sender's end there, less the
        reports' rounding (a digit, ``MPos`` less ``WCO``: 0.001 mm, 0.00254 mm in inch
        reports). 0.002 mm at least: with steps of 0.006 mm or less, or unknown, a stop a
        step short may pass for the end here, short by less than the 0.01 mm a match
        allows for rounding.
        """
        blocks = self._program.blocks

        def known(j: int) -> float | None:
            return known_xyz(blocks[j].modal)[k] if j >= 0 else None

        end, start = known(i), known(i - 1)
        if end is None:
            return False
        digit = REPORT_DIGIT_MM[self.info.inch_reports]
        tol = max(0.002, self._step_mm()[k] / 2.0 - digit)
        if start is None:
            return abs(v - end) < tol
        return (v - end) * math.copysign(1.0, end - start) > -tol


#: Relative error allowed for GRBL's single-precision arithmetic (a float's 6e-8, a few
#: operations, a margin): a position or target's step is counted from it.
FLOAT32_SLACK = 1e-6


class _AxisSteps(NamedTuple):
    """One axis of a move in whole steps, each a span (first, last) of the steps it may be."""

    at: tuple[int, int]  # where the report puts the machine
    start: tuple[int, int] | None  # GRBL's end of the move before (None: not known)
    end: tuple[int, int] | None  # GRBL's end of the move (None: not known)
    way: int  # the sender's direction (1, -1; 0: one target, no step, or not known)


def step_span(mm: float, slack: float, step: float, rounded: bool = False) -> tuple[int, int]:
    """The whole steps (first, last) a machine coordinate known to ``slack`` mm may stand for.

    Args:
        mm: The machine coordinate (mm).
        slack: How far the true coordinate may lie from ``mm`` (a report's rounding).
        step: The axis's step (mm, ``1 / $10x``; > 0).
        rounded: ``mm`` is a target GRBL rounds to its nearest step (``lround``, in
            single precision); else a position on a step, reported to ``slack``.

    Returns:
        The span of steps; first > last where no step lies within ``slack`` of ``mm``.
    """
    margin = slack + FLOAT32_SLACK * (abs(mm) + 1.0)
    lo, hi = (mm - margin) / step, (mm + margin) / step
    if rounded:
        return math.ceil(lo - 0.5), math.floor(hi + 0.5)  # a half: either step
    return math.ceil(lo), math.floor(hi)


def _step_count(axis: _AxisSteps) -> tuple[float, float]:
    """The fewest and most steps the move may take on ``axis`` (unknown: up to inf)."""
    if axis.start is None or axis.end is None:
        return 0.0, math.inf
    if axis.way == 0:  # one target: one step
        return 0.0, 0.0
    (s0, s1), (e0, e1) = axis.start, axis.end
    return float(max(e0 - s1, s0 - e1, 0)), float(max(e1 - s0, s1 - e0))


def _most_steps(steps: list[_AxisSteps], moved: list[int]) -> list[int]:
    """The moved axes that may take the most steps of the move (GRBL steps them every time).

    Empty where the move takes no step on any axis (GRBL drops it: nothing to run), so it
    ran wherever the machine stands.
    """
    counts = [_step_count(a) if k in moved else (0.0, 0.0) for k, a in enumerate(steps)]
    least = max(lo for lo, _ in counts)
    return [k for k in moved if counts[k][1] > 0 and counts[k][1] >= least]


def _step_reached(axis: _AxisSteps) -> bool:
    """Whether ``axis`` stands at the move's end, or past it in its direction, in whole steps.

    Either way where the start is not known: only surely at it. Never where the end is
    not known.
    """
    if axis.end is None:
        return False
    (a0, a1), (e0, e1) = axis.at, axis.end
    if axis.start is None:
        return a0 == a1 == e0 == e1
    return a0 >= e1 if axis.way > 0 else a1 <= e0


def _off_move(steps: list[_AxisSteps] | None) -> bool:
    """Whether the steps show the machine is off the move: on an axis, beyond both ends.

    GRBL's stepper moves each axis from the move's start step to its end step, one way.
    False where the steps are not known.
    """
    if steps is None:
        return False
    for axis in steps:
        if axis.start is not None and axis.end is not None:
            lo, hi = min(axis.start[0], axis.end[0]), max(axis.start[1], axis.end[1])
            if axis.at[1] < lo or axis.at[0] > hi:
                return True
    return False


def steps_counted_until(blocks: Sequence[Block]) -> int:
    """The first block from which a stop's steps are not matched (:meth:`Streamer._move_steps`).

    Where a block changes the work offset (G10, G92, G92.1, another G54-G59 system, a tool
    length offset) a report's ``WCO`` may be an older frame's than the move's where a
    build does not report it (every change makes Grbl 1.1 send it). From a G91 block on
    GRBL sums increments in single precision, which may drift by more than the match
    allows. Before any of these, whole steps tell.
    """
    before = Modal()
    for j, b in enumerate(blocks):
        m = b.modal
        if (
            m.relative
            or m.wcs != before.wcs
            or m.z_frame != before.z_frame
            or (m.tlo or 0.0) != (before.tlo or 0.0)  # a header's G49: GRBL's 0 kept
            or _SETS_OFFSET.search(b.text)
        ):
            return j
        before = m
    return len(blocks)


def _first_given(blocks: Sequence[Block], start: int) -> tuple[int, int, int]:
    """Per axis, the first motion block from ``start`` on that gives it (len: none).

    Before it the axis stands where the session found it (a stream from the top, placed
    there: :meth:`Program.placed_at`). A resumed session's preamble gives every axis
    before block ``start``.
    """
    if start > 0:
        return start, start, start
    first = [len(blocks)] * 3
    for b in blocks:
        if b.motion:
            for letter, _ in block_words(b.text):
                k = "XYZ".find(letter)
                if k >= 0:
                    first[k] = min(first[k], b.index)
    return first[0], first[1], first[2]


def _tool_down(strokes: Sequence[tuple[int, int]]) -> frozenset[int]:
    """The blocks after which the tool is down: a stroke's tool-down block up to its end.

    A stroke (first, last) lowers the tool at ``first`` and raises it at ``last``: after
    any block from ``first`` to ``last - 1`` the tool touches the board (a plunge's end,
    a cut's), where a drag tool held still marks it.
    """
    return frozenset(j for first, last in strokes for j in range(first, last))


def _repeated_targets(blocks: Sequence[Block]) -> tuple[set[float], ...]:
    """Per axis, the work targets (mm) that two or more motion blocks move that axis to."""
    seen: list[set[float]] = [set(), set(), set()]
    again: list[set[float]] = [set(), set(), set()]
    before: tuple[float | None, ...] = (None, None, None)
    for b in blocks:
        xyz = known_xyz(b.modal)
        if b.motion:
            for k, v in enumerate(xyz):
                if v is not None and v != before[k]:
                    (again if v in seen[k] else seen)[k].add(v)
        before = xyz
    return again[0], again[1], again[2]


#: G10 and G92 (G92.1 too) in a block's text (upper case, no spaces).
_SETS_OFFSET = re.compile(r"G0*(?:10|92)(?![0-9])")


def _soft_limit_top(settings: dict[int, float]) -> tuple[float, str] | None:
    """The highest machine Z a lift may go to under soft limits, and the clause saying so.

    None with soft limits off (``$20=0``). Grbl 1.1h's soft limits allow up to machine Z 0,
    which with hard limits on (``$21=1``) is where homing found the Z switch (it then
    pulls off by ``$27``), so a move there can trip it: ``ALARM:1``, position lost; grblHAL
    with hard limits on puts its soft-limit top at ``-$27`` itself. With ``$21=1`` the
    top is therefore the pull-off position ``-$27`` (GRBL's default 1 mm where unknown).
    """
    if not settings.get(20):
        return None
    if not settings.get(21):
        return 0.0, ", capped at machine Z 0.000, the top of GRBL's soft-limit travel"
    pulloff = max(0.0, settings.get(27, 1.0))
    top = math.floor(-pulloff * 1000.0 + 1e-6) / 1000.0
    return top, (
        f", capped at machine Z {top:.3f}, the homing pull-off ($27) below the Z limit "
        "switch (hard limits are on, $21=1)"
    )


def _clause(lifted: _Lifted | None) -> str:
    """The stop message's clause about the tool ("" with the lift off)."""
    return "" if lifted is None else lifted.text


def _journaled(lifted: _Lifted | None) -> dict[str, Any]:
    """The stop event's ``lift`` field (none with the lift off)."""
    return {} if lifted is None else {"lift": lifted.record}


def _where(status: Status | None) -> dict[str, Any]:
    """A ``lost`` or ``stop`` event's ``mpos`` and ``wco`` (mm) by the last report, where known.

    A resume compares them with where the controller stands once connected: one that
    reset (an Arduino resets when its port is opened) boots at machine zero
    (:func:`~scratchfab.machine.stream_job.reset_since_last_run`).
    """
    if status is None:
        return {}
    return {
        key: [round(v, 4) for v in xyz]
        for key, xyz in (("mpos", status.mpos), ("wco", status.wco))
        if xyz is not None
    }


def banner_firmware(line: str) -> str | None:
    """``"Grbl"`` or ``"grblHAL"`` if ``line`` is a start-up banner, else None."""
    for prefix, firmware in BANNERS.items():
        if line.startswith(prefix):
            return firmware
    return None


def xyz_text(xyz: Sequence[float]) -> str:
    """``X1 Y-2.5 Z0``: a position or offset in mm for messages."""
    return " ".join(f"{axis}{v:g}" for axis, v in zip("XYZ", xyz, strict=True))


def _interrupt_name(exc: KeyboardInterrupt) -> str:
    """``Ctrl-C``, or the signal's name for a :class:`StopSignal`."""
    return str(exc) if isinstance(exc, StopSignal) else "Ctrl-C"


def _code(line: str) -> int:
    tail = line.partition(":")[2]
    return int(tail) if tail.isdigit() else -1
