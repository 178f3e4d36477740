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


def progress_text(p: Progress, width: int = 30) -> str:
    """One step as a bar with the step count, loss, elapsed time and ETA."""
    frac = p.iteration / p.total if p.total else 1.0
    filled = int(round(frac * width))
    return (
        f"[{'#' * filled}{'.' * (width - filled)}] {p.iteration}/{p.total} "
        f"loss {p.loss:.5f}  elapsed {clock(p.elapsed_s)}  eta {clock(p.eta_s)}"
    )


def progress_printer(
    say: Say,
    redraw: Callable[[str, bool], Any] | None = None,
    width: int = 30,
) -> Callable[[Progress], None]:
    """A ``progress`` callback for :func:`scratchfab.optimize.stage.run_optimize`.

    Args:
        say: Writes one line. Without ``redraw`` (a log) it gets every status message and
            a step line per 10 % of the steps and at least every 5 s.
        redraw: ``redraw(text, done)`` replaces the current line (a terminal); it then
            gets every message and every step, ``done`` when the line is to stay.
        width: Characters of the bar.
    """
    last = {"decile": -1, "time": 0.0}

    def report(p: Progress) -> None:
        if p.message:
            if redraw is not None:
                redraw(f"{p.message}...", True)
            else:
                say(f"{p.message}...")
            return
        text = progress_text(p, width)
        if redraw is not None:
            redraw(text, p.iteration >= p.total)
            return
        decile = int(10 * (p.iteration / p.total if p.total else 1.0))
        if decile != last["decile"] or time.monotonic() - last["time"] > THROTTLE_S:
            last["decile"] = decile
            last["time"] = time.monotonic()
            say(text)

    return report
