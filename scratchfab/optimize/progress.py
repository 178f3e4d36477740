"""Optimizer progress as text: the one printer of ``scratchfab optimize`` and the pipeline."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from scratchfab.console import Say, clock

if TYPE_CHECKING:
    from scratchfab.optimize.stage import Progress

#: A log gets a line per this fraction of the steps, and one at least every THROTTLE_S.
THROTTLE_S = 5.0


def step_text(p: Progress) -> str:
    """One step's count, loss, elapsed time and ETA."""
    return (
        f"{p.iteration}/{p.total} loss {p.loss:.5f}  elapsed {clock(p.elapsed_s)}  "
        f"eta {clock(p.eta_s)}"
    )


def progress_text(p: Progress, width: int = 30) -> str:
    """One step as a bar ``width`` characters wide and :func:`step_text`."""
    filled = int(round(_fraction(p) * width))
    return f"[{'#' * filled}{'.' * (width - filled)}] {step_text(p)}"


def message_text(message: str) -> str:
    """A status message as printed: an activity gets "...", a note stays as it is.

    A note is a sentence ending in a full stop (e.g. the glint left out of a view's image
    error).
    """
    return message if message.endswith(".") else f"{message}..."


def _fraction(p: Progress) -> float:
    """The fraction of the steps done."""
    return p.iteration / p.total if p.total else 1.0


def progress_printer(
    say: Say,
    redraw: Callable[[str, bool, float | None], Any] | None = None,
    width: int = 30,
) -> Callable[[Progress], None]:
    """A ``progress`` callback for :func:`scratchfab.optimize.stage.run_optimize`.

    Args:
        say: Writes one line. Without ``redraw`` (a log) it gets every status message
            (:func:`message_text`) and a step line (:func:`progress_text`) per 10 % of the
            steps and at least every 5 s.
        redraw: ``redraw(text, done, fraction)`` replaces the current line (a terminal),
            with a bar ``fraction`` full before ``text`` unless ``fraction`` is None (a
            terminal fits the two to its width). It then gets every message (no bar) and
            every step (:func:`step_text` and the fraction of the steps done), ``done``
            when the line is to stay.
        width: Characters of the log's bar.
    """
    last = {"decile": -1, "time": 0.0}

    def report(p: Progress) -> None:
        if p.message:
            if redraw is not None:
                redraw(message_text(p.message), True, None)
            else:
                say(message_text(p.message))
            return
        if redraw is not None:
            redraw(step_text(p), p.iteration >= p.total, _fraction(p))
            return
        decile = int(10 * _fraction(p))
        if decile != last["decile"] or time.monotonic() - last["time"] > THROTTLE_S:
            last["decile"] = decile
            last["time"] = time.monotonic()
            say(progress_text(p, width))

    return report
