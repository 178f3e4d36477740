"""The tests' own small G-code interpreter (independent of scratchfab.export).

It runs a program the way GRBL 1.1 would for the words scratchfab may emit, and records
every move with the tool state, so tests can check what would actually be cut. It raises
:class:`GcodeError` with GRBL's error number where GRBL would refuse a line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
SUPPORTED_G = {0, 1, 4, 17, 21, 90, 94}
SUPPORTED_M = {2, 3, 4, 5, 30}


class GcodeError(Exception):
    def __init__(self, code: int, line_no: int, text: str) -> None:
        super().__init__(f"error:{code} at line {line_no}: {text!r}")
        self.code = code
        self.line_no = line_no


@dataclass
class Move:
    kind: str  # "G0" or "G1"
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    feed: float | None
    spindle: bool
    line_no: int


@dataclass
class Run:
    moves: list[Move] = field(default_factory=list)
    dwells: list[float] = field(default_factory=list)
    modes_before_motion: set[int] = field(default_factory=set)
    final_position: tuple[float, float, float] | None = None
    spindle_at_end: bool = False
    ended: bool = False


def _xyz(p: list[float | None]) -> tuple[float, float, float]:
    """A position with unknown axes (never set) as NaN."""
    return tuple(float("nan") if v is None else float(v) for v in p)  # type: ignore[return-value]


def interpret(text: str, max_line_length: int = 79) -> Run:
    if "\r" in text:
        raise GcodeError(0, 0, "CR in program (GRBL would answer twice)")
    run = Run()
    pos: list[float | None] = [None, None, None]
    feed: float | None = None
    motion: int | None = None
    absolute = False
    metric = False
    spindle = False
    for line_no, raw in enumerate(text.split("\n"), start=1):
        if any(c in raw for c in "!?~"):
            raise GcodeError(0, line_no, "realtime character in line")
        line = re.sub(r"\([^)]*\)", "", raw)
        line = line.split(";", 1)[0]
        line = "".join(line.split()).upper()
        if len(line) > max_line_length:
            raise GcodeError(11, line_no, raw)
        if not line:
            continue
        words = WORD.findall(line)
        if "".join(a + b for a, b in words) != line:
            raise GcodeError(1, line_no, raw)
        target: dict[str, float] = {}
        dwell_p: float | None = None
        for letter, value in words:
            v = float(value)
            if letter == "G":
                g = int(v)
                if v != g or g not in SUPPORTED_G:
                    raise GcodeError(20, line_no, raw)
                if g in (0, 1):
                    motion = g
                elif g == 90:
                    absolute = True
                elif g == 21:
                    metric = True
                elif g == 4:
                    dwell_p = -1.0
                if not run.moves:
                    run.modes_before_motion.add(g)
            elif letter == "M":
                mcode = int(v)
                if v != mcode or mcode not in SUPPORTED_M:
                    raise GcodeError(20, line_no, raw)
                if mcode in (3, 4):
                    spindle = True
                elif mcode == 5:
                    spindle = False
                elif mcode in (2, 30):
                    spindle = False
                    run.ended = True
            elif letter == "F":
                feed = v
            elif letter == "S":
                pass
            elif letter == "P":
                dwell_p = v
            elif letter in "XYZ":
                target[letter] = v
            else:
                raise GcodeError(20, line_no, raw)
        if dwell_p is not None:
            run.dwells.append(dwell_p)
        if target:
            if not (absolute and metric):
                raise GcodeError(0, line_no, "motion before G21/G90")
            if motion is None:
                raise GcodeError(0, line_no, "no motion mode")
            if motion == 1 and feed is None:
                raise GcodeError(22, line_no, raw)
            new = list(pos)
            for i, axis in enumerate("XYZ"):
                if axis in target:
                    new[i] = target[axis]
            if pos[0] is None or pos[1] is None:
                pos = new
                continue
            start = _xyz(pos)
            end = _xyz(new)
            run.moves.append(
                Move(f"G{motion}", start, end, feed if motion == 1 else None, spindle, line_no)
            )
            pos = new
    if pos[0] is not None and pos[1] is not None:
        run.final_position = _xyz(pos)
    run.spindle_at_end = spindle
    return run


def cuts(run: Run, engrave_below_z: float | None) -> tuple[list[Move], list[Move]]:
    """Split XY moves into (cutting, not cutting).

    A move cuts when the tool is down: in Z mode (``engrave_below_z`` given) when it runs
    below that height, in servo mode when the servo command (M3) is on.
    """
    cutting, other = [], []
    for mv in run.moves:
        if engrave_below_z is not None:
            down = max(mv.start[2], mv.end[2]) < engrave_below_z
        else:
            down = mv.spindle
        moved_xy = mv.start[:2] != mv.end[:2]
        if down and moved_xy:
            cutting.append(mv)
        else:
            other.append(mv)
    return cutting, other
