"""The callbacks through which the library tells a person something or asks them.

The core never prints: each stage takes a ``say`` (or ``progress``) callback that gets
one line at a time, and a ``confirm`` callback before a machine moves. The CLI passes
``click.echo`` and a terminal prompt; library callers pass their own, or nothing.
"""

from __future__ import annotations

import math
import os
import shlex
import subprocess
from collections.abc import Callable, Sequence
from typing import Any

#: Takes one line of progress or result (no trailing newline); its return is ignored.
Say = Callable[[str], Any]

#: Takes a yes/no question; returns True to go on.
Confirm = Callable[[str], bool]


def clock(seconds: float, up: bool = False) -> str:
    """``mm:ss``, or ``h:mm:ss`` from an hour on; ``--:--`` when not known.

    Rounded to the nearest second, or with ``up`` (a time still left) up to the next
    one (a millionth over a whole second taken for float noise), so that it reads
    ``00:00`` only when nothing is left.
    """
    if not math.isfinite(seconds):
        return "--:--"
    s = max(0, math.ceil(seconds - 1e-6) if up else round(seconds))
    return (
        f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
        if s >= 3600
        else f"{s // 60:02d}:{s % 60:02d}"
    )


def duration_text(seconds: float) -> str:
    """A duration as a person says it: ``1 h 23 min``, ``23 min``, ``45 s``."""
    if seconds < 59.5:
        return f"{max(0, round(seconds))} s"
    minutes = round(seconds / 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes} min" if hours else f"{minutes} min"


def command_line(args: Sequence[str | os.PathLike[str]]) -> str:
    """Arguments as one command line a person can paste into their shell unchanged.

    Each argument is quoted so the shell passes it back as it is, never expanding
    ``$(...)``, quotes or spaces: POSIX shell rules, or ``CommandLineToArgvW``'s on Windows.
    """
    words = [os.fspath(a) for a in args]
    if os.name == "nt":
        return subprocess.list2cmdline(words)
    return " ".join(shlex.quote(w) for w in words)
