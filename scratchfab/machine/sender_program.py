"""A G-code file as the sender sees it: stripped blocks, modal state, strokes, resume preamble.

Works on any G-code GRBL accepts, not only ours. Each file line becomes at most one *block*:
comments (``( )`` and ``;``) and whitespace removed and letters upper-cased, as GRBL's own
pre-processing does, so the bytes counted are the bytes GRBL stores. Blank and comment-only
lines (and ``%``) are not sent.

A *stroke* is what cuts. The tool is **down** after a block when the programmed Z is below
``z_threshold`` (given, or read from the program: between the Z of its cutting moves and the
Z of its rapids, :func:`auto_threshold`), or, in a job that moves at one Z level at most (a
servo/plotter job), when the spindle output is on (M3/M4), at another S than the one that
holds a servo up where the job lifts it so (``M3 S90``, :func:`lift_state`). A stroke is
the run of blocks from the block that puts the tool down up to and including the block
that lifts it (Z back up, M5, or the up S); :func:`stroke_spans` is the one definition
used by streaming and resuming.
"""

from __future__ import annotations

import collections
import hashlib
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from scratchfab.errors import ConfigError
from scratchfab.fileio import read_input
from scratchfab.machine.grbl_codes import MM_PER_INCH
from scratchfab.machine.profile import GCODE_WORD, gcode_number
from scratchfab.toolpath.timing import GRBL_JUNCTION_DEVIATION_MM, path_times

MAX_BLOCK_CHARS = 79
DEFAULT_RAPID_MM_MIN = (500.0, 500.0, 500.0)  # G0 rates for the estimate until $110-$112 are known
_REALTIME = set("?!~")
_LINE_END = re.compile(r"\r\n|[\r\n]")
#: Control characters GRBL does not take as a tab (a line holds no CR or LF).
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")
#: ``$`` lines a job may hold: reports that move nothing and change no setting or state.
_QUERIES = frozenset({"$", "$$", "$#", "$G", "$I", "$N"})
#: GRBL's comments: ``(`` up to ``)`` or the line's end, and ``;`` to the line's end.
_COMMENT = re.compile(r"\([^)]*\)?|;.*", re.DOTALL)
#: What GRBL's pre-processing drops outside comments: whitespace, control characters, ``/``.
_DROPPED = str.maketrans("", "", "".join(map(chr, range(33))) + "/")


def strip_block(raw: str) -> str:
    """GRBL's pre-processing: drop comments, whitespace and ``/``; upper-case the rest."""
    if raw.isascii():
        text = _COMMENT.sub("", raw).translate(_DROPPED).upper()
        return "" if text == "%" else text
    out: list[str] = []
    depth = False
    for ch in raw:
        if depth:
            if ch == ")":
                depth = False
            continue
        if ch == "(":
            depth = True
        elif ch == ";":
            break
        elif ch <= " " or ch == "/":
            continue
        else:
            out.append(ch.upper())
    text = "".join(out)
    return "" if text == "%" else text


@dataclass(frozen=True)
class Modal:
    """The sender's view of the modal state after a block (positions in work mm)."""

    motion: str = "G0"
    inches: bool = False
    relative: bool = False
    plane: str = "G17"
    feed_mode: str = "G94"
    wcs: str = "G54"
    feed: float = 0.0  # in the file's units per minute (as last written)
    spindle: str = "M5"
    speed: float = 0.0
    coolant: str = "M9"
    # None: not known (Z until the program sets it; any axis after a change of the work
    # frame until a block gives it in absolute mode, :func:`_frame_change`; a G91 move keeps
    # an unknown axis unknown)
    x: float | None = 0.0
    y: float | None = 0.0
    z: float | None = None
    # the tool length offset (mm) the file set (G43.1; G49: 0); None: the file has not set
    # one (GRBL's after a reset is 0, what was set before the job is not known)
    tlo: float | None = None
    z_frame: int = 0  # how many times the frame work Z is counted in has changed
    g92: str = ""  # the axes the file's own G92 offsets (a reset clears them, and G92.1)
    # the axes still counted from the start the parse assumes (work X0 Y0) rather than
    # where the machine stood: used for estimates and checks, never matched (:func:`_ends`)
    assumed: str = "XY"

    @property
    def mm_per_unit(self) -> float:
        """Millimetres per unit of the file's coordinates and feeds (G20 inch or G21 mm)."""
        return MM_PER_INCH if self.inches else 1.0

    @property
    def feed_mm(self) -> float:
        """The feed in mm/min; meaningful under G94 only (G93's F is an inverse time)."""
        return self.feed * self.mm_per_unit


@dataclass(frozen=True)
class Block:
    """One line to send: ``index`` among blocks, ``lineno`` in the file (1-based)."""

    index: int
    lineno: int
    text: str
    modal: Modal  # state after the block
    seconds: float  # estimated run time
    motion: bool  # creates planner blocks
    sync_before: bool  # GRBL empties the planner before the block's motion, whatever $32 says
    sync_after: bool  # ... after its motion (M0, M2, M30); see _advance for both
    system: bool  # a ``$`` command (sent with send-response)
    unfollowed: str = ""  # why the sender cannot follow the position past it ("" if it can)
    arc_box: tuple[float, float, float, float] | None = None  # X lo, X hi, Y lo, Y hi swept
    rapid_mm: tuple[float, float, float] | None = None  # a G0's distance per axis
    speed_sync: bool = False  # empties it before the motion with laser mode off ($32=0) only
    laser_sync: bool = False  # ... with laser mode on ($32=1) only

    @property
    def sync(self) -> bool:
        """GRBL empties the planner at this block, before or after its motion, whatever $32 says."""
        return self.sync_before or self.sync_after

    def syncs_before(self, laser_mode: bool) -> bool:
        """Whether GRBL empties the planner before the block's motion, given ``$32``."""
        return self.sync_before or (self.laser_sync if laser_mode else self.speed_sync)


@dataclass
class Program:
    """A parsed G-code file."""

    path: Path
    sha256: str
    blocks: list[Block]
    strokes: list[tuple[int, int]]  # (first, last) block index of each stroke
    z_threshold: float | None  # None: the program does not show which Z cuts
    pen_mode: bool
    rapid_mm_min: tuple[float, float, float] = DEFAULT_RAPID_MM_MIN
    # a servo job held up with the output on: the S that holds it up (None: M5 lifts it)
    lift_speed: float | None = None
    tool_up: str = "M5"  # the block that lifts a servo job's tool (M5, or M3/M4 at lift_speed)

    @property
    def total_seconds(self) -> float:
        """Estimated run time (distance / feed, G0 at the max rates)."""
        return sum(b.seconds for b in self.blocks)

    def at_rapid_rates(self, rapid_mm_min: Sequence[float]) -> Program:
        """The same program with its G0 blocks timed at other rates (GRBL's $110-$112)."""
        rates = (float(rapid_mm_min[0]), float(rapid_mm_min[1]), float(rapid_mm_min[2]))
        blocks = [
            b
            if b.rapid_mm is None
            else replace(
                b,
                seconds=b.seconds
                - _rapid_seconds(b.rapid_mm, self.rapid_mm_min)
                + _rapid_seconds(b.rapid_mm, rates),
            )
            for b in self.blocks
        ]
        return replace(self, blocks=blocks, rapid_mm_min=rates)

    def placed_at(self, work_xy: Sequence[float], wcs: str | None = "G54") -> Program:
        """The program as streamed from work ``(x, y)`` (mm), its first moves drawn from there.

        Where its blocks count X or Y from the start the parse assumes (work X0 Y0,
        :attr:`Modal.assumed`), they count from ``(x, y)`` instead, and an arc from there
        sweeps from there (:attr:`Block.arc_box`). The sender reads where
        the machine stands before it streams; a stop's position is then matched against
        the job's first moves as they really run, except a move in the file's first block,
        whose start stays unknown (:func:`_ends`). ``(x, y)`` is in the controller's work
        system ``wcs`` (``$G``; GRBL's G54 after a reset; None: not known): from a block
        where the file has selected another, the rest stays unknown where matched.
        """
        blocks = list(self.blocks)
        selected = False  # the file has selected a work system
        before = Modal()  # as parsed, and as placed:
        placed = replace(before, x=float(work_xy[0]), y=float(work_xy[1]), assumed="")
        for k, b in enumerate(blocks):
            if not before.assumed:
                break  # an axis once given stays given
            m = b.modal
            selected = selected or _sets_wcs([b])
            if selected and m.wcs != wcs:
                break  # (x, y) is in another system than the file's from here
            x = m.x + work_xy[0] if "X" in m.assumed and m.x is not None else m.x
            y = m.y + work_xy[1] if "Y" in m.assumed and m.y is not None else m.y
            after = replace(m, x=x, y=y, assumed="")
            box = None if b.arc_box is None else _block_arc_box(b.text, placed, after)
            blocks[k] = replace(b, modal=after, arc_box=box)
            before, placed = m, after
        return replace(self, blocks=blocks)

    def timed_for(self, settings: Mapping[int, float]) -> Program:
        """The program timed as GRBL plans it with these ``$$`` settings.

        G0 runs at ``$110``-``$112`` (unknown: the estimate is kept). With ``$120``-``$122``
        known too, straight moves accelerate and join at corners by ``$11`` (GRBL's default
        when not given), as :func:`~scratchfab.toolpath.timing.path_times` plans them; the
        machine stops where a block empties the planner, before its motion
        (:meth:`Block.syncs_before` for this ``$32``) or after it (``Block.sync_after``),
        around an arc (timed alone, by its chord and feed), at a feed move without a feed
        (GRBL refuses it) and where the sender cannot follow the position.
        """
        rates = [settings.get(110 + k) for k in range(3)]
        if not all(r is not None and r > 0 for r in rates):
            return self
        program = self.at_rapid_rates([float(r or 0) for r in rates])
        accel = [settings.get(120 + k) for k in range(3)]
        if not all(a is not None and a > 0 for a in accel):
            return program
        laser = bool(settings.get(32, 0))
        moves: list[int] = []
        delta: list[tuple[float, float, float]] = []
        feed: list[float] = []
        rest: list[bool] = []
        stop = True  # the job starts at rest
        before = Modal()
        for b in program.blocks:
            after = b.modal
            empties = b.syncs_before(laser)
            straight = b.motion and not b.unfollowed and b.arc_box is None
            straight = straight and after.motion in ("G0", "G1")
            if straight:
                (ax, ay, az), (bx, by, bz) = _estimate_xyz(after), _estimate_xyz(before)
                d = (ax - bx, ay - by, az - bz)
                dist = math.hypot(*d)
                if after.motion == "G0":
                    rate = math.inf
                else:
                    rate = after.feed_mm if after.feed_mode == "G94" else dist * after.feed
                straight = rate > 0 or dist == 0  # no feed: error:22, no motion
            if straight:
                moves.append(b.index)
                delta.append(d)
                feed.append(rate)
                rest.append(stop or empties)  # a spindle, coolant or S change acts first
                stop = b.sync_after
            else:
                stop = stop or empties or b.sync_after or b.motion or bool(b.unfollowed)
            before = after
        if not moves:
            return program
        seconds = path_times(
            np.asarray(delta),
            np.asarray(feed),
            program.rapid_mm_min,
            (float(accel[0] or 0), float(accel[1] or 0), float(accel[2] or 0)),
            rest_before=np.asarray(rest),
            junction_deviation_mm=float(settings.get(11, GRBL_JUNCTION_DEVIATION_MM)),
        )
        blocks = list(program.blocks)
        for k, t in zip(moves, seconds, strict=True):
            blocks[k] = replace(blocks[k], seconds=float(t))
        return replace(program, blocks=blocks)

    def stroke_of(self) -> list[int]:
        """Per block, the index of the stroke it belongs to, or -1."""
        out = [-1] * len(self.blocks)
        for k, (a, b) in enumerate(self.strokes):
            for i in range(a, b + 1):
                out[i] = k
        return out


def work_xyz(modal: Modal) -> tuple[float | None, float | None, float | None]:
    """The work position (mm) after a block, None on an axis where it is not known."""
    return (modal.x, modal.y, modal.z)


def _estimate_xyz(modal: Modal) -> tuple[float, float, float]:
    """The work position for time estimates: an unknown axis taken as 0."""
    return _or_zero(work_xyz(modal))


def _or_zero(xyz: Sequence[float | None]) -> tuple[float, float, float]:
    """``xyz`` with an unknown (None) axis taken as 0."""
    x, y, z = (v if v is not None else 0.0 for v in xyz)
    return x, y, z


#: A block Grbl 1.1 reads to its end: words only, each a letter and a number.
_WORDS = re.compile(f"(?:{GCODE_WORD.pattern})*")
#: What a character GRBL stops at may have meant, for its error message.
_STOP_HINTS = {
    ",": " (a decimal comma? GRBL reads a point: 1.5)",
    ".": " (a second decimal point)",
    "*": " (a checksum? GRBL 1.1 takes none)",
}


def _word_error(block: str) -> str | None:
    """Why Grbl 1.1 would refuse a stripped block's words (error:1 or error:2), or None.

    ``gc_execute_line`` (``grbl/gcode.c``) reads the block as words: a letter A-Z (else
    error:1, expected command letter), then a number as ``read_float``
    (``grbl/nuts_bolts.c``) reads it: an optional sign, then digits with at most one
    decimal point, at least one digit (else error:2, bad number format). The number
    ends at the first character that is neither, which must start the next word. So
    ``X.5``, ``X-0.5``, ``X+1``, ``X1.`` and ``X0010`` are words; ``X1,5`` (the comma),
    ``X1*71`` (a checksum) and a ``%`` within a block are error:1; ``X``, ``X-``, ``X.``
    and ``XY1`` (X has no number) are error:2. GRBL checks a block only when it comes to
    it, so it would refuse the line mid-job.
    """
    if _WORDS.fullmatch(block):
        return None
    start = end = 0  # the last word GRBL reads whole, and where it stops
    while (m := GCODE_WORD.match(block, end)) is not None:
        start, end = end, m.end()
    stop = next((k for k in range(end + 1, len(block)) if "A" <= block[k] <= "Z"), len(block))
    found = block[end]
    if "A" <= found <= "Z":
        return (
            f"error:2 (bad number format) at {block[end:stop]!r}: it expects a number after "
            f"the letter {found}: an optional sign, then digits with at most one decimal "
            f"point ({found}1.5, {found}-0.5, {found}.5)"
        )
    return (
        f"error:1 (expected command letter) at {block[start:stop]!r}: it expects each word "
        f"to be a letter A-Z and a number, and finds {found!r} where a word's letter belongs"
        + _STOP_HINTS.get(found, "")
    )


def block_words(text: str) -> list[tuple[str, float]]:
    """The words of a block as :func:`strip_block` leaves it: (letter, value) pairs."""
    return [(letter, float(value)) for letter, value in GCODE_WORD.findall(text)]


class _Sync(NamedTuple):
    """Where a block empties GRBL's planner (see :class:`Block`)."""

    before: bool = False
    after: bool = False
    speed: bool = False  # before, with $32=0 only
    laser: bool = False  # before, with $32=1 only


class _Step(NamedTuple):
    modal: Modal
    seconds: float
    motion: bool
    sync: _Sync = _Sync()
    unfollowed: str = ""
    arc_box: tuple[float, float, float, float] | None = None
    rapid_mm: tuple[float, float, float] | None = None


def _rapid_seconds(axis_mm: Sequence[float], rapid_mm_min: Sequence[float]) -> float:
    """A G0's time: each axis at most at its own max rate, so the slowest axis sets it."""
    return 60.0 * max(
        (d / r for d, r in zip(axis_mm, rapid_mm_min, strict=True) if d > 0 and r > 0),
        default=0.0,
    )


def _arc_box(
    start: tuple[float, float],
    end: tuple[float, float],
    arc: dict[str, float],
    cw: bool,
    scale: float,
) -> tuple[float, float, float, float] | None:
    """X and Y extent of a G17 arc (work mm), centre found as GRBL does; None if GRBL rejects it.

    The centre is ``start + (I, J)``, or from ``R`` by GRBL's own formula (the sign of R
    picks the longer or shorter arc). The box holds both ends and every axis extreme
    (0, 90, 180, 270 degrees) the sweep passes; equal ends make a full circle.
    """
    dx, dy = end[0] - start[0], end[1] - start[1]
    if "R" in arc:
        r = arc["R"] * scale
        chord = math.hypot(dx, dy)
        h2 = 4.0 * r * r - chord * chord
        if chord == 0.0 or h2 < 0.0:
            return None  # error:33, no motion
        h = -math.sqrt(h2) / chord
        h = -h if not cw else h
        h = -h if r < 0 else h
        ci, cj = 0.5 * (dx - dy * h), 0.5 * (dy + dx * h)
    elif "I" in arc or "J" in arc:
        ci, cj = arc.get("I", 0.0) * scale, arc.get("J", 0.0) * scale
    else:
        return None  # error:35 (no I/J offset in the plane), no motion
    cx, cy = start[0] + ci, start[1] + cj
    radius = math.hypot(ci, cj)
    a0 = math.atan2(start[1] - cy, start[0] - cx)
    a1 = math.atan2(end[1] - cy, end[0] - cx)
    sweep = ((a0 - a1) if cw else (a1 - a0)) % math.tau
    if sweep <= 5e-7:  # GRBL's ARC_ANGULAR_TRAVEL_EPSILON: a full circle
        sweep = math.tau
    xs, ys = [start[0], end[0]], [start[1], end[1]]
    for k in range(4):
        extreme = k * math.pi / 2
        if ((a0 - extreme) if cw else (extreme - a0)) % math.tau <= sweep:
            xs.append(cx + radius * math.cos(extreme))
            ys.append(cy + radius * math.sin(extreme))
    return min(xs), max(xs), min(ys), max(ys)


def _block_arc_box(
    text: str, before: Modal, after: Modal
) -> tuple[float, float, float, float] | None:
    """:func:`_arc_box` of an arc block (stripped ``text``) run from ``before`` to ``after``."""
    arc = {letter: v for letter, v in block_words(text) if letter in "IJKR"}
    start, end = _estimate_xyz(before), _estimate_xyz(after)
    return _arc_box(start[:2], end[:2], arc, after.motion == "G2", after.mm_per_unit)


def _unfollowed(
    nonmodal: str, axes: dict[str, float], wcs_before: str, after: Mapping[str, Any]
) -> str:
    """Why the sender loses the position or the coordinate frame at a block ("" if not).

    ``after`` is the state after the block (:class:`Modal`'s fields by name).
    """
    if nonmodal == "G92.1" or (nonmodal in ("G92", "G10") and axes):
        return f"{nonmodal} changes the work coordinates"
    if nonmodal in ("G28", "G30"):
        return f"{nonmodal} moves through a stored machine position"
    if nonmodal == "G53" and axes:
        return "G53 moves in machine coordinates"
    if after["wcs"] != wcs_before:
        return f"{after['wcs']} selects another work coordinate system"
    if axes and after["motion"] in ("G2", "G3") and after["plane"] != "G17":
        return f"an arc in the {after['plane']} plane"
    return ""


_WCS = ("G54", "G55", "G56", "G57", "G58", "G59")


def _changes_tlo(current: float | None, tlo: float | None) -> bool:
    """Whether setting the tool length offset to ``tlo`` (mm; None: not set) may move work Z.

    ``current`` is the offset in force (:attr:`Modal.tlo`). Where the file has set none
    (None) a 0 (G49, common in headers) is taken for GRBL's own after a reset: no change.
    """
    return tlo is not None and tlo != (current or 0.0)


def _frame_change(
    w: dict[str, Any],
    wcs_before: str,
    nonmodal: str,
    words: list[tuple[str, float]],
    tlo: float | None = None,
) -> None:
    """The work position after a block's change of the work frame, before its motion.

    ``w`` is the block's working state (:class:`Modal`'s fields by name, the block's modal
    words applied), changed in place; ``wcs_before`` the work system before the block.

    GRBL changes the frame before the block's motion (``gc_execute_line``: G54-G59 at
    step 12, G43.1/G49 at step 14, G10, G53, G92 at step 19, the motion at step 20). Where
    the new frame's offset is not known to the sender, so is not the machine's work
    position in it, on the axes the offset changes: every axis after another G54-G59
    system, G92.1, G28 or G30 (which end at a stored machine position); the axes given
    after G10 L2 on the system in use (P0, or its own P1-P6) and after G53 (a move in
    machine coordinates); Z after a tool length offset ``tlo`` (mm, set by G43.1 or G49)
    other than the file's (:attr:`Modal.tlo`; where the file has set none, any but G49's
    0). G92, and G10 L20 on the system in use, set the axes given to the values given (in
    the block's units, whatever G90/G91 says): known. A lost axis stays unknown until a
    block gives it in absolute mode (G90).
    """
    if not nonmodal and tlo is None and w["wcs"] == wcs_before:
        return  # (the common block: no change of the frame)
    scale = MM_PER_INCH if w["inches"] else 1.0
    given = {letter: value * scale for letter, value in words if letter in "XYZ"}
    lost: set[str] = set()
    found: dict[str, float] = {}
    if nonmodal == "G92.1":
        w["g92"] = ""
    if w["wcs"] != wcs_before or nonmodal in ("G92.1", "G28", "G30"):
        lost = {"X", "Y", "Z"}
    elif nonmodal == "G53":
        lost = set(given)
    elif nonmodal in ("G10", "G92"):
        level = next((v for letter, v in words if letter == "L"), None)
        system = next((v for letter, v in words if letter == "P"), None)
        current = system in (0.0, float(_WCS.index(w["wcs"]) + 1))
        if nonmodal == "G92" or (level == 20.0 and current):
            found = given
        elif level == 2.0 and current:
            lost = set(given)
        if nonmodal == "G92":
            w["g92"] = "".join(a for a in "XYZ" if a in w["g92"] or a in given)
    if _changes_tlo(w["tlo"], tlo):
        lost.add("Z")
    if tlo is not None:
        w["tlo"] = tlo
    if not lost and not found:
        return
    for a in "XYZ":
        if a in lost:
            w[a.lower()] = None
        elif a in found:
            w[a.lower()] = found[a]
    w["assumed"] = "".join(a for a in w["assumed"] if a not in found and a not in lost)
    w["z_frame"] += "Z" in lost or "Z" in found


def _advance(state: Modal, text: str, rapid_mm_min: Sequence[float]) -> _Step:
    """One block's effect: modal state after it, estimated seconds, motion and sync flags.

    Also what the sender cannot follow past it (frame changes, machine-coordinate moves)
    and what it adds to the job's extent (the box an arc sweeps).

    Sync as Grbl 1.1h's ``gc_execute_line`` (``grbl/gcode.c``) does it with its default
    build options (``protocol_buffer_synchronize``), in its order of execution. Before the
    block's motion: an S change while the spindle is on (step 4; ``$32=0`` only, or with
    ``$32=1`` in a block that does not move, ``GC_PARSER_LASER_ISMOTION``: axis words of a
    motion mode, so not G28/G30's; under M3 in laser mode a block without motion that
    switches between G1/G2/G3 and another motion mode also syncs, ``LASER_FORCE_SYNC``), a
    spindle state *change* (M3/M4/M5, step 7, even in laser mode), a coolant change (step
    8), G4 (``mc_dwell``), a work offset change (``FORCE_BUFFER_SYNC_DURING_WCO_CHANGE``:
    G54-G59 to another system, G92, G92.1, G10 L2/L20, G43.1/G49 to another tool length
    offset, claimed only where the file set the one before) and the EEPROM writes G10,
    G28.1/G30.1 (``FORCE_BUFFER_SYNC_DURING_EEPROM_WRITE``). After it: M0, M2 and M30
    (step 21, program flow). No sync: a repeated M3 or M5, M9 with coolant off, M1
    (ignored by Grbl 1.1), G28/G30 (an EEPROM read), ``$`` lines (run at once, or refused
    while moving). The flags: ``before`` whatever ``$32`` says,
    ``speed`` only with ``$32=0`` (an S change in a block that moves), ``laser`` only with
    ``$32=1`` (the forced sync), ``after``.
    """
    if text.startswith("$"):
        return _Step(state, 0.0, False)
    words = block_words(text)
    w = dict(vars(state))  # the working state: :class:`Modal`'s fields, frozen at the end
    axes: dict[str, float] = {}
    arc: dict[str, float] = {}
    nonmodal = ""
    offset = ""
    tlo: float | None = None  # the tool length offset the block sets (mm)
    sync = False
    ending = ""
    speed_changed = False
    dwell = 0.0
    for letter, value in words:
        if letter == "G":
            code = f"G{value:g}"
            if code in ("G0", "G1", "G2", "G3", "G80"):
                w["motion"] = code
            elif code in ("G20", "G21"):
                w["inches"] = code == "G20"
            elif code in ("G90", "G91"):
                w["relative"] = code == "G91"
            elif code in ("G17", "G18", "G19"):
                w["plane"] = code
            elif code in ("G93", "G94"):
                w["feed_mode"] = code
            elif code in _WCS:
                w["wcs"] = code
            elif code in ("G4", "G10", "G28", "G30", "G53", "G92", "G28.1", "G30.1", "G92.1"):
                nonmodal = code
            elif code in ("G43.1", "G49"):
                offset = code  # its axis word is the offset, not a move
                tlo = 0.0 if code == "G49" else None
        elif letter == "M":
            code = f"M{value:g}"
            if code in ("M3", "M4", "M5"):
                w["spindle"] = code
                sync = sync or code != state.spindle
            elif code in ("M7", "M8", "M9"):
                # Grbl keeps M7 and M8 as two bits: only a change from all off surely syncs
                w["coolant"] = code
                sync = sync or (code == "M9") != (state.coolant == "M9")
            elif code in ("M0", "M2", "M30"):
                ending = code
        elif letter == "F":
            w["feed"] = value
        elif letter == "S":
            speed_changed = state.spindle != "M5" and value != state.speed
            w["speed"] = value
        elif letter == "P" and nonmodal == "G4":
            dwell = value
        elif letter in "XYZ":
            axes[letter] = value
        elif letter in "IJKR":
            arc[letter] = value
    scale = MM_PER_INCH if w["inches"] else 1.0  # the block's units (Modal.mm_per_unit)
    if nonmodal in ("G4", "G10", "G28.1", "G30.1", "G92.1") or (nonmodal == "G92" and axes):
        sync = True
    if offset == "G43.1":  # Z only, else error:37
        tlo = next((v * scale for letter, v in words if letter == "Z"), None)
    sync = sync or w["wcs"] != state.wcs
    sync = sync or (state.tlo is not None and _changes_tlo(state.tlo, tlo))
    # GRBL's laser mode passes an S change in a block whose axis words drive a motion mode
    drives = bool(axes) and not offset and nonmodal not in ("G10", "G28", "G30", "G92")
    feeding, was_feeding = (m in ("G1", "G2", "G3") for m in (w["motion"], state.motion))
    forced = state.spindle == "M3" and feeding != was_feeding
    sync = sync or (speed_changed and not drives)
    flags = _Sync(
        before=sync,
        after=bool(ending),
        speed=speed_changed and not sync,
        laser=forced and not drives and not sync,
    )
    motion = False
    seconds = dwell
    box = None
    rapid = None
    moving = not offset and nonmodal not in ("G10", "G92", "G28", "G30", "G53")
    _frame_change(w, state.wcs, nonmodal, words, tlo)
    mode, relative = w["motion"], w["relative"]
    if axes and moving and mode != "G80":
        # the estimate takes an unknown start as 0; a G91 move from it stays unknown
        known = [w["x"], w["y"], w["z"]]
        start = _or_zero(known)
        end = list(start)
        for k, a in enumerate("XYZ"):
            if a in axes:
                v = axes[a] * scale
                end[k] = start[k] + v if relative else v
                known[k] = None if relative and known[k] is None else end[k]
        if mode == "G0":
            rapid = (abs(end[0] - start[0]), abs(end[1] - start[1]), abs(end[2] - start[2]))
            seconds += _rapid_seconds(rapid, rapid_mm_min)
        else:
            dist = math.dist(start, end)
            rate = w["feed"] * scale if w["feed_mode"] == "G94" else dist * w["feed"]
            seconds += dist / rate * 60.0 if rate > 0 and math.isfinite(rate) else 0.0
        if mode in ("G2", "G3") and w["plane"] == "G17":
            box = _arc_box(start[:2], (end[0], end[1]), arc, mode == "G2", scale)
        w["assumed"] = "".join(a for a in w["assumed"] if relative or a not in axes)
        w["x"], w["y"], w["z"] = known
        motion = True
    elif nonmodal in ("G28", "G30") or (axes and nonmodal == "G53"):
        motion = True  # G28/G30 move to the stored position, through the point given
    unfollowed = _unfollowed(nonmodal, axes, state.wcs, w)
    if _changes_tlo(state.tlo, tlo):
        what = "changes" if offset == "G43.1" else "cancels"
        unfollowed = unfollowed or f"{offset} {what} the tool length offset (work Z)"
    if ending in ("M2", "M30"):  # after the motion
        wcs, w["wcs"] = w["wcs"], "G54"
        _frame_change(w, wcs, "", [])
        w.update(
            motion="G1", relative=False, plane="G17", feed_mode="G94", spindle="M5", coolant="M9"
        )
        unfollowed = unfollowed or _unfollowed("", {}, state.wcs, w)  # back to G54
    return _Step(Modal(**w), seconds, motion, flags, unfollowed, box, rapid)


def _tool_down(
    modal: Modal, z_threshold: float, pen_mode: bool, lift_speed: float | None = None
) -> bool:
    """Whether the tool is down after a block with state ``modal`` (see the module docstring).

    In pen mode: the output on (M3/M4), and where the job holds the servo up with the
    output on (``lift_speed``, :func:`lift_state`), at another S than that one and S0.
    """
    if pen_mode:
        on = modal.spindle in ("M3", "M4")
        return on and (lift_speed is None or modal.speed not in (0.0, lift_speed))
    return modal.z is not None and modal.z < z_threshold - 1e-9


def stroke_spans(
    blocks: Sequence[Block],
    z_threshold: float,
    pen_mode: bool,
    lift_speed: float | None = None,
) -> list[tuple[int, int]]:
    """The strokes: (first, last) block indices from tool-down to tool-up, both included.

    Args:
        blocks: The program's blocks (their ``modal`` is the state after each block).
        z_threshold: Z (work mm) below which the tool cuts.
        pen_mode: Use the spindle output (M3/M4 on) instead of Z as the tool state.
        lift_speed: In pen mode, the S that holds the tool up with the output on (None:
            M5 lifts it, any M3/M4 is down; :func:`lift_state`).
    """
    spans: list[tuple[int, int]] = []
    first = -1
    for b in blocks:
        down = _tool_down(b.modal, z_threshold, pen_mode, lift_speed)
        if down and first < 0:
            first = b.index
        elif not down and first >= 0:
            spans.append((first, b.index))
            first = -1
    if first >= 0:
        spans.append((first, len(blocks) - 1))
    return spans


def _followed_moves(blocks: Sequence[Block]) -> Iterator[tuple[Block, bool]]:
    """The motion blocks the sender follows, each with whether it moves in X or Y (an arc does)."""
    prev_xy: tuple[float | None, float | None] = (0.0, 0.0)
    for b in blocks:
        xy = (b.modal.x, b.modal.y)
        if b.motion and not b.unfollowed:
            yield b, xy != prev_xy or b.arc_box is not None
        prev_xy = xy


def servo_up(program: Program | None, profile_off: str | None) -> str:
    """The command that raises a servo job's tool, for a stop's lift and its advice.

    The file's own where it holds the tool up with the output on (``M3 S90``: it moves
    under that S, whatever the profile's ``off`` says, and M5 would leave the servo where
    PWM 0 puts it); else the servo profile's ``off`` (``profile_off``); else the file's
    (M5).
    """
    if program is not None and program.lift_speed is not None:
        return program.tool_up
    if profile_off is not None:
        return profile_off
    return "M5" if program is None else program.tool_up


def lift_state(blocks: Sequence[Block], tool_up: str | None = None) -> tuple[str, float] | None:
    """The M3/M4 and S with which a servo job holds its tool up, where not by M5; else None.

    Many hobby servo plotters hold the pen up with the output on (``M3 S90``) and lower it
    at another S (``M3 S35``). Told by the S levels the job's XY moves run under with the
    output on (M3/M4): the machine profile's up command (``tool_up``, its ``[tool_control]
    off``) where it sets an S the job moves under; else, where the job moves under exactly
    two levels above 0, the one its rapids (G0) run under where they run under one only
    and no feed move does, or, in a job whose rapids run under neither, the one both its
    first and its last XY move run under (a job travels to its first stroke and back home
    with the tool up; a file that starts drawing at once shows two levels there and is
    not guessed); else S0
    (GRBL's output off, as M5) where the job moves under it and one level above it. None
    (M5 lifts the tool, any M3/M4 is down) where the job moves under one level only or
    does not tell which one is up. The M code is the one the job first moves under that S
    with.
    """
    levels: dict[float, str] = {}  # S level -> its M code
    rapid: set[float] = set()  # the levels above 0 rapids and feed moves run under
    feed: set[float] = set()
    first: float | None = None  # the level of the first XY move (None: the output off)
    last: float | None = None  # and of the last
    seen = False
    for b, moved_xy in _followed_moves(blocks):
        if not moved_xy:
            continue
        m = b.modal
        on = m.spindle in ("M3", "M4")
        last = m.speed if on else None
        if not seen:
            seen, first = True, last
        if on:
            levels.setdefault(m.speed, m.spindle)
            if m.speed > 0:
                (rapid if m.motion == "G0" else feed).add(m.speed)
    words = block_words(strip_block(tool_up or ""))
    up = next((v for letter, v in words if letter == "S"), None)
    above = len(levels) - (0.0 in levels)
    if ("M", 5.0) in words or up not in levels:
        if above == 2:
            if rapid:
                up = next(iter(rapid)) if len(rapid) == 1 and not rapid & feed else None
            else:
                up = first if first and first == last else None
        else:
            up = 0.0 if above == 1 and 0.0 in levels else None
    return None if up is None else (levels[up], up)


def auto_threshold(blocks: Sequence[Block]) -> float | None:
    """Z below which the tool cuts, read from the program itself; None when it cannot tell.

    Rapids (G0) never cut, so the lowest Z a G0 reaches is a travel height; the cutting
    level is the highest Z below it at which feed moves (G1/G2/G3) go in XY. The threshold
    is halfway between them. A job that rapids nowhere at a known Z tells cutting from
    travel only when its feed moves use exactly two Z levels (the lower one cuts). Works
    at any Z zero (surface at 0, or a machine-zeroed job cutting at Z-30).
    """
    rapid_z: set[float] = set()
    feed_z: set[float] = set()
    for b, moved_xy in _followed_moves(blocks):
        m = b.modal
        if m.z is None:
            continue
        if m.motion == "G0":
            rapid_z.add(round(m.z, 6))
        elif m.motion in ("G1", "G2", "G3") and moved_xy:
            feed_z.add(round(m.z, 6))
    if rapid_z:
        travel = min(rapid_z)
        cuts = [z for z in feed_z if z < travel]
        return 0.5 * (max(cuts) + travel) if cuts else None
    if len(feed_z) == 2:
        return 0.5 * (min(feed_z) + max(feed_z))
    return None


def z_levels(blocks: Sequence[Block]) -> list[float]:
    """The distinct Z (work mm) the program's motion blocks end at, ascending."""
    return sorted({round(b.modal.z, 6) for b in blocks if b.motion and b.modal.z is not None})


def travel_height(program: Program) -> float | None:
    """The Z (work mm) a stopped job's tool is raised to without a machine profile.

    The highest Z the program's own moves reach: the file goes there itself, so it is
    within the machine's travel (the settings check covers the whole job) and clears
    whatever the file clears between strokes (our exports travel at ``z.safe_mm`` only).
    None when the program sets no Z, or when that Z is not above its cutting threshold
    (nothing in the file shows a height that clears the board).
    """
    levels = z_levels(program.blocks)
    if not levels:
        return None
    top = levels[-1]
    if program.z_threshold is not None and top <= program.z_threshold:
        return None
    return top


def load_program(
    path: str | Path,
    z_threshold: float | None = None,
    rapid_mm_min: Sequence[float] = DEFAULT_RAPID_MM_MIN,
    tool_up: str | None = None,
) -> Program:
    """Read and check a G-code file.

    Args:
        path: The G-code file.
        z_threshold: Z (work mm) below which the tool is down; None: :func:`auto_threshold`
            (a program that does not show it has no strokes, unless it is a servo job).
        rapid_mm_min: G0 rates per axis for the time estimate (GRBL's $110-$112).
        tool_up: A servo machine profile's up command (``[tool_control] off``), where
            known: a servo job held up with the output on (``M3 S90``) is read by it
            before the program's own clues (:func:`lift_state`).

    Raises:
        ConfigError: Unreadable file, or a line GRBL would reject before parsing (over 79
            characters after stripping, realtime characters, non-ASCII) or whose words it
            cannot read (error:1 or error:2, :func:`_word_error`), naming the line.
    """
    p = Path(path)
    data = read_input(p, "a G-code file")
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as exc:
        lineno = data[: exc.start].count(b"\n") + 1
        raise ConfigError(f"{p}:{lineno}: non-ASCII byte in G-code") from None
    blocks: list[Block] = []
    state = Modal()
    # GRBL ends a line at LF or CR only (str.splitlines also splits at VT, FF and
    # \x1c-\x1e, which would send a comment's tail as a command).
    for lineno, raw in enumerate(_LINE_END.split(text.removesuffix("\n")), start=1):
        found = _CONTROL.search(raw)
        if found is not None:
            control = found.group()
            raise ConfigError(
                f"{p}:{lineno}: control character {control!r} in G-code (0x18 is a soft "
                "reset, others end a line for some senders and not for GRBL)"
            )
        block = strip_block(raw)
        if not block:
            continue
        bad = _REALTIME.intersection(block)
        if bad:
            raise ConfigError(
                f"{p}:{lineno}: {''.join(sorted(bad))!r} is a GRBL realtime command and would "
                "act at once"
            )
        if block.startswith("$") and block not in _QUERIES:
            raise ConfigError(
                f"{p}:{lineno}: {block!r}: a GRBL system command that moves the machine or "
                "changes its settings or state does not belong in a job (home, jog and set up "
                "before streaming)"
            )
        if len(block) > MAX_BLOCK_CHARS:
            raise ConfigError(
                f"{p}:{lineno}: line has {len(block)} characters after stripping; "
                f"GRBL 1.1 accepts at most {MAX_BLOCK_CHARS} (error:11)"
            )
        refused = None if block.startswith("$") else _word_error(block)
        if refused is not None:
            raise ConfigError(
                f"{p}:{lineno}: GRBL 1.1 would refuse this line ({block!r} as sent) mid-job "
                f"with {refused}"
            )
        step = _advance(state, block, rapid_mm_min)
        state = step.modal
        blocks.append(
            Block(
                index=len(blocks),
                lineno=lineno,
                text=block,
                modal=state,
                seconds=step.seconds,
                motion=step.motion,
                sync_before=step.sync.before,
                sync_after=step.sync.after,
                system=block.startswith("$"),
                unfollowed=step.unfollowed,
                arc_box=step.arc_box,
                rapid_mm=step.rapid_mm,
                speed_sync=step.sync.speed,
                laser_sync=step.sync.laser,
            )
        )
    # the tool output may be the tool state: the job switches it, and moves Z nowhere the
    # sender does not know (a G91 Z move from an unknown Z may cut at any height)
    servo = any(b.modal.spindle in ("M3", "M4") for b in blocks)
    servo = servo and not any(_gives_z(b) and b.modal.z is None for b in blocks)
    if z_threshold is None:
        z_threshold = auto_threshold(blocks)
    if z_threshold is None:
        pen_mode = servo and len(z_levels(blocks)) <= 1
    else:
        goes_below = any(b.modal.z is not None and b.modal.z < z_threshold - 1e-9 for b in blocks)
        pen_mode = not goes_below and servo
    lift = lift_state(blocks, tool_up) if pen_mode else None
    lift_speed = None if lift is None else lift[1]
    strokes: list[tuple[int, int]] = []  # no strokes where the program does not show them
    if z_threshold is not None or pen_mode:
        strokes = stroke_spans(blocks, z_threshold or 0.0, pen_mode, lift_speed)
    return Program(
        path=p,
        sha256=hashlib.sha256(data).hexdigest(),
        blocks=blocks,
        strokes=strokes,
        z_threshold=z_threshold,
        pen_mode=pen_mode,
        rapid_mm_min=(float(rapid_mm_min[0]), float(rapid_mm_min[1]), float(rapid_mm_min[2])),
        lift_speed=lift_speed,
        tool_up="M5" if lift is None else f"{lift[0]}S{gcode_number(lift[1], 4)}",
    )


def check_tool_up_at_end(program: Program) -> None:
    """Refuse a program whose last stroke leaves the tool down: a file cut short.

    Streamed as it is, its end would leave the bit in the board (or the pen down), the
    spindle running. A program that does not show its cutting height (no stroke: e.g.
    cut off right after its first plunge) is refused when it ends by feeding the tool
    down below its travel height (:func:`_final_plunge`).

    Raises:
        ConfigError: Naming the file's last line and the tool state there.
    """
    if program.z_threshold is None and not program.pen_mode and program.blocks:
        plunge = _final_plunge(program.blocks)
        if plunge is not None:
            block, z, travel, counted = plunge
            last = program.blocks[-1]
            at = "" if block is last else f" (line {block.lineno})"
            raise ConfigError(
                f"{program.path}:{last.lineno}: the program ends by feeding the tool down to "
                f"Z {z:g} mm{at}, below its travel height {travel:g}"
                + (" (both counted from the Z the job began at)" if counted else "")
                + ", and never lifts it; the file may be cut short: expected a lift after the "
                "plunge (if the file is whole, give --machine or a --z-threshold below that Z)"
            )
    if not program.strokes or program.strokes[-1][1] != len(program.blocks) - 1:
        return
    last = program.blocks[-1]
    threshold = program.z_threshold or 0.0
    lift = program.lift_speed
    if not _tool_down(last.modal, threshold, program.pen_mode, lift):
        return
    if not program.pen_mode:
        state = f"Z {last.modal.z:g} mm, below the cutting threshold {threshold:g}"
    elif lift is None:
        state = f"spindle output {last.modal.spindle}"
    else:
        state = f"spindle output {last.modal.spindle} S{last.modal.speed:g}, not the S{lift:g} "
        state += "its servo is held up with"
    up = "Z up or M5" if lift is None else f"{program.tool_up}, or M5"
    raise ConfigError(
        f"{program.path}:{last.lineno}: the program ends with the tool down ({state}); the "
        f"file may be cut short: expected its last stroke to lift the tool ({up})"
    )


def _z_trace(blocks: Sequence[Block]) -> tuple[list[float | None], bool]:
    """Per block its work Z, or its Z counted from where the job began; and whether so.

    Counted so in a file that never gives Z in absolute mode: the sum of its G91 Z
    increments so far.
    """
    zs = [b.modal.z for b in blocks]
    if any(z is not None for z in zs):
        return zs, False
    counted: list[float | None] = []
    z = 0.0
    for b in blocks:
        if b.motion and b.modal.relative:
            z += sum(v for letter, v in block_words(b.text) if letter == "Z") * b.modal.mm_per_unit
        counted.append(z)
    return counted, True


def _final_plunge(blocks: Sequence[Block]) -> tuple[Block, float, float, bool] | None:
    """The program's last move, its Z and its travel height, if that move feeds the tool down.

    The travel height is the lowest Z a rapid reaches, else (a job without rapids at a
    known Z) the highest Z reached before. A complete job never ends by lowering the tool
    with a Z-only feed move to below it: that is a plunge whose cut and lift are missing.
    Not taken for one: a last move that lifts (even to below the travel height) or also
    moves in X or Y, and a lowering after the spindle or laser was switched off (M5). In a
    file that moves Z only by G91 increments, both Zs are counted from where the job began
    (:func:`_z_trace`; the last item says so): they compare all the same.
    """
    moves = [b for b in blocks if b.motion]
    if not moves or any(b.unfollowed for b in moves):
        return None
    zs, counted = _z_trace(blocks)
    last = moves[-1]
    z = zs[last.index]
    if last.modal.motion == "G0" or z is None:
        return None
    if last.modal.spindle == "M5" and any(b.modal.spindle in ("M3", "M4") for b in blocks):
        return None
    if len(moves) > 1 and (moves[-2].modal.x, moves[-2].modal.y) != (last.modal.x, last.modal.y):
        return None
    before = zs[moves[-2].index] if len(moves) > 1 else None
    rapid_z = [v for b in moves if b.modal.motion == "G0" and (v := zs[b.index]) is not None]
    earlier = [v for b in moves[:-1] if (v := zs[b.index]) is not None]
    travel = min(rapid_z) if rapid_z else max(earlier, default=None)
    if travel is None or (before is not None and z >= before - 1e-9) or z >= travel - 1e-9:
        return None
    return last, z, travel, counted


def resume_point(program: Program, done: set[int]) -> int:
    """The block to restart at: the first block of the first stroke not completely done.

    Blocks outside strokes (travel, set-up) that are not done before that stroke are
    replaced by the preamble. Returns ``len(program.blocks)`` when everything is done.
    """
    for first, last in program.strokes:
        if any(i not in done for i in range(first, last + 1)):
            return first
    after = program.strokes[-1][1] + 1 if program.strokes else 0
    for i in range(after, len(program.blocks)):
        if i not in done:
            return i
    return len(program.blocks)


def travel_move(program: Program, start: int) -> tuple[str, float]:
    """How the program travels with the tool up before block ``start``: G0, or G1 and its feed.

    Taken from the last XY move outside every stroke before ``start`` (a servo plotter
    travels with G1 to spare the servo); ``("G0", 0.0)`` when there is none. The feed is in
    mm/min.
    """
    stroke_of = program.stroke_of()
    blocks = program.blocks
    for i in range(min(start, len(blocks)) - 1, -1, -1):
        b = blocks[i]
        prev = blocks[i - 1].modal if i > 0 else Modal()
        moved_xy = (b.modal.x, b.modal.y) != (prev.x, prev.y)
        if not b.motion or stroke_of[i] >= 0 or not moved_xy or b.unfollowed:
            continue
        m = b.modal
        if m.motion == "G1" and m.feed_mode == "G94" and m.feed > 0:
            return "G1", m.feed_mm
        return "G0", 0.0
    return "G0", 0.0


def dwell_seconds(text: str) -> float:
    """The seconds a stripped block dwells (``G4 P``; GRBL 1.1 takes P in seconds), else 0."""
    words = block_words(text)
    if ("G", 4.0) not in words:
        return 0.0
    return next((v for letter, v in words if letter == "P"), 0.0)


def spin_up_dwell(program: Program, start: int) -> float:
    """Seconds the file dwelt (``G4 P``) after its last spindle start before block ``start``.

    The spindle start is the last block that turned the output on (M3/M4 from M5, or a
    change of direction); its dwell is the first ``G4`` from that block up to the next
    motion block. 0 when the spindle is off there or the file did not dwell.
    """
    blocks = program.blocks[: max(0, min(start, len(program.blocks)))]
    on = -1
    for b in blocks:
        prev = blocks[b.index - 1].modal.spindle if b.index > 0 else "M5"
        if b.modal.spindle != "M5" and b.modal.spindle != prev:
            on = b.index
    if on < 0 or blocks[-1].modal.spindle == "M5":
        return 0.0
    for b in blocks[on:]:
        if ("G", 4.0) in block_words(b.text):
            return dwell_seconds(b.text)
        if b.motion:
            break
    return 0.0


def _sets_wcs(blocks: Sequence[Block]) -> bool:
    """Whether ``blocks`` select a work coordinate system: a G54-G59, or M2/M30 (to G54).

    A file that never does runs in whichever the controller is in (a startup line may
    select G55): a resume must then not select one either.
    """
    return any(
        (letter == "G" and value in (54, 55, 56, 57, 58, 59))
        or (letter == "M" and value in (2, 30))
        for b in blocks
        for letter, value in block_words(b.text)
    )


def _gives_z(block: Block) -> bool:
    """Whether ``block`` moves and gives Z (a move on Z, or G28/G30 through a Z)."""
    return block.motion and any(letter == "Z" for letter, _ in block_words(block.text))


def _refuse_reset_offsets(program: Program, start: int) -> None:
    """Refuse a resume at block ``start`` where the file set a G92 or tool length offset.

    The stop's soft reset cleared both (Grbl keeps neither over a reset), and a preamble
    cannot set a G92 again (it counts from where the machine stood) nor knows the length
    offset the user had: the positions the file gives after it would land elsewhere.

    Raises:
        ConfigError: Naming the line that set the offset still in force.
    """
    before = program.blocks[start - 1].modal
    if not before.g92 and not before.tlo:
        return
    codes = {92.0} if before.g92 else set()
    codes |= {43.1} if before.tlo else set()
    setting = next(
        b
        for b in reversed(program.blocks[:start])
        if any(letter == "G" and value in codes for letter, value in block_words(b.text))
    )
    what = "a tool length offset" if ("G", 43.1) in block_words(setting.text) else "a G92 offset"
    raise ConfigError(
        f"{program.path}:{program.blocks[start].lineno}: cannot resume here: line "
        f"{setting.lineno} ({setting.text!r}) set {what}, which the stop's soft reset "
        "cleared and a preamble cannot set again, so the file's positions from there on "
        "would land elsewhere; stream the file from its start"
    )


def resume_preamble(program: Program, start: int) -> list[str]:
    """Blocks that restore the state the file had before block ``start``, safely.

    Order: mm and absolute (G21 G90, plane, G94, and the work coordinates where the file
    selected them); Z up to the highest Z the file used so far in the frame Z is counted
    in there (a stop may have left the bit in the board: the spindle must not start
    there; a Z of an earlier frame may lie anywhere in this one), or, in a job without Z
    (a servo), its up command before any move (M5, or the S that holds it up,
    :attr:`Program.tool_up`); then spindle/servo and
    coolant as the file had them, with the spin-up dwell the file used after its spindle
    start (:func:`spin_up_dwell`; the tool is up before a stroke by definition); XY to
    where the file was, Z down to the file's travel height there, then the file's units,
    distance mode, feed mode, feed and motion mode. The moves travel as the file does
    (:func:`travel_move`: G0, or G1 at its travel feed). The stroke's own first block then
    plunges.

    Raises:
        ConfigError: Where the sender does not know where to bring the tool back to: X or
            Y not given in absolute mode since the job began or the frame changed, Z
            likewise in a job that moves Z (no height is guessed), or a G92 or tool length
            offset set by the file that the stop's reset cleared.
    """
    if start <= 0 or start > len(program.blocks):
        return []
    before = program.blocks[start - 1].modal
    unknown = "".join(a for a in "XY" if a in before.assumed)
    if unknown:  # counted from where the job began, which a resume does not know
        raise ConfigError(
            f"{program.path}:{program.blocks[start].lineno}: cannot resume here: the file "
            f"has not given {' and '.join(unknown)} in absolute mode (G90) since it began, "
            "so it counts them from where the machine stood when the job started, which "
            "the sender does not know on a resume; stream the file from its start"
        )
    if before.x is None or before.y is None:
        lost = start - 1  # the block that lost X or Y
        while lost > 0 and None in work_xyz(program.blocks[lost - 1].modal)[:2]:
            lost -= 1
        raise ConfigError(
            f"{program.path}:{program.blocks[start].lineno}: cannot resume here: after line "
            f"{program.blocks[lost].lineno} ({program.blocks[lost].text!r}) changed the work "
            "frame, the file has not given X and Y again in absolute mode (G90), so the "
            "sender does not know where to bring the tool back to"
        )
    _refuse_reset_offsets(program, start)
    blocks = program.blocks[:start]
    if before.z is None and any(_gives_z(b) for b in blocks):
        first = start - 1  # the block that changed the frame Z is counted in, if any
        while first > 0 and blocks[first - 1].modal.z_frame == before.z_frame:
            first -= 1
        since = f"line {blocks[first].lineno} ({blocks[first].text!r})" if before.z_frame else ""
        raise ConfigError(
            f"{program.path}:{program.blocks[start].lineno}: cannot resume here: the file "
            f"has not given Z in absolute mode (G90) since {since or 'it began'}, so the "
            "sender does not know the height to travel at here (and will not guess one); "
            "stream the file from its start"
        )
    zs = [b.modal.z for b in blocks if b.modal.z is not None and b.modal.z_frame == before.z_frame]
    mode, feed = travel_move(program, start)
    move = mode if mode == "G0" else f"G1F{gcode_number(feed, 4)}"
    wcs = before.wcs if _sets_wcs(program.blocks[:start]) else ""
    lines = [f"G21G90{before.plane}G94{wcs}"]
    if zs:
        lines.append(f"{move}Z{gcode_number(max(zs), 4)}")
    else:
        lines.append(program.tool_up)  # no Z: the output lifts the tool
    if before.spindle == "M5":
        if zs:
            lines.append("M5")
    else:
        spindle = f"{before.spindle}S{gcode_number(before.speed, 4)}"
        if spindle != lines[-1]:  # (the servo's up command, already sent)
            lines.append(spindle)
        dwell = spin_up_dwell(program, start)
        if dwell > 0:
            lines.append(f"G4P{gcode_number(dwell, 4)}")
    lines.append(before.coolant)
    lines.append(f"{move}X{gcode_number(before.x, 4)}Y{gcode_number(before.y, 4)}")
    if zs and before.z is not None and before.z < max(zs):
        lines.append(f"{move}Z{gcode_number(before.z, 4)}")
    restore = ("G20" if before.inches else "") + ("G91" if before.relative else "")
    restore += "G93" if before.feed_mode == "G93" else ""
    if before.feed > 0:
        restore += f"F{gcode_number(before.feed, 4)}"
    restore += before.motion if before.motion != mode else ""
    if restore:
        lines.append(restore)
    return lines


def _ends(blocks: Sequence[Block], i: int) -> tuple[Modal, Modal]:
    """The modal state before and after block ``i``, for matching a reported position.

    An axis still counted from the assumed start (:attr:`Modal.assumed`: the job may begin
    anywhere, a homed machine far from work X0 Y0) is not known there.
    """
    before, after = (blocks[i - 1].modal if i > 0 else Modal()), blocks[i].modal
    return _placed(before), _placed(after)


def known_xyz(modal: Modal) -> tuple[float | None, float | None, float | None]:
    """The work position after a block where the sender knows it wherever the job began.

    As :func:`work_xyz`, with None also on the axes still counted from the start the
    parse assumes (:attr:`Modal.assumed`; :meth:`Program.placed_at` places them).
    """
    return work_xyz(_placed(modal))


def _placed(modal: Modal) -> Modal:
    """``modal`` with the axes it counts from the assumed start unknown."""
    if not modal.assumed:
        return modal
    x, y, z = (
        None if a in modal.assumed else v for a, v in zip("XYZ", work_xyz(modal), strict=True)
    )
    return replace(modal, x=x, y=y, z=z)


def _unknown_moves(blocks: Sequence[Block], i: int) -> list[int]:
    """The axes (0-2) block ``i`` gives whose work position is unknown at one of its ends."""
    before, after = _ends(blocks, i)
    given = {letter for letter, _ in block_words(blocks[i].text)}
    return [
        k
        for k, (a, u, v) in enumerate(zip("XYZ", work_xyz(before), work_xyz(after), strict=True))
        if a in given and (u is None or v is None)
    ]


def followed_move(blocks: Sequence[Block], i: int) -> bool:
    """Whether a position can be matched against block ``i``'s path (:func:`along_move`).

    A straight move (:func:`straight_move`) with an axis whose work position the sender
    knows at both ends. An axis unknown at an end (Z before the program sets it, any axis
    after a change of the work frame) is left out of the match, so the match never misses
    the machine on the move; a move known on no axis is not matched (the machine may be
    anywhere on it, as in an arc).
    """
    before, after = _ends(blocks, i)
    known = any(
        u is not None and v is not None
        for u, v in zip(work_xyz(before), work_xyz(after), strict=True)
    )
    return straight_move(blocks[i]) and known


def along_move(blocks: Sequence[Block], i: int, p: Sequence[float], tol: float) -> float | None:
    """How far ``p`` (work mm) is along block ``i``'s move (0 at its start), if within ``tol``.

    Matched on the axes known at both ends of the move (:func:`followed_move`). None when
    ``p`` is off the move, at its very end, the move is not followed or has no length. A
    move whose known axes stand still while it moves an unknown one (a first Z move) has
    ``p`` at 0 where ``p`` stands on those axes, unless ``p`` is exactly where the move
    ends.
    """
    if not followed_move(blocks, i):
        return None
    before, after = _ends(blocks, i)
    pairs = [
        (u, v, float(p[k]))
        for k, (u, v) in enumerate(zip(work_xyz(before), work_xyz(after), strict=True))
        if u is not None and v is not None
    ]
    a = [u for u, _, _ in pairs]
    ab = [v - u for u, v, _ in pairs]
    q = [w for _, _, w in pairs]
    length2 = sum(d * d for d in ab)
    if length2 == 0.0:
        unknown = _unknown_moves(blocks, i)
        if not unknown or math.dist(q, a) > tol:
            return None
        ends = [work_xyz(after)[k] for k in unknown]
        return None if ends == [float(p[k]) for k in unknown] else 0.0  # at its very end
    t = sum(d * (w - u) for d, w, u in zip(ab, q, a, strict=True)) / length2
    if t < -1e-9 or t > 1.0 - 1e-6:
        return None
    closest = [u + t * d for u, d in zip(a, ab, strict=True)]
    return max(t, 0.0) if math.dist(q, closest) <= tol else None


def stands_at_end(block: Block, p: Sequence[float], tol: float) -> bool:
    """Whether ``p`` (work mm) is within ``tol`` of where ``block`` ends, on the axes known there.

    False where no axis is known.
    """
    ends = known_xyz(block.modal)
    known = [(v, float(p[k])) for k, v in enumerate(ends) if v is not None]
    return bool(known) and math.dist([v for v, _ in known], [w for _, w in known]) <= tol


def straight_move(block: Block) -> bool:
    """Whether ``block`` moves on a straight line the sender knows (G0/G1, followed)."""
    return (
        block.motion
        and not block.unfollowed
        and block.arc_box is None
        and block.modal.motion in ("G0", "G1")
    )


#: A move of up to this many steps on each axis may be one Grbl drops (:func:`plans_nothing`).
STEP_SLACK = 1.05


def plans_nothing(
    blocks: Sequence[Block], i: int, step_mm: Sequence[float] = (0.0, 0.0, 0.0)
) -> bool:
    """Whether GRBL may plan nothing for block ``i``: a straight move of at most a step.

    Grbl's ``mc_line`` waits for a free planner block, then plans nothing for a move whose
    target rounds to the steps it stands on (``PLAN_EMPTY_BLOCK``), so such a move never
    holds a block: a bound on the blocks queued must not count it. Past moves GRBL
    dropped, its point lies within half a step of the sender's on each axis, so a move it
    drops moves at most one step (``step_mm``, ``$100``-``$102``; 0: not known, only a
    move of no length counts) on each axis by the sender's count. Calling a real move so
    is safe (the bound looks further back); the reverse would trust a queued move: an
    axis whose work position is unknown at one of the move's ends may not move at all.
    """
    if not straight_move(blocks[i]):
        return False
    before, after = _ends(blocks, i)
    moved = [  # an axis unknown at an end may not move: only the known ones tell
        0.0 if u is None or v is None else v - u
        for u, v in zip(work_xyz(before), work_xyz(after), strict=True)
    ]
    # Grbl rounds to steps in float32 (about 0.014 steps off at 300 mm and 800 steps/mm):
    # a move a little over a step may be dropped too
    return all(abs(d) <= STEP_SLACK * step for d, step in zip(moved, step_mm, strict=True))


class TimeLeft:
    """How much of a streamed program the machine still has to run, in the program's seconds.

    GRBL answers a motion line once it is queued in its planner (``planner_blocks`` deep),
    so the lines acknowledged are not the lines run. This follows a *run point*: the block
    the machine is on and the seconds of it already run; everything before it ran. The
    point only moves forward (the time left never grows), and from three clues, each
    read at a report (:meth:`update`):

    - the reported work position, matched against the acknowledged straight moves from the
      run point on (the first segment it lies on, the share of its length run as the share
      of its time); at the end point of the last move acknowledged before the report, all
      of those ran;
    - GRBL's planner: at most ``planner_blocks`` acknowledged moves are queued or running,
      so every move before the ``planner_blocks``-th last acknowledged one ran; where the
      report tells the blocks free (``Bf:``), the moves acknowledged before it less those
      queued ran (moves of no length, which GRBL drops, are not counted; an arc or G28
      counted as one move holds more planner blocks, so the bound stays on the safe side);
    - a block GRBL answers only after its planner emptied (spindle and coolant changes, G4,
      M0/M2/M30...: :attr:`Block.sync`): everything before it ran, and the block itself
      unless its own move was queued after the wait.

    The cost per report is the blocks acknowledged since the last one plus a scan of the
    moves that may still be queued (no scan over the whole job).

    Args:
        program: The program streamed, timed as the ETA's (:meth:`Program.timed_for`).
        start: The first block sent (a resume's): the blocks before it count as run.
        planner_blocks: GRBL's planner depth (``$I``'s ``[OPT:...]``, 15 on Grbl 1.1).
        laser_mode: ``$32`` (None: not known; only the syncs whatever ``$32`` says count).
        tol: How far (mm) a reported position may be off a move's line: report rounding
            plus a step (GRBL's steps leave the ideal line by up to one).
        step_mm: GRBL's step per axis (mm, ``$100``-``$102``; 0: not known), for the
            moves it may drop (:func:`plans_nothing`).
    """

    def __init__(
        self,
        program: Program,
        start: int = 0,
        planner_blocks: int = 15,
        laser_mode: bool | None = None,
        tol: float = 0.01,
        step_mm: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> None:
        self._blocks = program.blocks
        self._step_mm = tuple(step_mm)
        self._cum = np.concatenate(([0.0], np.cumsum([b.seconds for b in program.blocks])))
        self._planner = max(1, planner_blocks)
        self._laser = laser_mode
        self._tol = tol
        self._seen = start - 1  # blocks walked for moves and syncs
        self._moves: collections.deque[int] = collections.deque(maxlen=self._planner)
        self._block = max(0, start)  # the run point: the block the machine is on ...
        self._into = 0.0  # ... and the seconds of it already run

    @property
    def ran(self) -> int:
        """How many blocks the machine has run (the blocks before the run point)."""
        return self._block

    @property
    def seconds(self) -> float:
        """The program's seconds from the run point to its end."""
        return max(0.0, float(self._cum[-1] - self._cum[self._block]) - self._into)

    def update(
        self,
        acked_through: int,
        reported_through: int,
        wpos: Sequence[float] | None,
        planner_free: int | None = None,
        all_ran: bool = False,
    ) -> float:
        """Move the run point by the clues of a report; returns :attr:`seconds`.

        Args:
            acked_through: The last block acknowledged (-1: none).
            reported_through: The last block acknowledged before the status report that
                gave ``wpos`` (only those can be where the report saw the machine).
            wpos: The reported work position (mm); None when not known.
            planner_free: The report's planner blocks free (``Bf:``); None when not told.
            all_ran: Every acknowledged block ran (the sender's end-of-job dwell was
                answered).
        """
        for i in range(self._seen + 1, acked_through + 1):
            b = self._blocks[i]
            if b.motion and not plans_nothing(self._blocks, i, self._step_mm):
                self._moves.append(i)
            if b.sync_after or (b.syncs_before(self._laser) if self._laser is not None else b.sync):
                self._advance(i if b.motion and not b.sync_after else i + 1, 0.0)
        self._seen = max(self._seen, acked_through)
        if all_ran:
            self._advance(acked_through + 1, 0.0)
        if len(self._moves) == self._planner:
            self._advance(self._moves[0], 0.0)
        if planner_free is not None and reported_through >= self._block:
            queued = max(0, self._planner - planner_free)
            reported = [i for i in self._moves if i <= reported_through]
            if queued == 0:
                self._advance(reported_through + 1, 0.0)
            elif queued <= len(reported):
                self._advance(reported[-queued], 0.0)
        if wpos is not None:
            self._follow(reported_through, wpos)
        return self.seconds

    def _follow(self, reported_through: int, wpos: Sequence[float]) -> None:
        """Put the run point where the reported position lies, if it lies on a queued move.

        The first acknowledged followed move (:func:`followed_move`) from the run point on
        that the position lies on, or stands at the start of, not its end (a corner GRBL's
        steps round off both lines), not behind the run point (where a path passes a point
        twice, a pass behind it is skipped; of two ahead, the earlier counts, so the time
        left errs long); else, at the end point of the last block acknowledged before the
        report, all of them ran. Not past a move the sender does not follow (an arc, a move
        after a change of the work frame...): the machine may stand anywhere on it, even on
        a later move's path, so the run point goes no further than its start, as the
        journal's executed-through (``Streamer._executed_guess``) does.
        """
        for i in range(self._block, reported_through + 1):
            b = self._blocks[i]
            if not followed_move(self._blocks, i):
                if b.motion:
                    self._advance(i, 0.0)
                    return
                continue
            t = along_move(self._blocks, i, wpos, self._tol)
            if (
                t is None
                and i > self._block
                and stands_at_end(self._blocks[i - 1], wpos, self._tol)
                and not stands_at_end(b, wpos, self._tol)
            ):
                t = 0.0  # at its start, off both lines: the corner GRBL rounded to its steps
            if t is not None and (i > self._block or t * b.seconds >= self._into):
                self._advance(i, t * b.seconds)
                return
        if reported_through >= self._block:
            if stands_at_end(self._blocks[reported_through], wpos, self._tol):
                self._advance(reported_through + 1, 0.0)

    def _advance(self, block: int, into: float) -> None:
        """Move the run point to ``into`` seconds into ``block``, if that is further on."""
        if block >= len(self._blocks):
            block, into = len(self._blocks), 0.0
        else:
            into = min(into, float(self._blocks[block].seconds))
        if block > self._block or (block == self._block and into > self._into):
            self._block, self._into = block, into
