"""The G-code interpreter of the GRBL emulator: Grbl 1.1's parser rules and error codes.

The subset follows ``gc_execute_line``: motion G0/G1/G2/G3/G80, dwell G4, G10 L2/L20, G17-G19,
G20/G21, G28/G30 (+ .1), G40, G43.1/G49, G53, G54-G59, G61, G90/G91, G91.1, G92/G92.1, G93/G94,
M0/M1/M2/M30, M3/M4/M5, M7/M8/M9 and the words F I J K L N P R S T X Y Z. Probing (G38.x) and
anything else answer ``error:20``. A block is checked completely before any of it takes
effect; the caller commits the returned state only when the block is accepted.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from scratchfab.machine.grbl_codes import MM_PER_INCH

MAX_LINE_NUMBER = 10_000_000
MAX_TOOL_NUMBER = 255
_AXES = "XYZ"
_VALUE_LETTERS = "FIJKLNPRSTXYZ"


class GcodeError(Exception):
    """A block the controller rejects with ``error:code``."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


@dataclass
class ModalState:
    """Grbl's parser state (``gc_state``); positions are machine coordinates in mm."""

    motion: str = "G0"
    plane: int = 17
    inches: bool = False
    relative: bool = False
    inverse_time: bool = False
    coord_index: int = 0  # 0 = G54 ... 5 = G59
    spindle: str = "M5"
    coolant: frozenset[str] = frozenset()
    feed: float = 0.0  # mm/min
    spindle_speed: float = 0.0
    tool: int = 0
    tlo: float = 0.0
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    g92: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def copy(self) -> ModalState:
        """A shallow copy (all fields are immutable)."""
        return dataclasses.replace(self)


@dataclass
class Action:
    """One effect of an accepted block, executed in order by the emulator.

    ``kind`` is ``motion`` (``target`` machine mm, ``rate`` mm/min, ``rapid``), ``dwell``
    (``seconds``), ``spindle``, ``coolant``, ``sync`` (wait for the planner to empty),
    ``pause`` (M0) or ``end`` (M2/M30). Spindle and coolant actions wait for the planner
    to empty, except a spindle one marked ``free``. A motion marked ``outside`` has its
    target beyond the soft limits (``$20=1``): Grbl's ``mc_line`` alarms when it comes to it.
    """

    kind: str
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rate: float = 0.0
    rapid: bool = False
    seconds: float = 0.0
    spindle: str = "M5"
    speed: float = 0.0
    free: bool = False  # a spindle speed change that does not wait for the planner
    outside: bool = False  # a motion whose target is beyond the soft limits


@dataclass
class Settings:
    """The settings the interpreter needs (a view of ``$$``)."""

    max_rate: tuple[float, float, float] = (500.0, 500.0, 500.0)
    max_travel: tuple[float, float, float] = (200.0, 200.0, 200.0)
    soft_limits: bool = False
    arc_tolerance: float = 0.002
    laser_mode: bool = False
    coord_offsets: list[tuple[float, float, float]] = field(
        default_factory=lambda: [(0.0, 0.0, 0.0)] * 6
    )
    g28: tuple[float, float, float] = (0.0, 0.0, 0.0)
    g30: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass
class Outcome:
    """An accepted block: new modal state, actions, soft-limit breach, new G54-G59 offsets."""

    state: ModalState
    actions: list[Action]
    soft_limit: bool = False
    coord_offsets: list[tuple[float, float, float]] = field(default_factory=list)


def read_number(line: str, i: int) -> tuple[float, int]:
    """Grbl's ``read_float``: optional sign, digits and one point; raises error 2."""
    j = i
    if j < len(line) and line[j] in "+-":
        j += 1
    digits = 0
    point = False
    while j < len(line) and (line[j].isdigit() or (line[j] == "." and not point)):
        if line[j] == ".":
            point = True
        else:
            digits += 1
        j += 1
    if digits == 0:
        raise GcodeError(2)
    return float(line[i:j]), j


def _words(line: str) -> list[tuple[str, float]]:
    """Split a pre-processed block into (letter, value) words; raises errors 1 and 2."""
    out: list[tuple[str, float]] = []
    i = 0
    while i < len(line):
        letter = line[i]
        if not ("A" <= letter <= "Z"):
            raise GcodeError(1)
        value, i = read_number(line, i + 1)
        out.append((letter, value))
    return out


_MOTION_G = {0: "G0", 1: "G1", 2: "G2", 3: "G3", 80: "G80"}


def interpret(line: str, state: ModalState, settings: Settings) -> Outcome:
    """Check and interpret one pre-processed block (no spaces, upper case, no comments).

    Args:
        line: The block as Grbl's line buffer holds it.
        state: The current modal state (not modified).
        settings: Machine settings (max rates, travel, soft limits, offsets); not modified.

    Returns:
        The outcome to commit. Raises :class:`GcodeError` with Grbl's code if rejected.
    """
    words = _words(line)
    groups: dict[str, int] = {}
    new = state.copy()
    motion: str | None = None
    nonmodal: str | None = None
    axis_command: str | None = None  # "motion" or "nonmodal"
    g53 = False
    values: dict[str, float] = {}
    stop: str | None = None
    spindle: str | None = None
    coolant: set[str] = set()
    coolant_off = False

    def group(name: str, value: int) -> None:
        if name in groups:
            raise GcodeError(21)
        groups[name] = value

    for letter, value in words:
        if letter == "G":
            iv = int(value)
            mantissa = round(100 * (value - iv))
            if iv in (0, 1, 2, 3, 80):
                if mantissa:
                    raise GcodeError(23)
                group("motion", iv)
                if axis_command == "nonmodal":
                    raise GcodeError(24)
                axis_command = "motion"
                motion = _MOTION_G[iv]
            elif iv == 38:
                raise GcodeError(20)
            elif iv in (4, 53):
                if mantissa:
                    raise GcodeError(23)
                group("nonmodal", iv)
                nonmodal = f"G{iv}"
                g53 = iv == 53
            elif iv in (10, 28, 30, 92):
                if mantissa not in (0, 10) or (iv == 10 and mantissa):
                    raise GcodeError(23)
                group("nonmodal", iv)
                if mantissa == 0 or iv == 92:
                    # G28/G30/G92/G10 use axis words; G28.1/G30.1/G92.1 do not
                    if mantissa == 0:
                        if axis_command == "motion":
                            raise GcodeError(24)
                        axis_command = "nonmodal"
                nonmodal = f"G{iv}" + (".1" if mantissa else "")
            elif iv in (17, 18, 19):
                if mantissa:
                    raise GcodeError(23)
                group("plane", iv)
                new.plane = iv
            elif iv in (90, 91):
                if mantissa:
                    if iv == 91 and mantissa == 10:
                        group("arc_distance", iv)
                        continue
                    raise GcodeError(20 if iv == 90 and mantissa == 10 else 23)
                group("distance", iv)
                new.relative = iv == 91
            elif iv in (93, 94):
                if mantissa:
                    raise GcodeError(23)
                group("feed_mode", iv)
                new.inverse_time = iv == 93
            elif iv in (20, 21):
                if mantissa:
                    raise GcodeError(23)
                group("units", iv)
                new.inches = iv == 20
            elif iv == 40:
                if mantissa:
                    raise GcodeError(23)
                group("cutter", iv)
            elif iv in (43, 49):
                if (iv == 43 and mantissa != 10) or (iv == 49 and mantissa):
                    raise GcodeError(20 if iv == 43 else 23)
                group("tlo", iv)
                if iv == 49:
                    new.tlo = 0.0
                else:
                    groups["tlo_set"] = 1
            elif 54 <= iv <= 59:
                if mantissa:
                    raise GcodeError(23)
                group("coord", iv)
                new.coord_index = iv - 54
            elif iv == 61:
                if mantissa:
                    raise GcodeError(23)
                group("control", iv)
            else:
                raise GcodeError(20)
        elif letter == "M":
            iv = int(value)
            if value != iv:
                raise GcodeError(23)
            if iv in (0, 1, 2, 30):
                group("stop", iv)
                stop = f"M{iv}"
            elif iv in (3, 4, 5):
                group("spindle", iv)
                spindle = f"M{iv}"
            elif iv in (7, 8, 9):
                group("coolant", iv)
                if iv == 9:
                    coolant_off = True
                else:
                    coolant.add(f"M{iv}")
            else:
                raise GcodeError(20)
        elif letter in _VALUE_LETTERS:
            if letter in values:
                raise GcodeError(25)
            if letter in "FNPST" and value < 0:
                raise GcodeError(4)
            if letter == "N" and value > MAX_LINE_NUMBER:
                raise GcodeError(27)
            if letter == "T" and value > MAX_TOOL_NUMBER:
                raise GcodeError(38)
            values[letter] = value
        else:
            raise GcodeError(20)

    scale = MM_PER_INCH if new.inches else 1.0
    used = {"N"}
    axis_words = {a: values[a] for a in _AXES if a in values}
    if axis_words and axis_command is None:
        axis_command = "motion"
    mode = motion or state.motion
    actions: list[Action] = []

    # feed rate
    if "F" in values:
        used.add("F")
        if not new.inverse_time:
            new.feed = values["F"] * scale
    feed = values["F"] if new.inverse_time and "F" in values else new.feed
    if new.inverse_time and not state.inverse_time and "F" not in values:
        feed = 0.0
    # spindle speed, tool
    if "S" in values:
        used.add("S")
        new.spindle_speed = values["S"]
    if "T" in values:
        used.add("T")
        new.tool = int(values["T"])
    # dwell
    if nonmodal == "G4":
        if "P" not in values:
            raise GcodeError(28)
        used.add("P")
    if "tlo_set" in groups:
        if set(axis_words) != {"Z"}:
            raise GcodeError(37)
        new.tlo = axis_words["Z"] * scale
        axis_words = {}
        axis_command = None
    # G10
    offsets = list(settings.coord_offsets)
    if nonmodal == "G10":
        if "L" not in values or "P" not in values:
            raise GcodeError(28)
        used.update("LP")
        if values["L"] not in (2.0, 20.0):
            raise GcodeError(20)
        if not axis_words:
            raise GcodeError(26)
        p = int(values["P"])
        if p > 6:
            raise GcodeError(29)
        idx = new.coord_index if p == 0 else p - 1
        cur = list(offsets[idx])
        for k, a in enumerate(_AXES):
            if a in axis_words:
                v = axis_words[a] * scale
                if values["L"] == 2.0:
                    cur[k] = v
                else:
                    cur[k] = state.position[k] - state.g92[k] - v - (new.tlo if k == 2 else 0.0)
        offsets[idx] = (cur[0], cur[1], cur[2])
    if nonmodal in ("G53",) and mode not in ("G0", "G1"):
        raise GcodeError(30)

    wcs = offsets[new.coord_index]

    def work_offset(k: int) -> float:
        return wcs[k] + state.g92[k] + (new.tlo if k == 2 else 0.0)

    def target_of(words: dict[str, float], machine: bool) -> tuple[float, float, float]:
        t = list(state.position)
        for k, a in enumerate(_AXES):
            if a not in words:
                continue
            v = words[a] * scale
            if machine:
                t[k] = v
            elif new.relative:
                t[k] = state.position[k] + v
            else:
                t[k] = v + work_offset(k)
        return (t[0], t[1], t[2])

    if nonmodal == "G92":
        if not axis_words:
            raise GcodeError(26)
        g92 = list(state.g92)
        for k, a in enumerate(_AXES):
            if a in axis_words:
                g92[k] = (
                    state.position[k]
                    - wcs[k]
                    - (new.tlo if k == 2 else 0.0)
                    - axis_words[a] * scale
                )
        new.g92 = (g92[0], g92[1], g92[2])
    elif nonmodal == "G92.1":
        new.g92 = (0.0, 0.0, 0.0)

    soft = False

    def check_limits(p: tuple[float, float, float]) -> bool:
        if not settings.soft_limits:
            return False
        return any(not (-settings.max_travel[k] - 1e-6 <= p[k] <= 1e-6) for k in range(3))

    def add_motion(target: tuple[float, float, float], rapid: bool, rate: float) -> None:
        nonlocal soft
        outside = check_limits(target)
        soft = soft or outside
        actions.append(Action("motion", target=target, rapid=rapid, rate=rate, outside=outside))

    # gc_execute_line steps 4, 7 and 8: only a change acts (and syncs). An S change with
    # the spindle on syncs too, except in laser mode ($32=1) in a block that moves
    # (GC_PARSER_LASER_ISMOTION); a spindle state change syncs even in laser mode. In laser
    # mode with M3 on, a block without motion that switches between G1/G2/G3 and another
    # motion mode syncs as well (GC_PARSER_LASER_FORCE_SYNC), the laser off outside G1-G3.
    if spindle is not None:
        new.spindle = spindle
    speed_change = "S" in values and values["S"] != state.spindle_speed and state.spindle != "M5"
    laser_motion = settings.laser_mode and axis_command == "motion" and bool(axis_words)
    cutting = ("G1", "G2", "G3")
    force_sync = (
        settings.laser_mode
        and not laser_motion
        and state.spindle == "M3"
        and (state.motion in cutting) != (mode in cutting)
    )
    if new.spindle != state.spindle or speed_change or force_sync:
        free = new.spindle == state.spindle and laser_motion
        speed = new.spindle_speed
        if force_sync and new.spindle == state.spindle and mode not in cutting:
            speed = 0.0
        actions.append(Action("spindle", spindle=new.spindle, speed=speed, free=free))
    if coolant or coolant_off:
        new.coolant = frozenset() if coolant_off else frozenset(coolant | set(state.coolant))
        if new.coolant != state.coolant:
            actions.append(Action("coolant"))
    if nonmodal == "G4":
        actions.append(Action("dwell", seconds=values["P"]))
    # Grbl empties the planner before a G10 (an EEPROM write) and before any change of the
    # work offset (FORCE_BUFFER_SYNC_DURING_WCO_CHANGE, on by default): G43.1/G49 to another
    # length, another of G54-G59, G92 and G92.1 (even to the same offset).
    wco_change = (
        new.tlo != state.tlo or new.coord_index != state.coord_index or nonmodal in ("G92", "G92.1")
    )
    if nonmodal == "G10" or wco_change:
        actions.append(Action("sync"))

    if nonmodal in ("G28", "G30"):
        stored = settings.g28 if nonmodal == "G28" else settings.g30
        mid = target_of(axis_words, False) if axis_words else state.position
        if axis_words:
            add_motion(mid, True, 0.0)
        add_motion(stored, True, 0.0)
        new.position = stored
    elif nonmodal in ("G28.1", "G30.1"):
        actions.append(Action("sync"))
    elif axis_command == "motion" and axis_words and nonmodal not in ("G10", "G92"):
        if mode == "G80":
            raise GcodeError(31)
        target = target_of(axis_words, g53)
        if mode == "G0":
            add_motion(target, True, 0.0)
        elif mode == "G1":
            if feed <= 0.0:
                raise GcodeError(22)
            rate = _rate(state.position, target, feed, new.inverse_time)
            add_motion(target, False, rate)
        else:
            if feed <= 0.0:
                raise GcodeError(22)
            for point, seg_rate in _arc(
                state, new, target, values, used, mode, scale, feed, settings
            ):
                add_motion(point, False, seg_rate)
        new.position = target
    if mode in ("G2", "G3") and axis_words:
        used.update("IJKR")
    new.motion = mode

    unused = set(values) - used - set(_AXES)
    if unused:
        raise GcodeError(36)

    if stop == "M0":  # Grbl 1.1 parses M1 (optional stop) and ignores it
        actions.append(Action("pause"))
    elif stop in ("M2", "M30"):
        actions.append(Action("end"))
        new.motion = "G1"
        new.plane = 17
        new.relative = False
        new.inverse_time = False
        new.coord_index = 0
        new.spindle = "M5"
        new.coolant = frozenset()  # G92, F, S and the units are kept (gcode.c, step 21)
    return Outcome(new, actions, soft, offsets)


def _rate(
    start: tuple[float, float, float],
    end: tuple[float, float, float],
    feed: float,
    inverse_time: bool,
) -> float:
    """Feed in mm/min for a G1 move (inverse time: the move takes 1/F minutes)."""
    if not inverse_time:
        return feed
    return math.dist(start, end) * feed


def _arc(
    state: ModalState,
    new: ModalState,
    target: tuple[float, float, float],
    values: dict[str, float],
    used: set[str],
    mode: str,
    scale: float,
    feed: float,
    settings: Settings,
) -> list[tuple[tuple[float, float, float], float]]:
    """Segment a G2/G3 arc the way ``mc_arc`` does (chord error <= ``$12``)."""
    axes = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}[new.plane]
    a0, a1, lin = axes
    names = "XYZ"
    offs = "IJK"
    if names[a0] not in values and names[a1] not in values and target == state.position:
        raise GcodeError(32)
    start = state.position
    dx = target[a0] - start[a0]
    dy = target[a1] - start[a1]
    clockwise = mode == "G2"
    if "R" in values:
        used.add("R")
        r = values["R"] * scale
        if dx == 0.0 and dy == 0.0:
            raise GcodeError(33)
        h2 = 4.0 * r * r - dx * dx - dy * dy
        if h2 < 0:
            raise GcodeError(34)
        h = -math.sqrt(h2) / math.hypot(dx, dy)
        if not clockwise:
            h = -h
        if r < 0:
            h = -h
            r = -r
        ci = 0.5 * (dx - dy * h)
        cj = 0.5 * (dy + dx * h)
    else:
        oa, ob = offs[a0], offs[a1]
        if oa not in values and ob not in values:
            raise GcodeError(35)
        ci = values.get(oa, 0.0) * scale
        cj = values.get(ob, 0.0) * scale
        used.update(offs)
        r = math.hypot(ci, cj)
        r_end = math.hypot(dx - ci, dy - cj)
        delta = abs(r_end - r)
        if delta > 0.005 and (delta > 0.5 or delta > 0.001 * r):
            raise GcodeError(33)
    cx, cy = start[a0] + ci, start[a1] + cj
    t0 = math.atan2(start[a1] - cy, start[a0] - cx)
    t1 = math.atan2(target[a1] - cy, target[a0] - cx)
    sweep = t1 - t0
    if clockwise and sweep >= -1e-9:
        sweep -= 2 * math.pi
    elif not clockwise and sweep <= 1e-9:
        sweep += 2 * math.pi
    tol = settings.arc_tolerance
    n = max(1, int(abs(sweep) * r / math.sqrt(max(tol * (2 * r - tol), 1e-12))))
    n = min(n, 2000)
    out: list[tuple[tuple[float, float, float], float]] = []
    length = math.hypot(abs(sweep) * r, target[lin] - start[lin])
    for i in range(1, n + 1):
        f = i / n
        ang = t0 + sweep * f
        p = [0.0, 0.0, 0.0]
        p[a0] = cx + r * math.cos(ang)
        p[a1] = cy + r * math.sin(ang)
        p[lin] = start[lin] + (target[lin] - start[lin]) * f
        if i == n:
            p = list(target)
        rate = length * feed if new.inverse_time else feed
        out.append(((p[0], p[1], p[2]), rate))
    return out
