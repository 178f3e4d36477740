"""Stream one G-code file to a GRBL controller: the stream stage, without any CLI.

Connects, compares the controller with the machine profile, optionally runs check mode,
asks for confirmation, then streams with the journal that makes ``resume`` possible.
The CLI and the pipeline runner both call :func:`stream_file`; they differ only in the
callbacks they pass.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from scratchfab.console import Confirm, Say, clock, command_line
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.machine.grbl_codes import error_meaning
from scratchfab.machine.protocol_grblsim import grblsim_query, sim_options
from scratchfab.machine.sender import (
    ControllerInfo,
    Streamer,
    StreamFault,
    StreamOptions,
    StreamProgress,
    StreamStopped,
    homing_of,
    machine_coordinates,
    open_port,
    refind,
    work_zero_command,
    xyz_text,
    zero_kept_advice,
)
from scratchfab.machine.sender_checks import (
    compare,
    eta_settings,
    job_extent,
    offset_tolerance_mm,
    same_offset,
)
from scratchfab.machine.sender_journal import (
    Journal,
    check_journal_file,
    default_journal_path,
    done_blocks,
    interrupted,
    last_fresh_start,
    last_session,
    read_journal,
    run_homing,
    run_zero,
    run_zero_in_inches,
    run_zeroed,
    xyz_of,
)
from scratchfab.machine.sender_program import (
    Program,
    check_tool_up_at_end,
    load_program,
    resume_point,
    resume_preamble,
    z_levels,
)
from scratchfab.model.job import JobLayout

if TYPE_CHECKING:
    from scratchfab.export.gcode import GcodeHeader
    from scratchfab.machine.grblsim import SimOptions
    from scratchfab.machine.profile import MachineProfile
    from scratchfab.toolpath import Toolpath


@dataclass(frozen=True)
class StreamRequest:
    """What to stream where, and how.

    Attributes:
        gcode: The G-code file (a ``str`` is taken as a path, as is ``journal``'s).
        port: Serial device, pty path or pyserial URL (``grblsim://...``).
        baud: Baud rate (None: the machine profile's, else 115200).
        protocol: ``"counting"`` or ``"simple"``.
        journal: Journal file (None: JOB/stream/journal.jsonl or beside the G-code).
        resume: Restart at the first stroke not completely done.
        resume_interrupted: Resume when the journal's last run streamed this same file and
            did not finish; otherwise start from the top (the pipeline's stream stage).
        recut_unsure: When resuming: also cut again what the controller acknowledged but
            may not have run before a lost link (a board powered over the USB cable).
        check: Run GRBL check mode ($C) first.
        machine: Machine profile (name, path or loaded) to compare with ``$$`` (None:
            the job's own, else no check).
        margin: RX buffer bytes kept free.
        stall_timeout: Seconds of silence with lines in flight and an Idle controller.
        banner_timeout: Seconds to wait for the banner before a soft reset.
        z_threshold: Tool is down below this Z (None: the profile's, else automatic).
        lift: After a stop (an error, a stall, Ctrl-C's stop, SIGTERM) that ended in a soft
            reset of a machine standing still, raise the tool once the controller is Idle
            (:attr:`StreamOptions.lift`).
        homed: The machine was homed, or its work zero set again, since an alarm or a
            reset of the controller that may have lost its position (:func:`ask_if_homed`).
        zero_here: The tool stands at the board's origin point: once connected, set the
            work zero there with the profile's command (:func:`zero_here_command`: X and
            Y, and Z0 for a tool that is not a servo, touching the surface); on a resume it
            stands for ``homed``.
    """

    gcode: Path
    port: str
    baud: int | None = None
    protocol: str = "counting"
    journal: Path | None = None
    resume: bool = False
    resume_interrupted: bool = False
    recut_unsure: bool = False
    check: bool = False
    machine: str | MachineProfile | None = None
    margin: int = 8
    stall_timeout: float = 10.0
    banner_timeout: float = 2.5
    z_threshold: float | None = None
    lift: bool = True
    homed: bool = False
    zero_here: bool = False

    def __post_init__(self) -> None:
        """Take a path given as ``str`` (a Python caller's habit) as a :class:`Path`."""
        object.__setattr__(self, "gcode", Path(self.gcode))
        if self.journal is not None:
            object.__setattr__(self, "journal", Path(self.journal))


@dataclass(frozen=True)
class StreamCallbacks:
    """How the stream talks to a person.

    Attributes:
        progress: Called with progress reports (lines acknowledged, state, position).
        say: Called with one line per event.
        ask_interrupt: After Ctrl-C and a feed hold: returns "resume" or "stop".
        confirm: Asked before anything moves; False aborts with nothing sent. None: nobody
            is asked (``--yes``): what needs a person's word is refused (a partial board on
            a machine, a G-code of an earlier plan or of a toolpath planned from other
            inputs than there are now, a stream from the top over an unfinished one, a
            resume after an alarm, a controller reset or a lost link that may have lost
            the position unless ``homed``).
        result: Called with the outcome lines (resume point, done); default ``say``.
    """

    progress: Callable[[StreamProgress], Any]
    say: Say
    ask_interrupt: Callable[[], str]
    confirm: Confirm | None
    result: Say | None = None

    def outcome(self, text: str) -> None:
        """Report an outcome line."""
        (self.result or self.say)(text)


#: Off a terminal, a progress line at each tenth of the job and, between tenths, once
#: this many seconds have passed since the last line (an hour's job: about one a minute).
PROGRESS_EVERY_S = 60.0


def progress_text(p: StreamProgress, elapsed_s: float) -> str:
    """One progress line of a stream, for a terminal and a log alike.

    Percent and count of lines the machine has run (GRBL acknowledges a line when it is
    queued; where the report does not tell, those acknowledged), the time since the stream
    started, the time left (``--:--`` unknown), the controller's state and its work
    position (mm) where reported:
    `` 42.0% 420/1000 lines  elapsed 01:05  ETA 03:04  Run X1.00 Y2.00 Z-0.10``.
    The percent is cut, not rounded: ``100.0%`` only once every line has run.
    """
    tenths = 1000 * p.done // p.total if p.total else 1000
    pos = ""
    if p.wpos is not None:
        # rounded first, so that -0.001 shows as 0.00, not -0.00
        x, y, z = (round(v, 2) + 0.0 for v in p.wpos)
        pos = f" X{x:.2f} Y{y:.2f} Z{z:.2f}"
    return (
        f"{tenths / 10:5.1f}% {p.done}/{p.total} lines  elapsed {clock(elapsed_s)}  "
        f"ETA {clock(p.eta_s, up=True)}  {p.state}{pos}"
    )


class ProgressLines:
    """A stream's progress reports as text: every report for a terminal, paced for a log.

    Time counts from the first report (the stream's start, after any confirmation).
    Off a terminal (:meth:`line`) a line comes at each new tenth of the job and between
    tenths once ``every_s`` seconds have passed since the last line; the 100 % line waits
    for the job's end, so that it shows the final state and position (an earlier report's
    position can be seconds old).

    Args:
        every_s: Longest gap between two lines off a terminal (seconds).
        now: The clock (seconds; tests pass their own).
    """

    def __init__(
        self, every_s: float = PROGRESS_EVERY_S, now: Callable[[], float] = time.monotonic
    ) -> None:
        self.every_s = every_s
        self._now = now
        self._start: float | None = None
        self._last_tenth = -1
        self._last_line = -math.inf

    def text(self, p: StreamProgress) -> str:
        """The report's line (:func:`progress_text`), whenever it comes."""
        return self._text(p, self._now())

    def line(self, p: StreamProgress) -> str | None:
        """The report's line when one is due off a terminal, else None."""
        now = self._now()
        text = self._text(p, now)  # starts the clock at the first report, printed or not
        if p.fraction >= 1.0 and not p.final:
            return None
        tenth = int(p.fraction * 10)
        if tenth == self._last_tenth and now - self._last_line < self.every_s:
            return None
        self._last_tenth, self._last_line = tenth, now
        return text

    def _text(self, p: StreamProgress, now: float) -> str:
        if self._start is None:
            self._start = now
        return progress_text(p, now - self._start)


class EmulatorEta:
    """The ETA of a stream to the emulator in the emulator's own time.

    A stream's reports carry machine time as GRBL plans the job, right for a machine. The
    emulator runs that time multiplied by its ``time_scale`` (0.001 in the demo), so beside
    the wall-clock "elapsed" a person expects the ETA to count the emulator's time too: the
    machine time left times ``time_scale``, but no less than its serial line needs for the
    lines left (10 bits a byte at ``baud``), which bounds a fast-forwarded job.
    :meth:`note` says so once, with the machine's time.

    Args:
        options: The emulator's options (:func:`~scratchfab.machine.protocol_grblsim.sim_options`).
        program: The program streamed.
    """

    def __init__(self, options: SimOptions, program: Program) -> None:
        self.time_scale = options.time_scale
        byte_s = 10.0 / options.baud if options.baud > 0 else 0.0
        sizes = [len(b.text) + 1 for b in program.blocks]  # each line and its newline
        left = [0.0] * (len(sizes) + 1)
        for k in range(len(sizes) - 1, -1, -1):
            left[k] = left[k + 1] + sizes[k] * byte_s
        self._link_left = left

    def __call__(self, p: StreamProgress) -> StreamProgress:
        """The report with its ETA in the emulator's time."""
        link = self._link_left[min(max(p.acked, 0), len(self._link_left) - 1)]
        scaled = p.eta_s * self.time_scale if self.time_scale > 0.0 else 0.0  # (inf * 0)
        return replace(p, eta_s=max(scaled, link))

    def note(self, machine_s: float) -> str:
        """The line that says which time the ETA counts (``machine_s``: a machine's ETA)."""
        return (
            f"emulator at time_scale {self.time_scale:g}: elapsed and ETA count its time "
            f"(on a machine: ETA {clock(machine_s)})"
        )


class EmulatorProgress:
    """A progress callback with the ETA in the emulator's time (:func:`emulator_progress`).

    :func:`stream_file` hands it the program it loaded and the line's baud
    (:meth:`prepare`), so the job is read once; a caller that streams otherwise gets the
    program loaded at the first report, timed at ``baud`` (None: 115200).
    """

    def __init__(
        self,
        port: str,
        baud: int | None,
        gcode: Path,
        progress: Callable[[StreamProgress], Any],
        say: Say,
    ) -> None:
        self._port = port
        self._baud = baud or 115200
        self._gcode = gcode
        self._progress = progress
        self._say = say
        self._eta: EmulatorEta | None = None
        self._noted = False

    def prepare(self, program: Program, baud: int) -> None:
        """Use the program streamed and the port's baud (the URL's ``baud`` wins)."""
        options = sim_options(self._port, baud)
        if options is not None:
            self._eta = EmulatorEta(options, program)

    def __call__(self, p: StreamProgress) -> Any:
        """Report ``p`` with its ETA in the emulator's time; the note before the first."""
        if self._eta is None:
            self.prepare(load_program(self._gcode), self._baud)
        eta = self._eta
        if eta is None:  # (a port that sim_options refused streams nothing)
            return self._progress(p)
        if not self._noted and eta.time_scale != 1.0:
            self._noted = True
            self._say(eta.note(p.eta_s))
        return self._progress(eta(p))


def emulator_progress(
    port: str,
    baud: int | None,
    gcode: Path,
    progress: Callable[[StreamProgress], Any],
    say: Say,
) -> Callable[[StreamProgress], Any]:
    """``progress`` with the ETA in the emulator's time for a ``grblsim://`` port.

    For the emulator each report's ETA becomes :class:`EmulatorEta`'s, and before the
    first one ``say`` gets its note (unless time_scale is 1); a machine's port, or a URL
    that :func:`stream_file` will refuse, gets ``progress`` itself. The program and the
    line's baud come from :func:`stream_file`; ``baud`` (None: 115200) serves only a
    caller that streams otherwise (the URL's ``baud`` wins over both).
    """
    try:
        if sim_options(port, 115200) is None:
            return progress
    except ScratchfabError:
        return progress  # stream_file reports the URL's mistake, once
    return EmulatorProgress(port, baud, gcode, progress, say)


#: The rests a stream session may take (:attr:`StreamOptions.rests`): each stops the
#: machine, tool up, for a fraction of a second to learn GRBL's step at a move's end, so
#: that a stop there is matched in whole steps and not cut again on ``--resume``.
REST_LIMIT = 24


def stream_file(req: StreamRequest, cb: StreamCallbacks) -> Path:
    """Stream ``req.gcode``; returns the journal file.

    Raises:
        ScratchfabError: Bad input, a refusal before sending, a check-mode error, or a
            fault while streaming (the machine is left held or reset, never moving).
    """
    journal_file = req.journal or default_journal_path(req.gcode)
    check_journal_file(journal_file, req.gcode)
    planned = _planned(req)
    profile = _profile_for(req, planned, cb.say)
    zero = zero_here_command(profile) if req.zero_here else None
    header = _read_header(req.gcode)
    if header.not_optimized:  # planned so on purpose, or not: said, never refused
        cb.say(f"note: {req.gcode}: this G-code cuts the design's initial layout (not optimized)")
    ask_before_a_partial_board(planned, header, req.gcode, req.port, cb.confirm, cb.say)
    if planned is not None:
        loaded = None if req.machine is None or isinstance(req.machine, str) else profile
        ask_before_a_stale_toolpath(planned, req.gcode, req.port, cb.confirm, cb.say, loaded)
        ask_before_an_earlier_export(planned, header, req.gcode, req.port, cb.confirm, cb.say)
    program = load_program_for(req.gcode, profile, req.z_threshold)
    if not program.blocks:
        raise ScratchfabError(f"{req.gcode}: no G-code lines to send")
    check_tool_up_at_end(program)
    if zero is not None and " Z" in zero[1]:
        _check_raised_first(program, req.gcode)
    journal = Journal(journal_file).open()  # locked: a second stream of this job refuses
    try:
        _stream_locked(req, cb, journal, program, profile, zero)
    except BaseException:
        with contextlib.suppress(ScratchfabError):
            journal.close(remove_if_empty=True)
        raise
    journal.close(remove_if_empty=True)
    return journal_file


def _stream_locked(
    req: StreamRequest,
    cb: StreamCallbacks,
    journal: Journal,
    program: Program,
    profile: MachineProfile | None,
    zero: tuple[str, str] | None = None,
) -> None:
    """:func:`stream_file` once the journal is open and locked.

    ``zero``: ``--zero-here``'s (point, command) (:func:`zero_here_command`), else None.
    """
    journal_file = journal.path
    start = 0
    preamble: list[str] = []
    events = None
    lost = False  # warn of a lost position once connected and at the end
    homing: bool | None = None  # GRBL's $22 (None: not known)
    asked = False  # the journal's alarm or stop already put the lost-position question
    if req.resume and journal.created:
        raise ConfigError(
            f"{journal_file}: no journal to resume from (stream without --resume first)"
        )
    if not journal.created:
        try:
            events = read_journal(journal_file)
        except ConfigError:
            if req.resume or req.resume_interrupted:
                raise  # only a fresh stream can do without its journal
    unfinished = events is not None and interrupted(events, program.sha256)
    resume = req.resume or (req.resume_interrupted and unfinished)
    again = ""  # the question's clause for a stream from the top over an unfinished one
    if not resume and unfinished:
        assert events is not None
        before = _unfinished_run(events, program, journal_file)
        _refuse_from_the_top(before, journal_file, cb.confirm)
        cb.say(
            f"warning: {journal_file} shows an unfinished stream of this file; this run starts "
            f"again from the top ({before.resume_does})"
        )
        if before.cut:
            again = (
                " from the top, cutting again what the unfinished stream cut "
                f"({before.resume_does})"
            )
    if resume:
        assert events is not None  # a resume reads the journal or raises
        _check_strokes(program, req.gcode)
        trusted = done_blocks(events, program.sha256, journal_file, program=program)
        cautious = done_blocks(
            events, program.sha256, journal_file, recut_unsure=True, program=program
        )
        blind = done_blocks(
            events, program.sha256, journal_file, program=program, recut_unclosed=False
        )
        _say_unclosed(program, blind - trusted, cb.outcome)
        _say_unsure(program, trusted - cautious, req.recut_unsure, cb.outcome)
        done = cautious if req.recut_unsure else trusted
        start = resume_point(program, done)
        if start >= len(program.blocks):
            # closes the run: the next one is fresh
            journal.start(program, resume=True, start=start, protocol=req.protocol)
            journal.write("end", complete=True)
            cb.outcome(
                f"{req.gcode}: every line is done according to {journal_file}; nothing to do"
            )
            return
        homing = run_homing(events)  # GRBL's $22 as the run resumed read it
        lost = ask_if_homed(events, req.homed, req.port, cb.confirm, cb.say, profile, homing, zero)
        asked = _lost_event(events) is not None
        preamble = resume_preamble(program, start)
        n_done = sum(1 for a, b in program.strokes if all(i in done for i in range(a, b + 1)))
        cb.outcome(
            f"resuming at line {program.blocks[start].lineno} "
            f"({n_done} of {len(program.strokes)} strokes done); preamble: {' '.join(preamble)}"
        )
    options = StreamOptions(
        protocol=req.protocol,
        margin=req.margin,
        rx_buffer=profile.serial.rx_buffer_bytes if profile is not None else None,
        stall_timeout=req.stall_timeout,
        banner_timeout=req.banner_timeout,
        rests=REST_LIMIT,
        lift=req.lift,
        profile=profile,
    )
    baud = req.baud or (profile.serial.baud if profile is not None else 115200)
    if isinstance(cb.progress, EmulatorProgress):
        cb.progress.prepare(program, baud)
    ser = open_port(req.port, baud)
    try:
        streamer = Streamer(ser, options, cb.progress, cb.say, cb.ask_interrupt)
        info = streamer.connect()
        cb.say(
            f"connected: {info.firmware} {info.version}, RX buffer {info.rx_buffer} bytes, "
            f"state {info.status.state}"
        )
        if resume and events is not None:
            inches = info.inch_reports
            if zero is None:  # (--zero-here sets it anew)
                _check_same_zero(events, info.wco, info.g92, journal_file, cb.say, inches, profile)
            if homing is None:  # not recorded (an older journal): as read now
                homing = homing_of(info.settings)
            inches = inches or run_zero_in_inches(events)
            spans = (info.settings.get(130), info.settings.get(131))  # homing's X/Y space
            found = reset_since_last_run(
                events,
                info.status.mpos,
                info.wco,
                homing,
                inches,
                program,
                spans,
                info.settings.get(27),
            )
            reset = None if asked else found
            if reset is not None:  # asked here, connected, before anything moves
                events = [*events, reset]
                lost = ask_if_homed(
                    events, req.homed, req.port, cb.confirm, cb.say, profile, homing, zero
                )
            if lost:
                _say_lost_position(events, cb.say, profile=profile, homing=homing)
        booted = None if resume or zero is not None else booted_zero_warning(info, profile)
        if booted is not None:
            cb.say(f"warning: {booted}")
        program = program.timed_for(eta_settings(info.settings, profile))  # the ETA's times
        wco, wpos = info.wco, info.status.wpos
        if zero is not None:
            wco, wpos = _zeroed_here(info, zero[1])
            if resume and events is not None and not info.booted:
                kept = lost_position_warning(events, profile, homing) is None
                _ask_zero_moved(events, wco, info, kept, cb.confirm)
        wpos = wpos if start == 0 else None  # a fresh stream starts there
        findings = compare(
            info.settings,
            wco,
            program,
            profile,
            grbl_seconds=program.total_seconds,
            start_xy=None if wpos is None else wpos[:2],
            wcs=info.wcs,
            tlo=info.tlo,
        )
        for text in findings.warnings:
            cb.say(f"warning: {text}")
        if findings.refusals:
            for text in findings.refusals[:-1]:
                cb.say(f"refused: {text}")
            travel = any("travel" in text for text in findings.refusals)
            hint = travel_hint(req.port, info.settings, program, profile) if travel else ""
            raise ScratchfabError(f"{findings.refusals[-1]} (nothing was sent){hint}")
        if zero is not None:  # before check mode, whose soft limits count from the zero
            if cb.confirm is not None:
                first = _first_travel(program) if start == 0 else None
                _ask_zero_here(zero, cb.confirm, "nothing was sent", first)
            assert wco is not None  # (:func:`_zeroed_here` gave it)
            _set_zero_here(streamer, zero[1], wco, info.inch_reports, cb.say)
        if req.check:
            _check(streamer, program, req.gcode, cb.say, None if zero is None else zero[1])
        # check mode sent every line, and nothing moved
        spared = "nothing was cut (check mode moves nothing)" if req.check else "nothing was sent"
        if zero is not None:
            spared = f"nothing moved (the work zero was set: `{zero[1]}`)"
        if cb.confirm is not None and not _ask(
            cb.confirm,
            f"Stream {len(program.blocks) - start} lines of {req.gcode} to {req.port}{again}? "
            "The machine moves: board clamped and set up as README step 5 says, area clear",
            "answer y, or pass --yes to stream without asking",
            spared,
        ):
            raise ScratchfabError(f"not confirmed; {spared}")
        try:
            try:
                streamer.stream(
                    program,
                    journal,
                    start=start,
                    preamble=preamble,
                    resume=resume,
                    zeroed=None if zero is None else zero[1],
                )
            except (StreamFault, StreamStopped) as exc:
                text = str(exc)
                if zero is not None and info.booted:  # (a zero it keeps: resume as is)
                    text = f"{text}; {_zeroed_resume(zero)}"
                lines = fault_lines(text) if isinstance(exc, StreamFault) else text
                exc.args = (lines, *exc.args[1:])
                raise
            journal.close()
            cb.outcome(
                f"done: {len(program.blocks) - start} lines acknowledged; journal {journal_file}"
            )
        finally:
            if lost:
                assert events is not None
                _say_lost_position(events, cb.say, again=True, profile=profile, homing=homing)
    finally:
        ser.close()


def zero_here_command(profile: MachineProfile | None) -> tuple[str, str]:
    """``--zero-here``'s board point and command: ``("lower-left corner", "G10 L20 P0 X20 Y20")``.

    The profile's own work zero command (X and Y at the board's origin point, as the
    G-code writes them; a Z tool's ``Z0`` too, the tool touching the board's surface
    there, as the profile's heights count from it): where the tool stands once connected
    becomes that point, which
    holds on a controller without homing that resets as its port opens (its machine zero
    is where the tool stands then).

    Raises:
        ScratchfabError: No profile is known (the board's point and its numbers are not),
            or the profile works in machine coordinates (homing sets it; no work zero).
    """
    if profile is None:
        raise ScratchfabError(
            "--zero-here sets the work zero with the machine profile's command at the board's "
            "origin point: give --machine (or stream a job's G-code, which names its "
            "machine); nothing was sent"
        )
    if machine_coordinates(profile):
        raise ScratchfabError(
            f"--zero-here: machine '{profile.name}' works in GRBL's machine coordinates "
            '([envelope] coordinates = "machine"), which homing sets ($H): it takes no '
            "work zero; home it and stream without --zero-here; nothing was sent"
        )
    point, command = work_zero_command(profile)
    if profile.tool_control.mode != "servo":  # a Z tool: Z0 where it touches the board
        command += " Z0"
    return point, command


def _check_raised_first(program: Program, gcode: Path) -> None:
    """Refuse a G-code whose first move is not a rise in Z, where ``--zero-here`` zeroes Z.

    The tool then touches the board's surface as the stream begins: a first move in X or
    Y (or down) would drag it across the board. The exporter's first move is
    ``G0 Z<safe>``.

    Raises:
        ScratchfabError: Naming the first move's line; nothing was sent.
    """
    first = next((b for b in program.blocks if b.motion), None)
    if first is None:
        return
    z = first.modal.z
    up = not first.modal.relative and z is not None and z > 0.0
    if up and "Z" in first.text and not any(a in first.text for a in "XYABC"):
        return
    raise ScratchfabError(
        f"{gcode}:{first.lineno}: --zero-here zeroes Z where the tool touches the board's "
        f"surface, so the G-code's first move must raise it alone (`G0 Z<safe>`, as the "
        f"exporter writes it); its first move is `{first.text}`; nothing was sent"
    )


def _zeroed_resume(zero: tuple[str, str]) -> str:
    """How a run zeroed with ``--zero-here`` is resumed: at the same point, zeroed again."""
    point, command = zero
    touching = ", touching its surface," if " Z" in command else ""
    return (
        "this run's work zero was set with --zero-here, which a controller that resets as "
        "its port opens loses at the next connection: before --resume jog the tool back to "
        f"the board's {point}{touching} and add --zero-here"
    )


def _ask_zero_moved(
    events: list[dict[str, Any]],
    wco: tuple[float, float, float],
    info: ControllerInfo,
    kept: bool,
    confirm: Confirm | None,
) -> None:
    """Before ``--resume --zero-here`` on a controller that did not boot as the port opened.

    Such a controller kept its machine position, and with it the run's work zero (a stop's
    soft reset at rest keeps both): zeroing where the tool stands now would shift the rest
    of the job from what was cut, unless the tool stands just where the run's zero was
    set. ``wco``: the offset ``--zero-here`` would give; ``kept``: the journal shows no
    lost position (where it does, a re-zero at the board's point is the way back). A shift
    beyond two steps (and the reports' rounding) is refused under ``--yes`` and asked
    otherwise.

    Raises:
        ScratchfabError: The shift, under ``--yes`` or not confirmed; nothing was sent.
    """
    before = run_zero(events)[0]
    if before is None or not kept:
        return
    inches = info.inch_reports or run_zero_in_inches(events)
    steps = [info.settings.get(k) for k in (100, 101)]
    slack = max(offset_tolerance_mm(inches), *(2.0 / s for s in steps if s is not None and s > 0))
    shift = [now - was for now, was in zip(wco[:2], before[:2], strict=True)]
    if max(abs(d) for d in shift) <= slack:
        return
    moved = " ".join(f"{a}{round(d, 3):+g}" for a, d in zip("XY", shift, strict=True))
    why = (
        f"--zero-here would move the rest {moved} mm from what was cut; the controller kept "
        "the run's zero (no banner came as the port opened: it did not reset)"
    )
    if confirm is None:
        raise ScratchfabError(
            f"refusing to resume with --yes: {why}: resume without --zero-here (or without "
            "--yes to be asked); nothing was sent"
        )
    question = f"{why[0].upper()}{why[1:]}. Zero here anyway (only if the run's zero was wrong)?"
    if not _ask(confirm, question, ASKED_ONLY):
        raise ScratchfabError("not confirmed; nothing was sent: resume without --zero-here")


def _first_travel(program: Program) -> tuple[float, float] | None:
    """Where the program's first move in X or Y goes (work mm); None where not known."""
    for block in program.blocks:
        if block.motion and ("X" in block.text or "Y" in block.text):
            x, y = block.modal.x, block.modal.y
            if block.modal.relative or x is None or y is None:
                return None
            return x, y
    return None


def _ask_zero_here(
    zero: tuple[str, str],
    confirm: Confirm,
    spared: str,
    first: tuple[float, float] | None = None,
) -> None:
    """Ask whether the tool stands at ``--zero-here``'s point (under ``--yes`` the flag says so).

    ``first``: where the job's first travel goes (work mm, :func:`_first_travel`), said
    from the point, so that the person sees which way the tool will move.

    Raises:
        ScratchfabError: The person said no, or no answer came; ``spared`` was not done.
    """
    point, command = zero
    touching = ", touching the board's surface" if " Z" in command else ""
    goes = ""
    if first is not None:
        words = {w[0]: float(w[1:]) for w in command.split() if w[0] in "XY"}
        shift = (first[0] - words["X"], first[1] - words["Y"])
        away = " ".join(f"{a}{round(d, 3):+g}" for a, d in zip("XY", shift, strict=True))
        goes = f"; the job's first travel goes to X{first[0]:g} Y{first[1]:g}, {away} mm from it"
    question = (
        f"--zero-here: does the tool stand at the board's {point}{touching}? The work zero "
        f"is set there (`{command}`) before streaming{goes}"
    )
    how = (  # --yes answers this question: it says the tool stands there
        "answer y on a terminal or through a pipe, or pass --yes, which says the tool stands "
        f"at the board's {point}"
    )
    if not _ask(confirm, question, how, spared):
        raise ScratchfabError(
            f"not confirmed; {spared}: jog the tool to the board's {point} first (or stream "
            "without --zero-here)"
        )


def _zeroed_here(
    info: ControllerInfo, command: str
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The work offset and position ``command`` (``G10 L20 P0 X.. Y..``) will give, unsent.

    So that the checks before anything is sent (the travel, the board's place) see the
    zero that will be set; Z keeps its offset where the command has no Z word. Reports
    in WPos (``$10=0``) give the machine position with the offset (``$#`` or ``WCO:``).

    Raises:
        ScratchfabError: The controller's machine position or work offset is not known
            (nothing to check the zero against); nothing was sent.
    """
    mpos, wco, wpos = info.status.mpos, info.wco, info.status.wpos
    if mpos is None and wpos is not None and wco is not None:  # WPos reports ($10=0)
        mpos = (wpos[0] + wco[0], wpos[1] + wco[1], wpos[2] + wco[2])
    if mpos is None or wco is None:
        raise ScratchfabError(
            "--zero-here: the controller's status reports give no machine position or work "
            "offset ($10=1 makes them give MPos), so the zero it sets cannot be checked; "
            "nothing was sent"
        )
    words = {w[0]: float(w[1:]) for w in command.split() if w[0] in "XYZ"}
    x, y = words["X"], words["Y"]
    z = words.get("Z", mpos[2] - wco[2])  # without a Z word work Z keeps its offset
    return (mpos[0] - x, mpos[1] - y, mpos[2] - z), (x, y, z)


def _set_zero_here(
    streamer: Streamer,
    command: str,
    expected: tuple[float, float, float],
    inches: bool,
    say: Say,
) -> None:
    """Send ``--zero-here``'s ``command`` and check the work offset it gave.

    Raises:
        ScratchfabError: The controller refused it, or its offset is not ``expected``
            (the tool moved since connecting?); nothing moved.
    """
    got = streamer.set_work_zero(f"G21 {command}")
    if got is None or not same_offset(got, expected, inches):
        now = "unknown" if got is None else f"{xyz_text(got)} mm"
        raise ScratchfabError(
            f"--zero-here: after `{command}` the work offset is {now}, not "
            f"{xyz_text(expected)} mm as the position at connect gave (did the machine move "
            "since?); check the board's zero before streaming again; nothing moved"
        )
    say(f"work zero set here: `{command}` (work offset now {xyz_text(got)} mm)")


@dataclass(frozen=True)
class _Unfinished:
    """What the unfinished stream of a file did, as a stream from the top would repeat it.

    Attributes:
        reached: The line number of the last line it had acknowledged (0: none).
        cut: It began a stroke (or the program shows none, so it may have).
        left: A resume has lines left to send.
    """

    reached: int
    cut: bool
    left: bool

    @property
    def resume_does(self) -> str:
        """What ``--resume`` would do instead."""
        if self.left:
            return "--resume continues where it stopped"
        return "--resume only closes it: every line was acknowledged"


def _unfinished_run(
    events: list[dict[str, Any]], program: Program, journal_file: Path
) -> _Unfinished:
    """:class:`_Unfinished` of the journal's runs of ``program`` since its last fresh start."""
    first = last_fresh_start(events)
    acked = {ev["i"] for ev in events[first:] if ev.get("ev") == "ack" and "i" in ev}
    if not acked:
        return _Unfinished(0, cut=False, left=True)
    reached = program.blocks[min(max(acked), len(program.blocks) - 1)].lineno
    cut = not program.strokes or any(
        any(i in acked for i in range(a, b + 1)) for a, b in program.strokes
    )
    try:
        done = done_blocks(events, program.sha256, journal_file, program=program)
    except ConfigError:  # a resume would say why; here it only words the advice
        return _Unfinished(reached, cut, left=True)
    return _Unfinished(reached, cut, left=resume_point(program, done) < len(program.blocks))


def fault_lines(text: str) -> str:
    """A stream fault's message as its error line, then one indented line per clause.

    The sender words a fault as clauses joined by ``"; "``: what happened, what became of
    the machine and the tool, what to do next. On one line that ran to 600 characters
    after a lost link; here each clause (split outside parentheses) starts a line.
    """
    clauses: list[str] = []
    depth = begin = 0
    for k, c in enumerate(text):
        if c == "(":
            depth += 1
        elif c == ")":
            depth = max(0, depth - 1)
        elif depth == 0 and text.startswith("; ", k):
            clauses.append(text[begin:k])
            begin = k + 2
    clauses.append(text[begin:])
    return "\n  ".join(clauses)


def _refuse_from_the_top(before: _Unfinished, journal_file: Path, confirm: Confirm | None) -> None:
    """Under ``--yes`` (``confirm`` None), refuse to cut again what an unfinished stream cut.

    A job must survive a dropped cable: rerunning the command without ``--resume`` would
    start from line 1 and cut the strokes already done a second time, with nobody asked.
    An unfinished stream that began no stroke is no reason to refuse.

    Raises:
        ScratchfabError: Naming the line it reached, ``--resume``, and how to start over.
    """
    if confirm is not None or not before.cut:
        return
    over = (
        "to start over on purpose run without --yes and answer the question, or move the "
        "journal aside; nothing was sent"
    )
    if not before.left:
        raise ScratchfabError(
            f"{journal_file} shows a stream of this file that had every line acknowledged but "
            "did not end: streaming it from the top would cut the whole board again; nothing is "
            f"left to cut (--resume only closes the journal), or {over}"
        )
    raise ScratchfabError(
        f"{journal_file} shows an unfinished stream of this file that reached line "
        f"{before.reached}; streaming it from the top would cut those strokes again: continue "
        "it with --resume (after re-homing or re-zeroing if its position was lost), or "
        f"{over}"
    )


class NoAnswer(ScratchfabError):
    """A question got no answer: ``why`` (stdin closed before one came).

    Raised by a ``confirm`` callback (the CLI's); the one who asked says how to answer
    (:func:`_ask`), as each question has its own way.
    """

    def __init__(self, why: str) -> None:
        super().__init__(f"no answer came to the question ({why})")


class TerminalQuestion(str):
    """A question only a person at a terminal answers: whether the machine was homed.

    Only a person can tell, and an answer read from a pipe was written before the
    question was (``yes | scratchfab stream``): a ``confirm`` that reads a pipe answers
    it with :class:`NoAnswer` (the CLI's does); ``--homed`` says it without a question.
    """


def _ask(confirm: Confirm, question: str, how: str, spared: str = "nothing was sent") -> bool:
    """``confirm(question)``; no answer (:class:`NoAnswer`): an error naming ``how``.

    ``how``: how this question is answered; ``spared``: what was not done.
    """
    try:
        return confirm(question)
    except NoAnswer as exc:
        raise ScratchfabError(f"{exc}: {how}; {spared}") from None


#: How a question that ``--yes`` refuses is answered.
ASKED_ONLY = "answer y on a terminal or through a pipe (--yes refuses this question)"


def booted_zero_warning(info: ControllerInfo, profile: MachineProfile | None = None) -> str | None:
    """A controller without homing that booted as the port opened, with a work offset.

    Without homing (``$22=0``) GRBL's machine zero is where the tool stood at boot, and an
    Arduino-based controller boots when the port opens (its banner came unasked). The work
    offset it keeps (G54, in EEPROM) was set in an earlier session's frame, so the work
    zero lies that far from the tool now: the board's zero only where the tool stands
    where the controller booted last. A resume asks its own question
    (:func:`reset_since_last_run`). With a work-coordinate ``profile`` the warning names
    ``--zero-here`` at its board's point too. None where homing is on or not read, no
    banner came at opening, or the offset is zero.
    """
    wco = info.wco
    if not info.booted or homing_of(info.settings) is not False or wco is None:
        return None
    if same_offset(wco, (0.0, 0.0, 0.0), info.inch_reports):
        return None
    here = ""
    servo = profile is not None and profile.tool_control.mode == "servo"
    if profile is not None and not machine_coordinates(profile):
        here = (
            f", or jog the tool to the board's {profile.board.origin_text}"
            + ("" if servo else ", touching its surface,")
            + " and stream with --zero-here, which zeroes X and Y"
            + ("" if servo else " and Z")
            + " there once connected"
        )
    return (
        "the controller booted as the port opened (its banner came) and homing is off "
        f"($22=0): its machine zero is where the tool stands now, so the work offset it "
        f"keeps ({xyz_text(wco)} mm, set in an earlier session) puts the work zero that far "
        "from here, the board's zero only if the tool stood where the controller booted "
        "before (right where the zero was set from a connection opened at that spot, with "
        "the tool not moved since: then go on); else park the tool at the work zero with "
        "the offset cleared (`G10 L2 P0 X0 Y0 Z0`) before streaming, so that each boot's "
        f"machine zero is the work zero{here}"
    )


def travel_hint(
    port: str, settings: dict[int, float], program: Program, profile: MachineProfile | None
) -> str:
    """What to change where GRBL's travel refused a job; "" where nothing is named.

    Where the profile's envelope asks more travel of an axis than GRBL's ``$130``-``$132``
    give and the setting is the machine's own (a real controller, or an emulator URL that
    sets the key), one of the two is wrong: the profile's ``[envelope]`` range or the
    machine's setting, and the advice says to fix it first (an emulator told the profile's
    travel would rehearse on a machine that matches the wrong profile). The emulator run
    with its defaults (GRBL's, no such key in its URL) takes the travel from its URL: the
    keys named are the profile's envelope, else the job's own span, whole mm rounded up,
    never a key the URL has.
    """
    query = grblsim_query(port) if is_emulator(port) else None
    if profile is not None:
        env = profile.envelope
        spans = [hi - lo for lo, hi in (env.x_mm, env.y_mm, env.z_mm)]
        whose = "the profile's envelope"
    else:
        lo, hi = job_extent(program)
        spans = [b - a if a <= b else 0.0 for a, b in zip(lo, hi, strict=True)]
        whose = "the job's span"
    short = [
        k
        for k, span in enumerate(spans)
        if span > settings.get(130 + k, math.inf) and span < 1000.0
    ]
    own = [k for k in short if query is None or f"${130 + k}" in query]
    keys = [f"${130 + k}={math.ceil(spans[k] - 1e-9)}" for k in short if k not in own]
    hints = []
    if profile is not None and own:
        where = "on the controller" if query is None else "in the emulator's URL"
        hints.append(
            "; ".join(_envelope_disagrees(profile, k, settings[130 + k], where) for k in own)
        )
    if keys and query is not None:
        url = f"{port}{'&' if '?' in port else '?'}{'&'.join(keys)}"
        hints.append(f"the emulator takes its travel from its URL: --port '{url}' ({whose})")
    return "".join(f"; {text}" for text in hints)


def _envelope_disagrees(profile: MachineProfile, k: int, have: float, where: str) -> str:
    """The advice where profile ``profile``'s axis ``k`` spans more than GRBL's travel."""
    axis = "XYZ"[k]
    name = f"{axis.lower()}_mm"
    a, b = (profile.envelope.x_mm, profile.envelope.y_mm, profile.envelope.z_mm)[k]
    fit = (
        f"[{-have:g}, 0]" if profile.envelope.coordinates == "machine" else f"[{a:g}, {a + have:g}]"
    )
    return (
        f"the profile's [envelope] {name} = [{a:g}, {b:g}] ({b - a:g} mm) and GRBL's "
        f"${130 + k}={have:g} disagree: fix whichever is wrong first: if the machine "
        f"travels {have:g} mm, set the profile's {name} = {fit}; if it travels {b - a:g} mm, "
        f"set ${130 + k}={math.ceil(b - a - 1e-9)} {where}"
    )


def is_emulator(port: str) -> bool:
    """True for the built-in GRBL emulator (``grblsim://...``), which moves nothing."""
    return grblsim_query(port) is not None


def ask_before_a_partial_board(
    planned: tuple[JobLayout, Toolpath] | None,
    header: GcodeHeader,
    gcode: Path,
    port: str,
    confirm: Confirm | None,
    say: Say,
) -> None:
    """A board the envelope cuts short goes to a real machine only when a person says so.

    The toolpath stage plans one only when forced, with a warning (its preview shows what
    is lost); under ``--yes`` (``confirm`` None) nobody reads that, and the machine would
    cut a board that cannot be finished. Told by the job's toolpath (``planned``) and by
    the G-code's own header (``PARTIAL BOARD``), which a copy of the file keeps wherever it
    is streamed from. Said as a warning in any case; the emulator (:func:`is_emulator`) is
    neither asked nor refused.

    Args:
        planned: The job and the toolpath its G-code was exported from, else None.
        header: The G-code's header comments.
        gcode: The G-code file.
        port: Where the G-code goes.
        confirm: Asks a person; None: nobody is asked.
        say: Gets the warning.

    Raises:
        ScratchfabError: Under ``--yes`` on a machine, or when the person says no; nothing
            is sent.
    """
    from scratchfab.toolpath.plan import partial_text

    cut_short = None if planned is None else partial_text(planned[1].stats)
    if cut_short is not None:
        assert planned is not None
        lost = f"{cut_short} ({planned[0].toolpath_preview})"
    elif header.partial is not None:
        lost = f"{header.partial} (the header of {gcode} says so)"
    else:
        return
    _ask_on_a_machine(
        f"a partial board: {lost}",
        f"refusing to cut a partial board with --yes: {lost}; fix the machine profile's "
        "[board] offset_mm or [envelope], plan the toolpath and export again",
        f"Cut a partial board? {lost}",
        port,
        confirm,
        say,
    )


def ask_before_a_stale_toolpath(
    planned: tuple[JobLayout, Toolpath],
    gcode: Path,
    port: str,
    confirm: Confirm | None,
    say: Say,
    profile: MachineProfile | None = None,
) -> None:
    """A job's toolpath planned from other inputs than there are now is named first.

    ``optimize`` or ``design`` run again leave ``toolpath/toolpath.json`` and
    ``export/board.gcode`` as they were: ``toolpath`` and ``export`` refuse such inputs,
    and streaming would cut the earlier layout without a word. The check is export's
    (:func:`~scratchfab.toolpath.inputs.check_current`); where the optimized layout comes
    from an earlier design too (:func:`~scratchfab.model.job.stale_layout`), optimize is
    named before toolpath and export. ``profile``: the machine profile the caller loaded
    for this run (the pipeline's), compared with nothing again and not read twice; None
    (``stream JOB``): the recorded machine file is read and compared.

    Raises:
        ScratchfabError: Under ``--yes`` on a machine, or when the person says no; nothing
            is sent.
    """
    from scratchfab.model.job import stale_layout
    from scratchfab.toolpath.inputs import check_current

    layout, toolpath = planned
    stale, _ = check_current(toolpath, profile)
    if stale is None:
        return
    export = command_line(["scratchfab", "export", layout.root, "--format", "gcode"])
    layout_stale = stale_layout(layout.root)
    first = (
        ""
        if layout_stale is None
        else f"{layout_stale}: rerun `{command_line(['scratchfab', 'optimize', layout.root])}` "
        "first; "
    )
    what = f"{gcode} cuts an out-of-date plan: {first}{stale} (`{export}`)"
    _ask_on_a_machine(
        what,
        f"refusing to stream with --yes: {what}",
        f"Stream the out-of-date plan of {gcode} anyway (the warning above says why)?",
        port,
        confirm,
        say,
    )


def ask_before_an_earlier_export(
    planned: tuple[JobLayout, Toolpath],
    header: GcodeHeader,
    gcode: Path,
    port: str,
    confirm: Confirm | None,
    say: Say,
) -> None:
    """A G-code exported from another plan than the job's toolpath.json is named first.

    ``toolpath`` planned again (another offset, a whole board after a partial one, a new
    layout) leaves ``export/board.gcode`` as it was until ``export`` runs: streaming it
    would cut the earlier plan. The header's strokes id
    (:attr:`~scratchfab.toolpath.plan.Toolpath.strokes_id`) tells; a file without one (an
    earlier version's export, a foreign file) is not checked. No earlier plan's id is kept,
    so a G-code of another job copied into ``JOB/export/`` is told by its time: a file
    newer than ``toolpath.json`` was not exported from it, nor from a plan before it.

    Raises:
        ScratchfabError: Under ``--yes`` on a machine, or when the person says no; nothing
            is sent.
    """
    layout, toolpath = planned
    made_from = header.strokes_id
    if made_from is None or made_from == toolpath.strokes_id:
        return
    export = command_line(["scratchfab", "export", layout.root, "--format", "gcode"])
    if _newer(gcode, layout.toolpath_json):
        what = (
            f"{gcode} was not exported from this job's toolpath: its header names other "
            f"strokes than {layout.toolpath_json}, and the file is newer than that plan (a "
            "G-code of another job copied here?)"
        )
        cuts, plan = "it cuts what it was exported from, not this job's plan", "that G-code"
    else:
        what = (
            f"{gcode} was exported from another plan than {layout.toolpath_json} (planned "
            "again since)"
        )
        cuts, plan = "it cuts that plan, not the current one", "the earlier plan"
    _ask_on_a_machine(
        f"{what}: {cuts}; `{export}` writes the current one",
        f"refusing to stream with --yes: {what}; run `{export}` first",
        f"{what}. Stream {plan} anyway?",
        port,
        confirm,
        say,
    )


def load_program_for(
    gcode: Path, profile: MachineProfile | None, z_threshold: float | None = None
) -> Program:
    """``gcode`` read as it is streamed for ``profile``: its strokes by the profile's tool.

    A Z tool cuts below halfway between its safe and engrave heights (``z_threshold``
    where given); a servo is up under its ``off`` command. Without a profile the program
    tells both itself (:func:`~scratchfab.machine.sender_program.load_program`).
    """
    servo = profile is not None and profile.tool_control.mode == "servo"
    if z_threshold is None and profile is not None and not servo:
        z_threshold = 0.5 * (profile.z.safe_mm + profile.z.engrave_mm)
    tool_up = profile.tool_control.command("off") if servo and profile is not None else None
    return load_program(gcode, z_threshold=z_threshold, tool_up=tool_up)


def _newer(file: Path, than: Path) -> bool:
    """Whether ``file`` was modified after ``than`` (False where either cannot be read)."""
    try:
        return file.stat().st_mtime_ns > than.stat().st_mtime_ns
    except OSError:
        return False


def _ask_on_a_machine(
    warning: str, refusal: str, question: str, port: str, confirm: Confirm | None, say: Say
) -> None:
    """Say ``warning``; on a machine, ask ``question`` (under ``--yes``: refuse).

    The emulator moves nothing: it is neither asked nor refused. Under ``--yes``
    (``confirm`` None) nobody is asked: ``refusal`` ends with how to be asked.

    Raises:
        ScratchfabError: Refused, or the person said no; nothing was sent.
    """
    say(f"warning: {warning}")
    if is_emulator(port):
        return
    if confirm is None:
        raise ScratchfabError(f"{refusal}, or run without --yes to be asked; nothing was sent")
    if not _ask(confirm, question, ASKED_ONLY):
        raise ScratchfabError("not confirmed; nothing was sent")


def _check_same_zero(
    events: list[dict[str, Any]],
    wco: tuple[float, float, float] | None,
    g92: tuple[float, float, float] | None,
    journal_file: Path,
    say: Say,
    inches: bool = False,
    profile: MachineProfile | None = None,
) -> None:
    """Before a resume: the work zero must be where the interrupted run had it.

    A soft reset (every stop, check mode, a reconnect) clears GRBL's G92 offset, so a
    zero set with G92 is gone and the resumed strokes would land that far off: refused
    when the work offset is now exactly the old one less that G92 part (nobody zeroed
    again). Any other change of the work offset is told (a re-zero after a lost position
    changes it legitimately). Offsets compare with :func:`same_offset`, as check mode's,
    at the inch reports' coarser digit if either run read them so (``inches``: this one).

    Raises:
        ScratchfabError: The earlier run had a G92 offset, it is now cleared, and the work
            zero was not set again.
    """
    before, g92_before = run_zero(events)
    inches = inches or run_zero_in_inches(events)
    if before is None or wco is None or same_offset(before, wco, inches):
        return
    was, now = xyz_text(before), xyz_text(wco)
    zero = (0.0, 0.0, 0.0)
    if g92_before is not None and not same_offset(g92_before, zero, inches):
        cleared = tuple(b - g for b, g in zip(before, g92_before, strict=True))
        if (g92 is None or same_offset(g92, zero, inches)) and same_offset(cleared, wco, inches):
            raise ScratchfabError(
                f"{journal_file}: the interrupted run's work zero included a G92 offset "
                f"({xyz_text(g92_before)} mm) that a reset since then cleared (work offset "
                f"was {was}, now {now} mm): the resumed strokes would land elsewhere; "
                f"{zero_kept_advice(profile, 'set the same zero again', before)}, then --resume; "
                "nothing was sent"
            )
    say(
        f"warning: the work offset changed since the interrupted run (was {was}, now {now} "
        "mm): the work zero must be the same point on the board as before"
    )


def _check_strokes(program: Program, gcode: Path) -> None:
    """Refuse to resume a job that cuts (feed moves) but has no stroke at its Z threshold.

    Without strokes the resume point is the first block not acknowledged, which may lie
    in the middle of a cut (a threshold below every Z the job uses).
    """
    if program.strokes or not any(b.motion and b.modal.motion != "G0" for b in program.blocks):
        return
    if program.z_threshold is None:
        levels = ", ".join(f"{z:g}" for z in z_levels(program.blocks)[:8])
        heights = (
            f"its moves end at Z {levels}; no rapid shows a travel height"
            if levels
            else "it gives Z only as G91 increments from where Z stood, or not at all"
        )
        raise ScratchfabError(
            f"{gcode}: cannot tell from the program which Z cuts and which travels "
            f"({heights}); resuming could restart in the middle of a cut (give --machine, or "
            "a --z-threshold between the cutting and the travel heights)"
        )
    zs = [b.modal.z for b in program.blocks if b.modal.z is not None]
    span = f"Z {min(zs):g}..{max(zs):g}" if zs else "no Z"
    raise ScratchfabError(
        f"{gcode}: no stroke has the tool below the Z threshold {program.z_threshold:g} (the "
        f"job uses {span}); resuming could restart in the middle of a cut (give a "
        "--z-threshold between the cutting and the travel heights)"
    )


def _lost_event(events: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The journal's last session's last event that may have lost the position, else None.

    An ``alarm`` or ``stop`` with ``lost`` (a ``stop`` holds it where the controller reset
    itself: its banner came, a power or USB glitch, its reset button); a ``lost`` event (a
    dropped link) with ``lost``, once :func:`reset_since_last_run` found a reset since, or
    with no ``mpos`` (:func:`_unplaced_drop`): whether it reset cannot be told. Else an
    ordinary ``stop`` with no ``mpos`` (:func:`_unplaced_stop`), for the same reason, unless
    the session's ``start`` recorded homing on: a controller that resets then boots locked
    in Alarm, which the connect refuses.
    """
    kinds = ("alarm", "stop", "lost", "killed")
    session = last_session(events)
    homed_machine = run_homing(events) is True  # the session's start recorded $22=1
    lost = [
        ev
        for ev in session
        if ev.get("ev") in kinds
        and (ev.get("lost") or _unplaced_drop(ev))
        and not _unplaced_stop(ev)
    ]
    lost = lost or [ev for ev in session if _unplaced_stop(ev) and not homed_machine]
    return lost[-1] if lost else None


def _unplaced_drop(event: dict[str, Any]) -> bool:
    """A ``lost`` or ``stop`` event without the position the machine had by then.

    No status report came before it, its reports gave no machine position (``$10`` without
    MPos on a build that sends no ``WCO:``), or the journal was written before these events
    recorded ``mpos``: a controller that reset since (an Arduino resets when its port is
    opened) cannot be told from one that kept power, so a resume asks.
    """
    return event.get("ev") in ("lost", "stop") and xyz_of(event.get("mpos")) is None


def _unplaced_stop(event: dict[str, Any]) -> bool:
    """A ``stop`` the controller did not reset by itself, recorded without a position."""
    return event.get("ev") == "stop" and not event.get("lost") and _unplaced_drop(event)


def _killed_end(
    session: list[dict[str, Any]], program: Program | None
) -> tuple[float, float, float] | None:
    """Where a session with no closing event (the sender killed) left the machine, in MPos.

    A controller that kept power ran its queue to the end of the last acknowledged block:
    its work position (the program's) plus the offset the session's ``start`` read. None
    where the session closed (``stop``, ``lost``, ``end``), acknowledged nothing, or the
    position is not known: no program or offset, or a block up to it that the sender
    cannot follow (a G92, another work system) or counted from an assumed start.
    """
    if program is None or any(ev.get("ev") in ("stop", "lost", "end") for ev in session):
        return None
    acked = [ev["i"] for ev in session if ev.get("ev") == "ack" and isinstance(ev.get("i"), int)]
    wco = xyz_of(session[0].get("wco")) if session else None
    if not acked or wco is None or not 0 <= acked[-1] < len(program.blocks):
        return None
    blocks = program.blocks[: acked[-1] + 1]
    modal = blocks[-1].modal
    if any(b.unfollowed for b in blocks) or modal.x is None or modal.y is None:
        return None
    if "X" in modal.assumed or "Y" in modal.assumed:
        return None
    z = 0.0 if modal.z is None else modal.z
    return (modal.x + wco[0], modal.y + wco[1], z + wco[2])


def reset_since_last_run(
    events: list[dict[str, Any]],
    mpos: tuple[float, float, float] | None,
    wco: tuple[float, float, float] | None = None,
    homing: bool | None = None,
    inches: bool = False,
    program: Program | None = None,
    travel: Sequence[float | None] = (None, None),
    pulloff: float | None = None,
) -> dict[str, Any] | None:
    """The last session's closing event, where the machine may have lost its zero.

    The closing ``lost`` or ``stop``, or a ``killed`` one made up for a session with none.

    A controller without homing (``$22=0``), or unlocked with ``$X``, boots at machine
    zero wherever the tool stands: an Arduino resets when its port is opened (a reconnect
    after an ordinary stop too), a board powered over the cable lost power with it. It then
    answers as if nothing happened, and its work offset (kept in EEPROM) now counts from
    that new machine zero: the rest of the board would be cut shifted. Only where it stood
    when the run ended (the event's ``mpos``, and a stop's ``wco``) tells:

    - ``mpos`` now within two steps of machine zero in X and Y while the recorded one was
      not (Z is left out: a tool the stop could not raise is jogged up): a reset
      (``"zero"``), after a lost link or a stop alike;
    - after a stop only (the machine stood still, so a controller that kept power stands
      where it stopped): X or Y elsewhere by more than two steps (``"moved"``), unless
      homing is on (``$22=1``: a controller that reset boots locked in Alarm, and only
      ``$H`` or ``$X`` opens it, so a machine found Idle elsewhere was jogged). A jog keeps
      machine zero and the work offset, but a reset followed by a jog looks the same;
    - after a stop only: the work offset now differs from the one recorded after the
      stop's reset (``"wco"``): the work zero was set again, or lost;
    - homing on (``$22=1``), after any of them: X or Y outside the space homing gives
      (``-$130..0``, ``-$131..0``; ``travel``, None: not known, only above 0 counts) while
      the recorded position lay inside it (``"unhomed"``): a homed machine cannot stand
      there, so the controller reset and was unlocked (``$X``) and jogged, not homed. Its
      margins: above 0 the pull-off (``$27``, ``pulloff``; None: GRBL's default 1 mm) and
      1 mm, below ``-$13x`` 5 mm (a homed machine with soft limits off jogs a little past
      either end before its switch or its stop). A
      recorded position outside that space (a build that homes to machine zero,
      ``HOMING_FORCE_SET_ORIGIN``) tells nothing. Inside it, ``$H`` and ``$X`` with a jog
      still look alike.

    One that kept power after a lost link ran its queue and stands at a move's end, so
    being elsewhere alone says nothing there. A session with no closing event (the sender
    was killed or crashed) is read like a lost link, its position the end of the last
    acknowledged block in ``program`` (:func:`_killed_end`; ``"ev": "killed"``). Steps come
    from the session's ``start`` (else 0.025 mm), plus a report digit; offsets compare
    with :func:`same_offset`, at the inch reports' digit where either run read them
    (``inches``).

    Returns:
        A copy of the event (or the made-up ``killed`` one) with ``"lost": true``,
        ``"mpos_now"``, ``"why"`` (``"zero"``, ``"moved"`` or ``"wco"``) and for ``"wco"``
        ``"wco_now"``, else None (no closing ``lost`` or ``stop`` and no killed session's
        end, positions unknown, or nothing changed).
    """
    session = last_session(events)
    closing = [ev for ev in session if ev.get("ev") in ("lost", "stop")]
    killed = _killed_end(session, program)
    if mpos is None:
        return None
    if closing:
        event = closing[-1]
    elif killed is not None:
        event = {"ev": "killed", "mpos": [round(v, 3) for v in killed]}
    else:
        return None
    was = xyz_of(event.get("mpos"))
    if was is None:
        return None
    steps = xyz_of(session[0].get("steps")) or (0.0, 0.0, 0.0)
    near = [2.0 * (step or 0.025) + 0.001 for step in steps]
    found = {**event, "lost": True, "mpos_now": [round(v, 3) for v in mpos]}

    def within(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
        return all(abs(u - v) <= d for u, v, d in zip(a[:2], b[:2], near[:2], strict=True))

    zero = (0.0, 0.0, 0.0)
    if within(mpos, zero) and not within(was, zero):
        return {**found, "why": "zero"}
    above = (pulloff if pulloff is not None else 1.0) + 1.0  # past 0: pull-off and 1 mm
    homed = _homed_space(was, travel, near)
    if homing is True and homed and not _homed_space(mpos, travel, near, above, 5.0):
        return {**found, "why": "unhomed"}
    if event.get("ev") != "stop":
        return None
    if homing is not True and not within(mpos, was):
        return {**found, "why": "moved"}
    wco_was = xyz_of(event.get("wco"))
    if wco_was is not None and wco is not None and not same_offset(wco_was, wco, inches):
        return {**found, "why": "wco", "wco_now": [round(v, 3) for v in wco]}
    return None


def _homed_space(
    mpos: Sequence[float],
    travel: Sequence[float | None],
    near: Sequence[float],
    above: float = 0.0,
    below: float = 0.0,
) -> bool:
    """Whether X and Y lie where homing puts a machine: ``-travel..0``, within ``near``.

    GRBL 1.1 counts machine space negative from the home corner (``-$13x <= MPos <= 0``)
    whatever the homing direction (``$23``); a travel None bounds only the top. ``above``,
    ``below``: mm more allowed above 0 and below ``-travel``.
    """
    for m, t, d in zip(mpos[:2], travel[:2], near[:2], strict=True):
        if m > d + above or (t is not None and m < -t - d - below):
            return False
    return True


def _lost_by(event: dict[str, Any]) -> str:
    """What ended the run in ``event`` (:func:`_lost_event`): ``ALARM:2``, a reset."""
    since = {
        "zero": "the controller reset since (it stands at machine zero)",
        "moved": "the machine moved since (a jog, or a reset and a jog)",
        "wco": "the work offset changed since",
        "unhomed": "the machine stands where homing never puts it (reset, unlocked, jogged)",
    }.get(event.get("why", ""), "")
    if event.get("ev") == "stop" and since:
        return f"a stop, and {since}"
    if _unplaced_stop(event):
        return "a stop, with no position of the machine recorded"
    if event.get("ev") == "stop":
        return "a reset of the controller it did not send (its banner came)"
    if event.get("ev") == "lost" and "mpos_now" not in event:
        return "a lost link, with no position of the machine recorded before it"
    if event.get("ev") == "lost":
        return f"a lost link, and {since}"
    if event.get("ev") == "killed":
        return f"the sender killed (no stop recorded), and {since}"
    return f"ALARM:{event.get('code')}"


def lost_position_warning(
    events: list[dict[str, Any]],
    profile: MachineProfile | None = None,
    homing: bool | None = None,
) -> str | None:
    """The warning where the interrupted run ended in a way that may have lost the position.

    The journal's last session's ``alarm`` with ``lost``: ``true`` where GRBL stopped the
    motors at speed (a soft limit while the sender's feed hold slowed the machine down, a
    hard limit, a reset in motion), ``"maybe"`` where a hold the sender did not send (the
    controller's feed hold button, or GRBL's own soft-limit hold) was slowing it. GRBL stays
    locked until homed or unlocked, and the sender cannot tell which was done (Grbl 1.1
    answers ``$H`` and ``$X`` alike): an unlock keeps the lost position, so the resumed
    strokes would land off. The last session's ``stop`` with ``lost``: the controller
    reset itself; its ``lost`` event: the link dropped, and the controller reset since or
    no position tells (:func:`_lost_event`). What was to be done since is said for
    ``profile``'s frame and GRBL's ``homing`` (``$22``; None: not known), as
    :func:`~scratchfab.machine.sender.refind` words it. None where none of these ended it.
    """
    alarm = _lost_event(events)
    if alarm is None:
        return None
    done = refind(profile, homing).done
    if alarm.get("ev") == "lost" and "mpos_now" not in alarm:
        return (
            "the run before this resume ended with a lost link before any position of the "
            "machine was recorded (no status report came, or the journal is older than such "
            "records): whether the controller reset since cannot be told (an Arduino resets "
            "when its port is opened; a board powered over the cable lost power), which "
            f"loses the position; go on only if the machine was {done} since, or you know "
            "its controller kept power and was not reset"
        )
    if _unplaced_stop(alarm):
        return (
            "the run before this resume was stopped with no position of the machine recorded "
            "(its status reports gave no machine position, $10 without MPos on a build that "
            "sends no WCO:, none came, or the journal is older than such records): whether "
            "the controller reset since cannot be told (an Arduino resets when its port is "
            "opened), which makes machine zero where the tool stood and moves the work zero "
            f"with it; go on only if the machine was {done} since, or you know its controller "
            "kept power, was not reset and was not moved (reports with machine position, "
            "$10=1, let a resume tell)"
        )
    if "mpos_now" in alarm:
        return _moved_warning(alarm, done)
    if alarm.get("ev") == "stop":
        return (
            f"the run before this resume ended with {_lost_by(alarm)}: a power or USB glitch "
            "loses the position (a reset button pressed while the machine stood still keeps "
            f"it); go on only if the machine was {done} since"
        )
    code = alarm.get("code")
    if alarm["lost"] == "maybe":
        return (
            f"the run before this resume ended with ALARM:{code} (a soft limit) while the "
            "machine moved or slowed down under a feed hold the sender did not send: GRBL's own "
            "soft-limit hold keeps the position, the controller's feed hold button would have "
            "lost it "
            "(the motors stopped at speed); go on only if the machine was homed ($H) since, or "
            "you know the hold was GRBL's own; after an unlock ($X) alone the strokes may land off"
        )
    why = {
        1: "a hard limit",
        2: "a soft limit while a feed hold slowed the machine down",
        3: "a reset while the machine moved",
    }.get(code if isinstance(code, int) else -1, "an alarm")
    since = done if homing is False else "homed ($H)"
    return (
        f"the run before this resume ended with ALARM:{code}, which stopped the motors at "
        f"speed ({why}), so its position was likely lost: go on only if the machine was "
        f"{since} since; after an unlock ($X) alone the strokes would land off"
    )


def _moved_warning(event: dict[str, Any], done: str) -> str:
    """:func:`lost_position_warning` for an event :func:`reset_since_last_run` found."""
    stopped = event.get("ev") == "stop"
    killed = event.get("ev") == "killed"
    ended = {
        "stop": "was stopped",
        "killed": "ended with the sender killed or crashed (its journal records no stop)",
    }.get(event["ev"], "ended with a lost link")
    when = "when it stopped" if stopped else "when the link dropped"
    was = "the last acknowledged line ended at" if killed else "it stood at"
    where = f"MPos {xyz_text(event['mpos_now'])}; {was} {xyz_text(event['mpos'])}"
    where += "" if killed else f" {when}"
    reboot = "an Arduino resets when its port is opened" + (
        "" if stopped else "; a board powered over the cable lost power"
    )
    if event.get("why") == "moved":
        return (
            f"the run before this resume {ended}, and the machine stands elsewhere now "
            f"({where}): a jog keeps the work zero, but a reset ({reboot}) followed by a jog "
            "makes machine zero where the tool stood and moves the work zero with it, and "
            f"without homing nothing tells the two apart; go on only if the machine was {done} "
            "since, or it was only jogged and its controller never reset"
        )
    if event.get("why") == "unhomed":
        return (
            f"the run before this resume {ended}, and the machine now stands outside the "
            f"space homing gives it ({where}; a homed GRBL counts X and Y from -$130 and "
            "-$131 up to 0): the controller reset since "
            f"({reboot}) and was unlocked ($X) and jogged, not homed, so machine zero is where "
            f"the tool stood at the reset and the work zero moved with it; go on only if the "
            f"machine was {done} since"
        )
    if event.get("why") == "wco":
        return (
            f"the run before this resume {ended}, and the work offset changed since (was "
            f"{xyz_text(event['wco'])}, now {xyz_text(event['wco_now'])} mm): the work zero "
            f"must be the same point on the board as before; go on only if the machine was "
            f"{done} since"
        )
    return (
        f"the run before this resume {ended}, and the controller now stands at machine zero "
        f"({where}): it reset since ({reboot}), which makes machine zero where the tool stood "
        "and moves the work zero with it; go on only if the machine was "
        f"{done} since"
    )


def ask_if_homed(
    events: list[dict[str, Any]],
    homed: bool,
    port: str,
    confirm: Confirm | None,
    say: Say,
    profile: MachineProfile | None = None,
    homing: bool | None = None,
    zero: tuple[str, str] | None = None,
) -> bool:
    """Before a resume where the position may be lost since the run: homed since?

    After an alarm, a reset, or a stop, lost link or killed sender where the controller
    may have reset since or that recorded no position (:func:`lost_position_warning`).
    GRBL needs ``$H`` or ``$X`` after such an alarm and answers both alike, and a
    controller that reset itself, or may have, may boot at another position, so only a person can
    tell; after ``$X`` alone the strokes land off. ``homed`` (``--homed``) says the machine
    was homed, or its work zero set again, since. Otherwise, on a machine, the person is
    asked before anything is sent, and under ``--yes`` (``confirm`` None) the resume is
    refused. The emulator moves nothing: it is neither asked nor refused. What to do is
    said for ``profile``'s coordinates and GRBL's ``homing`` (``$22``; None: not known),
    as :func:`~scratchfab.machine.sender.refind` words it. ``zero`` (``--zero-here``'s
    point and command, :func:`zero_here_command`) answers as ``homed`` does: the work zero
    is set again where the tool stands; where the journal's run was zeroed so, a refusal
    names it as a way.

    Returns:
        True where :func:`lost_position_warning` is to be said once connected and again at
        the end (the emulator); False where there is none, or a person answered for it.

    Raises:
        ScratchfabError: Under ``--yes`` on a machine without ``homed``, or the person
            said no; nothing was sent.
    """
    warning = lost_position_warning(events, profile, homing)
    if warning is None:
        return False
    how = refind(profile, homing)
    if homed or zero is not None:
        by = _lost_by(_lost_event(events) or {})
        since = (
            f"--homed: the machine was {how.done} since"
            if zero is None
            else f"--zero-here: the work zero is set again here (`{zero[1]}` at the board's "
            f"{zero[0]})"
        )
        say(
            f"note: the run before this resume ended with {by}, which may have lost the "
            f"position; {since}"
        )
        return False
    if is_emulator(port):
        return True
    then = f"{how.do}, then run the same command with --homed"
    zeroed = run_zeroed(events)
    if zeroed is not None and not machine_coordinates(profile):
        then += (
            " (the run was zeroed with --zero-here: jogging the tool back to that point and "
            "resuming with --zero-here instead does both)"
        )
    if confirm is None:
        raise ScratchfabError(
            f"refusing to resume with --yes: {warning}; {then} (or without --yes to be "
            "asked); nothing was sent"
        )
    kept = ""
    event = _lost_event(events)
    if event is not None and _unplaced_stop(event):
        kept = ", or did its controller keep power without a reset or a move"
    elif event is not None and event.get("ev") == "lost" and "mpos_now" not in event:
        kept = ", or did its controller keep power without a reset"
    elif event is not None and event.get("why") == "moved":
        kept = ", or was it only jogged and its controller never reset"
    if not _ask(
        confirm,
        TerminalQuestion(
            f"{warning[0].upper()}{warning[1:]}. Was the machine {how.done} since then{kept} "
            "(--homed says so)?"
        ),
        f"{then} (--yes refuses this question), or answer it on a terminal",
    ):
        raise ScratchfabError(f"not confirmed; nothing was sent: {then}")
    return False


def _say_lost_position(
    events: list[dict[str, Any]],
    say: Say,
    again: bool = False,
    profile: MachineProfile | None = None,
    homing: bool | None = None,
) -> None:
    """Say :func:`lost_position_warning`, where there is one; ``again`` in the closing lines.

    Said once connected, and again when the resumed stream ends (done, stopped or failed):
    with ``--yes`` nothing waits after the first, which scrolls past under the progress.
    """
    warning = lost_position_warning(events, profile, homing)
    if warning is not None:
        say(f"warning{' (repeated)' if again else ''}: {warning}")


def _say_unclosed(program: Program, unsure_blocks: set[int], say: Say) -> None:
    """Name the lines a killed or crashed sender left unsure; they are cut again."""
    if not unsure_blocks:
        return
    unsure = sorted(unsure_blocks)
    say(
        "an earlier stream ended without a stop (the sender was killed or crashed): lines "
        f"{program.blocks[unsure[0]].lineno}-{program.blocks[unsure[-1]].lineno} were "
        "acknowledged but may not have run before the controller was reset; they are cut again"
    )


def _say_unsure(program: Program, unsure_blocks: set[int], recut_unsure: bool, say: Say) -> None:
    """Name the lines a lost link left unsure, and how they are treated on this resume."""
    if not unsure_blocks:
        return
    unsure = sorted(unsure_blocks)
    lines = f"lines {program.blocks[unsure[0]].lineno}-{program.blocks[unsure[-1]].lineno}"
    if recut_unsure:
        say(f"the link was lost earlier: {lines} count as not done and are cut again")
    else:
        say(
            f"the link was lost earlier: {lines} were acknowledged and count as done, as a "
            "controller that kept power ran them; if it lost power with the cable (lights "
            "out, a board powered over USB), stop and resume with --recut-unsure "
            "([stream] recut_unsure = true in a pipeline)"
        )


def _read_header(gcode: Path) -> GcodeHeader:
    """The G-code's header comments; empty where the file cannot be read (loading it says why)."""
    from scratchfab.export.gcode import GcodeHeader, read_header

    try:
        with gcode.open(encoding="utf-8", errors="replace") as handle:
            return read_header(handle)
    except OSError:
        return GcodeHeader()


def _planned(req: StreamRequest) -> tuple[JobLayout, Toolpath] | None:
    """The job and toolpath a G-code file in ``JOB/export/`` was exported from, else None.

    Raises:
        ConfigError: ``JOB/toolpath/toolpath.json`` does not load, and no ``--machine``
            makes do without it (with one, the partial-board check is skipped).
    """
    # the job's paths as the G-code was given (relative stays relative), where they tell it
    job = JobLayout.for_export_file(req.gcode) or JobLayout.for_export_file(req.gcode.resolve())
    if job is None or not job.toolpath_json.is_file():
        return None
    from scratchfab.toolpath import Toolpath

    try:
        return job, Toolpath.load(job.toolpath_json)
    except ConfigError:
        if req.machine is None:
            raise
        return None


def _profile_for(req: StreamRequest, planned: tuple[JobLayout, Toolpath] | None, say: Say) -> Any:
    """The machine profile to check against: the one asked for, else the job's own.

    A G-code file in ``JOB/export/`` was planned for the profile recorded in
    ``JOB/toolpath/toolpath.json`` (``planned``); streaming it is checked against that
    envelope even when no ``--machine`` is given.
    """
    if req.machine is not None:
        from scratchfab.machine.profile import load_profile

        return load_profile(req.machine)
    if planned is not None:
        job, toolpath = planned
        profile = toolpath.profile
        say(f"checking against machine '{profile.name}' of {job.toolpath_json}")
        return profile
    return None


def _check(
    streamer: Streamer, program: Any, gcode: Path, say: Say, zeroed: str | None = None
) -> None:
    """Run check mode and raise when GRBL finds any problem, listing each with its line.

    ``zeroed``: the work zero command ``--zero-here`` sent before, which the error names.
    """
    report = streamer.check(program)
    for block, code in report.errors:
        say(f"{gcode}:{block.lineno}: error:{code} ({error_meaning(code)}): {block.text}")
    if report.alarm is not None:
        block, code = report.alarm
        say(f"{gcode}:{block.lineno}: ALARM:{code} ({report.meaning}): {block.text}")
    if report.errors or report.alarm is not None:
        n = len(report.errors) + (report.alarm is not None)
        # check mode moved nothing: the position is kept, the controller may stay locked
        locked = f"; the controller stays in Alarm: {report.locked}" if report.locked else ""
        kept = "" if zeroed is None else f" (the work zero was set: `{zeroed}`)"
        raise ScratchfabError(
            f"{gcode}: check mode found {n} problem(s); nothing moved{kept}{locked}"
        )
    say(f"check mode: {len(program.blocks)} lines, no errors")


def run_stream_job(
    job: Path,
    port: str,
    protocol: str = "counting",
    baud: int | None = None,
    check: bool = False,
    machine: str | MachineProfile | None = None,
    recut_unsure: bool = False,
    homed: bool = False,
    say: Say = lambda _: None,
    confirm: Confirm | None = lambda _: True,
    zero_here: bool = False,
) -> Path:
    """The pipeline's stream stage: JOB/export/board.gcode to ``port``.

    ``confirm`` is asked about a partial board on a machine, and after the settings check
    (and check mode), as ``stream`` asks; the default answers yes (the caller has
    consent); None asks nobody and refuses a partial board on a machine
    (:func:`ask_before_a_partial_board`). A Ctrl-C stops safely. A run after an
    interrupted stream of the same G-code resumes it from the journal; after an alarm or a
    controller reset that may have lost the position only with ``homed`` or a person's word (:func:`ask_if_homed`).
    ``zero_here``: :attr:`StreamRequest.zero_here` (``run --zero-here``).
    """
    lines = ProgressLines()
    layout = JobLayout(job)

    def show(p: StreamProgress) -> None:
        text = lines.line(p)
        if text is not None:
            say(f"  {text}")

    progress = emulator_progress(
        port, baud, layout.export_file("gcode"), show, lambda text: say(f"  {text}")
    )
    req = StreamRequest(
        gcode=layout.export_file("gcode"),
        port=port,
        baud=baud,
        protocol=protocol,
        journal=layout.journal,
        resume_interrupted=True,
        recut_unsure=recut_unsure,
        check=check,
        machine=machine,
        homed=homed,
        zero_here=zero_here,
    )
    return stream_file(req, StreamCallbacks(progress, say, lambda: "stop", confirm))
