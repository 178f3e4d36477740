"""``scratchfab stream`` (send G-code to GRBL) and ``scratchfab grbl-sim`` (the emulator)."""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import click

from scratchfab.cli.options import FiniteFloat, RedrawnLine, confirm, stdin_is_a_terminal
from scratchfab.errors import ScratchfabError
from scratchfab.machine.sender import StreamProgress
from scratchfab.machine.stream_job import (
    ProgressLines,
    StreamCallbacks,
    StreamRequest,
    emulator_progress,
    stream_file,
)
from scratchfab.model.job import JobLayout


class _ProgressLine:
    """One status line on stderr: a bar redrawn in place on a terminal, else paced lines.

    The text is :func:`~scratchfab.machine.stream_job.progress_text`'s, as the pipeline's
    stream stage prints it; off a terminal :class:`ProgressLines` paces it. On a terminal
    :class:`RedrawnLine` draws the bar and keeps the line inside the terminal's width.
    """

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self._lines = ProgressLines()
        self._line = RedrawnLine()
        self._open = False  # a bar is drawn and its line not yet ended

    def __call__(self, p: StreamProgress) -> None:
        if self.tty:
            self._line(self._lines.text(p), newline=False, fraction=p.fraction)
            self._open = True
        else:
            due = self._lines.line(p)
            if due is not None:
                click.echo(due, err=True)

    def end(self) -> None:
        """End the bar's line (before any other output); nothing when none is drawn."""
        if self._open:
            self._line.last_len = 0
            click.echo("", err=True)
            self._open = False


def ask_resume_or_stop(say: Callable[[str], None]) -> str:
    """After Ctrl-C (the machine held): ``"resume"`` or ``"stop"``, asked on a terminal.

    Off a terminal nobody can answer in time, and a pipe's answers were written for other
    questions (``yes |`` gives ``y``, which click would refuse and ask again for ever while
    the machine is held): stop, the safe answer, said once, stdin not read.
    """
    if not stdin_is_a_terminal():
        say("stdin is not a terminal, so nobody can answer [r]esume or [s]top: stopping")
        return "stop"
    answer = click.prompt(
        "machine held: [r]esume or [s]top (stop = wait for the hold, then soft reset)",
        type=click.Choice(["r", "s"]),
        default="s",
        show_choices=False,  # the text names them: "(r, s)" after it said them twice
        err=True,
    )
    return "resume" if answer == "r" else "stop"


def _job_gcode(path: Path) -> Path:
    """``path``, or for a job folder its ``export/board.gcode`` (said on stderr).

    Raises:
        ScratchfabError: A folder without that file: where it would be and how to make it.
    """
    if not path.is_dir():
        return path
    board = JobLayout(path).export_file("gcode")
    inside = JobLayout(path.parent).export_file("gcode")  # given JOB/export itself
    if not board.is_file() and path.name == inside.parent.name and inside.is_file():
        board = inside
    if not board.is_file():
        raise ScratchfabError(
            f"{path} is a folder: as a job folder its G-code would be {board}, which does not "
            f"exist; run `scratchfab export {path} --format gcode` first, or give a G-code file"
        )
    what = "a job's export folder" if board == inside else "a job folder"
    click.echo(f"{path} is {what}: streaming {board}", err=True)
    return board


@click.command("stream")
@click.argument("gcode", metavar="GCODE|JOB", type=click.Path(path_type=Path))
@click.option(
    "--port", required=True, help="Serial device, pty path or pyserial URL (grblsim://...)."
)
@click.option(
    "--yes",
    is_flag=True,
    help="Do not ask before motion; what needs a person's word is refused instead (a partial "
    "board, an earlier plan's G-code, an unfinished job from the top, a resume after an "
    "alarm that may have lost the position without --homed).",
)
@click.option(
    "--baud",
    type=click.IntRange(min=1),
    default=None,
    show_default="the machine profile's, else 115200",
    help="Baud rate.",
)
@click.option(
    "--protocol",
    type=click.Choice(["counting", "simple"]),
    default="counting",
    show_default=True,
    help="Character counting, or send-and-wait.",
)
@click.option(
    "--journal",
    "journal_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    show_default="JOB/stream/journal.jsonl, or beside the G-code",
    help="Journal file.",
)
@click.option("--resume", is_flag=True, help="Restart at the first stroke not completely done.")
@click.option(
    "--recut-unsure",
    is_flag=True,
    help="With --resume after a lost link: also cut again what the controller acknowledged "
    "but may not have run (a board that lost power with the USB cable).",
)
@click.option(
    "--homed",
    is_flag=True,
    help="With --resume after an alarm, a lost link or a stop that may have lost the "
    "position (a controller found reset since: at machine zero, moved, another work "
    "offset): the machine was homed ($H) since, or (a work-coordinate profile) unlocked "
    "($X) and its work zero set again (else asked; refused under --yes).",
)
@click.option(
    "--zero-here",
    is_flag=True,
    help="The tool stands at the board's origin point (the profile's, e.g. its lower-left "
    "corner; a Z tool touching the board's surface): once connected, set the work zero there "
    "(the profile's G10 L20 command: X and Y, and Z0 for a Z tool) before streaming. For a "
    "controller without homing that resets as its port opens; with --resume it stands for "
    "--homed (refused where the controller kept the run's zero). Asked unless --yes.",
)
@click.option(
    "--check",
    "check_first",
    is_flag=True,
    help="Run the file through GRBL check mode ($C) first; stream only if it is clean.",
)
@click.option(
    "--machine",
    default=None,
    show_default="the job's toolpath machine",
    help="Machine profile NAME or PATH to compare with $$.",
)
@click.option(
    "--margin",
    type=click.IntRange(0, 64),
    default=8,
    show_default=True,
    help="RX bytes kept free.",
)
@click.option(
    "--stall-timeout",
    type=FiniteFloat(min=0, min_open=True),
    default=10.0,
    show_default=True,
    help="Seconds without an answer, lines in flight and the controller Idle, before "
    "the stream stops as stalled.",
)
@click.option(
    "--banner-timeout",
    type=FiniteFloat(min=0, min_open=True),
    default=2.5,
    show_default=True,
    help="Seconds to wait for GRBL's banner after opening the port or a soft reset.",
)
@click.option(
    "--z-threshold",
    type=FiniteFloat(),
    default=None,
    show_default="machine: halfway engrave..safe; else from the G-code: between its cutting "
    "and rapid heights",
    help="The tool is down below this Z (mm).",
)
@click.option(
    "--lift/--no-lift",
    default=True,
    show_default=True,
    help="After a stop (an error, a stall, Ctrl-C's stop, SIGTERM), once the controller is "
    "reset and Idle with its position known, raise the tool: Z up to the travel height (the "
    "machine's z.safe_mm, else the file's highest Z) in machine coordinates (G53), or the "
    "servo's up command. Never after an alarm, a lost link or with the door open.",
)
def stream(
    gcode: Path,
    port: str,
    yes: bool,
    baud: int | None,
    protocol: str,
    journal_path: Path | None,
    resume: bool,
    recut_unsure: bool,
    homed: bool,
    zero_here: bool,
    check_first: bool,
    machine: str | None,
    margin: int,
    stall_timeout: float,
    banner_timeout: float,
    z_threshold: float | None,
    lift: bool,
) -> None:
    """Stream GCODE to a GRBL 1.1 controller on PORT, safely.

    Character counting by default; stops and holds on any error or alarm, aborts on a
    controller reset or a stall, journals every acknowledged line so that --resume can
    continue after a disconnect or a stop without skipping a stroke. A job folder JOB
    streams its export/board.gcode.
    """
    if recut_unsure and not resume:
        raise click.UsageError("--recut-unsure only applies with --resume")
    if homed and not resume:
        raise click.UsageError("--homed only applies with --resume")
    gcode = _job_gcode(gcode)
    request = StreamRequest(
        gcode=gcode,
        port=port,
        baud=baud,
        protocol=protocol,
        journal=journal_path,
        resume=resume,
        recut_unsure=recut_unsure,
        check=check_first,
        machine=machine,
        margin=margin,
        stall_timeout=stall_timeout,
        banner_timeout=banner_timeout,
        z_threshold=z_threshold,
        lift=lift,
        homed=homed,
        zero_here=zero_here,
    )
    bar = _ProgressLine()

    def message(text: str) -> None:
        bar.end()
        click.echo(text, err=True)

    def outcome(text: str) -> None:
        bar.end()
        click.echo(text)

    def ask_interrupt() -> str:
        bar.end()
        return ask_resume_or_stop(message)

    try:
        progress = emulator_progress(port, baud, gcode, bar, message)
        callbacks = StreamCallbacks(
            progress, message, ask_interrupt, None if yes else confirm, outcome
        )
        stream_file(request, callbacks)
    finally:
        bar.end()


@click.command("grbl-sim")
@click.option(
    "--pty", "use_pty", is_flag=True, help="Serve on a new pseudo-terminal (prints its path)."
)
@click.option(
    "--baud",
    type=click.IntRange(min=300),
    default=115200,
    show_default=True,
    help="Emulated line speed.",
)
@click.option(
    "--time-scale",
    type=FiniteFloat(min=0),
    default=1.0,
    show_default=True,
    help="Motion time factor.",
)
@click.option(
    "--error-at",
    type=click.IntRange(min=0),
    default=0,
    help="Answer error:<code> to the N-th G-code block (0: never).",
)
@click.option(
    "--error-code",
    type=click.IntRange(1, 38),
    default=20,
    show_default=True,
    help="Code for --error-at.",
)
@click.option(
    "--disconnect-after",
    type=click.IntRange(min=0),
    default=0,
    help="Drop the link at the N-th block (0: never).",
)
@click.option(
    "--usb-powered", is_flag=True, help="Lose power with the link (stop running at once)."
)
@click.option(
    "--slow", type=FiniteFloat(min=0), default=0.0, help="Extra seconds before each answer."
)
@click.option("--soft-limits", is_flag=True, help="Start with $20=1 and $22=1 (in ALARM).")
@click.option(
    "--record",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Write what the controller received and ran (JSONL) on exit.",
)
@click.option(
    "--set",
    "extra",
    multiple=True,
    metavar="KEY=VALUE",
    help="Any other emulator key of a grblsim:// URL, or a GRBL setting such as $130=300 "
    "(repeatable; overrides the options above).",
)
def grbl_sim(
    use_pty: bool,
    baud: int,
    time_scale: float,
    error_at: int,
    error_code: int,
    disconnect_after: int,
    usb_powered: bool,
    slow: float,
    soft_limits: bool,
    record: Path | None,
    extra: tuple[str, ...],
) -> None:
    """Run the built-in GRBL 1.1 emulator on a pseudo-terminal until Ctrl-C.

    Any sender can open the printed device. In-process, the same emulator is the pyserial
    URL grblsim://?time_scale=0.01&error_at=500&$130=300 (keys as the options here, with
    underscores, and as --set).
    """
    if not use_pty:
        raise ScratchfabError(
            "grbl-sim serves a pseudo-terminal: pass --pty (in-process, use the URL grblsim://)"
        )
    if os.name != "posix":
        raise ScratchfabError(
            "grbl-sim --pty needs a POSIX pseudo-terminal (Linux, macOS); here, stream to "
            "the in-process emulator instead: --port grblsim://"
        )
    from scratchfab.machine.grblsim import SimOptions
    from scratchfab.machine.grblsim_pty import GrblPty

    query = {
        "baud": str(baud),
        "time_scale": repr(time_scale),
        "error_at": str(error_at),
        "error_code": str(error_code),
        "disconnect_after": str(disconnect_after),
        "usb_powered": str(usb_powered),
        "slow": repr(slow),
        "soft_limits": str(soft_limits),
        "record": str(record) if record else "",
    }
    for pair in extra:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise click.BadParameter(f"expected KEY=VALUE, got {pair!r}", param_hint="'--set'")
        query[key] = value
    options = SimOptions.from_query(query, "grbl-sim")
    if options.record:
        from scratchfab.fileio import write_text

        write_text(options.record, "")  # fails now, in one line, rather than on exit
    sim = GrblPty(options).start()
    click.echo(sim.path)
    click.echo(f"GRBL 1.1h emulator on {sim.path} (Ctrl-C to quit)", err=True)
    stop = threading.Event()
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        sim.close()
        click.echo(
            f"received {sum(e['ev'] == 'rx' for e in sim.sim.record)} lines, "
            f"RX overruns {sim.sim.overruns}",
            err=True,
        )
