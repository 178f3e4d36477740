"""The callbacks through which the library tells a person something or asks them.

The core never prints: each stage takes a ``say`` (or ``progress``) callback that gets
one line at a time, and a ``confirm`` callback before a machine moves. The CLI passes
``click.echo`` and a terminal prompt; library callers pass their own, or nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

#: Takes one line of progress or result (no trailing newline); its return is ignored.
Say = Callable[[str], Any]

#: Takes a yes/no question; returns True to go on.
Confirm = Callable[[str], bool]
