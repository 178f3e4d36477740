"""Click options shared by several commands."""

from __future__ import annotations

import math
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from scratchfab.errors import ScratchfabError

_F = TypeVar("_F", bound=Callable[..., Any])


class FiniteFloat(click.FloatRange):
    """A float option that refuses ``nan`` and ``inf`` (click's FloatRange lets them by)."""

    name = "finite float"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        """The number, or a usage error naming the option when it is not finite."""
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return number

    def _describe_range(self) -> str:
        """The range for the help; none without bounds (click would print ``x<=None``)."""
        if self.min is None and self.max is None:
            return ""
        return super()._describe_range()


_SIZE_RE = re.compile(r"^\s*([-+]?[0-9]*\.?[0-9]+)\s*[xX*]\s*([-+]?[0-9]*\.?[0-9]+)\s*(mm)?\s*$")


class SizePair(click.ParamType):
    """``WxH``: two positive numbers (a board in mm, ``100x80`` or ``100x80mm``; or pixels).

    Args:
        whole: Whole numbers only (camera pixels); a single ``N`` then means ``NxN``.
    """

    def __init__(self, whole: bool = False) -> None:
        self.whole = whole
        self.name = "N or WxH" if whole else "WxH"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        """The pair, or a usage error naming the option."""
        if isinstance(value, tuple):
            return value
        text = str(value).strip()
        if self.whole and text.isdigit():
            text = f"{text}x{text}"
        match = _SIZE_RE.match(text)
        if not match or (self.whole and match.group(3)):
            example = "128 or 128x96" if self.whole else "100x100"
            self.fail(f"expected {self.name} such as {example}, got {value!r}", param, ctx)
        w, h = float(match.group(1)), float(match.group(2))
        if self.whole:
            if w != int(w) or h != int(h) or w < 1 or h < 1:
                self.fail(f"expected whole pixel counts of at least 1, got {value!r}", param, ctx)
            return int(w), int(h)
        if w <= 0 or h <= 0:
            self.fail(f"both sizes must be positive, got {value!r}", param, ctx)
        return w, h


#: ``--backend llvm|cuda`` of the commands that run Dr.Jit kernels.
backend_option = click.option(
    "--backend",
    type=click.Choice(["llvm", "cuda"]),
    default="llvm",
    show_default=True,
    help="Dr.Jit backend: llvm (CPU) or cuda (NVIDIA GPU).",
)


def job_or_files_options(out_default: str) -> Callable[[_F], _F]:
    """JOB, or ``--design``/``--scratches``/``--out``: the inputs of the commands that render a board.

    Args:
        out_default: The folder under JOB written when ``--out`` is not given (for the help).
    """

    def decorate(f: _F) -> _F:
        f = click.option(
            "--out",
            "out_dir",
            type=click.Path(path_type=Path),
            show_default=f"JOB/{out_default}",
            help="Output folder.",
        )(f)
        f = click.option(
            "--scratches", "scratch_file", type=click.Path(path_type=Path), help="Scratch CSV (mm)."
        )(f)
        f = click.option(
            "--design", "design_file", type=click.Path(path_type=Path), help="Design TOML."
        )(f)
        return click.argument("job", required=False, type=click.Path(path_type=Path))(f)

    return decorate


def job_or_files(
    job: Path | None, design_file: Path | None, scratch_file: Path | None, out_dir: Path | None
) -> Path | tuple[Path, Path, Path]:
    """JOB, or ``(design, scratches, out)`` when those were given instead.

    Raises:
        ScratchfabError: When JOB comes with ``--design``/``--scratches``, or without JOB
            one of ``--design``, ``--scratches`` and ``--out`` is missing.
    """
    if job is not None:
        if design_file is not None or scratch_file is not None:
            raise ScratchfabError("give either JOB or --design/--scratches, not both")
        return job
    if design_file is None or scratch_file is None or out_dir is None:
        raise ScratchfabError("give JOB, or all of --design FILE --scratches CSV --out DIR")
    return design_file, scratch_file, out_dir


def stdin_is_a_terminal() -> bool:
    """Whether stdin is a terminal (a person may answer), not a pipe or a file."""
    return sys.stdin.isatty()


def confirm(question: str) -> bool:
    """Ask ``question`` on stderr; the answer comes from stdin, a terminal or a pipe.

    ``stream`` and ``run`` ask alike: ``echo y | scratchfab run ...`` answers as it does
    for ``stream``, except a question only a person at a terminal answers
    (:class:`~scratchfab.machine.stream_job.TerminalQuestion`: was the machine homed?).
    A Ctrl-C at the question stays click's abort (exit 130).

    Raises:
        NoAnswer: stdin closed before an answer came (nothing to read, or a pipe that ran
            out); the one who asked says how to answer
            (:class:`~scratchfab.machine.stream_job.NoAnswer`).
    """
    from scratchfab.machine.stream_job import NoAnswer, TerminalQuestion

    if isinstance(question, TerminalQuestion) and not stdin_is_a_terminal():
        click.echo(question, err=True)
        raise NoAnswer("stdin is not a terminal, and only a person there can answer it")
    try:
        return click.confirm(question, default=False, err=True)
    except click.exceptions.Abort as exc:
        if not isinstance(exc.__context__, EOFError):
            raise  # Ctrl-C at the question: "aborted", exit 130
        click.echo("", err=True)  # end the question's line
        raise NoAnswer("stdin closed") from None


#: The widest and the narrowest bar :func:`fit_line` draws (characters inside the brackets).
BAR_WIDEST = 28
BAR_NARROWEST = 8


def terminal_columns() -> int:
    """The width of the terminal on stderr in characters; 0 where it does not say."""
    try:
        return os.get_terminal_size(sys.stderr.fileno()).columns
    except (OSError, ValueError):
        return 0


def fit_line(text: str, columns: int, fraction: float | None = None) -> str:
    """``text`` (after a bar ``fraction`` full, if given) fitted to ``columns - 1`` characters.

    A line as wide as the terminal wraps, and each redraw would then start a row lower.
    The bar narrows (from BAR_WIDEST to BAR_NARROWEST, then none) to make room for the
    text; text still too long is cut after its last whole word that fits (a word longer
    than the line: where the line ends). ``columns`` 0 (a terminal that does not say):
    the widest bar and the whole text.
    """
    room = columns - 1
    width = min(BAR_WIDEST, room - len(text) - 3) if columns else BAR_WIDEST
    if fraction is not None and width >= BAR_NARROWEST:
        fill = min(width, max(0, int(width * fraction)))
        return f"[{'#' * fill}{'.' * (width - fill)}] {text}"
    if not columns or len(text) <= room:
        return text
    # the first ``columns`` characters: a space at the last is a word's end that fits
    words = text[:columns].rsplit(" ", 1)[0].rstrip()
    return words if 0 < len(words) <= room else text[: max(0, room)]


class RedrawnLine:
    """One line of a terminal on stderr, redrawn in place and kept inside its width.

    Spaces, not an ANSI erase code, blank what a shorter line leaves: a Windows console
    prints ANSI codes as text.
    """

    def __init__(self, columns: Callable[[], int] | None = None) -> None:
        """A line whose width comes from ``columns()`` (default :func:`terminal_columns`)."""
        self.last_len = 0
        self._columns = columns

    def __call__(self, text: str, newline: bool, fraction: float | None = None) -> None:
        """Draw ``text`` (after a bar ``fraction`` full) fitted over the line.

        ``newline`` ends the line: the next draw starts a new one.
        """
        columns = self._columns() if self._columns is not None else terminal_columns()
        text = fit_line(text, columns, fraction)
        blank = self.last_len if not columns else min(self.last_len, columns - 1)
        pad = " " * max(0, blank - len(text))
        click.echo(f"\r{text}{pad}", nl=newline, err=True)
        self.last_len = 0 if newline else len(text)
