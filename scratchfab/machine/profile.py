"""Machine profiles: what an engraver can do and where the board sits on it.

A profile is a TOML file parsed strictly into :class:`MachineProfile` (unknown keys are
rejected with the nearest valid key). Bundled profiles live in
``scratchfab/data/machine_profiles/<name>.toml``; :func:`load_profile` takes such a name
or a path. All lengths are millimetres in the machine's work coordinates (what the
G-code's X, Y and Z words mean), feeds are mm/min, accelerations mm/s^2.

Schema (every table and key; defaults in brackets)::

    name = "GRBL 3018, diamond drag bit"   # free text
    dialect = "grbl-1.1"                    # the only dialect so far
    start_mm = [0.0, 0.0]                   # XY where a job starts and ends (tool up)

    [envelope]              # reachable work coordinates, per axis [min, max]
    x_mm = [-290.0, 0.0]    # GRBL after homing: negative space, -$130 <= X <= 0
    y_mm = [-170.0, 0.0]    #                                     -$131 <= Y <= 0
    z_mm = [-40.0, 0.0]     #                                     -$132 <= Z <= 0
                            # (optional: without it Z is not checked against $132)
    coordinates = "work"    # "machine": these are GRBL machine coordinates (G54 cleared);
                            # stream refuses while GRBL's work offset is not zero ["work"]

    [board]                 # where and how the board lies on the bed
    origin = "lower-left"   # board corner (after rotation) placed at offset_mm:
                            # lower-left | lower-right | upper-left | upper-right | center
    offset_mm = [-250.0, -150.0]
    rotation_deg = 0        # 0, 90, 180 or 270, counter-clockwise as seen from above

    [z]                     # tool heights (z mode and spindle mode; unused for a servo)
    safe_mm = 2.0           # travel height
    engrave_mm = -0.05      # height while cutting

    [feeds]
    engrave_mm_min = 800.0
    plunge_mm_min = 200.0
    travel_mm_min = 3000.0  # [unset] unset: travel with G0 at the machine's max rates;
                            # set: travel with G1 at this feed (kinder to a servo scribe)

    [motion]                # for the time estimate and for comparing with GRBL's $$
    max_rate_mm_min = [3000.0, 3000.0, 500.0]   # $110, $111, $112
    acceleration_mm_s2 = [200.0, 200.0, 50.0]   # $120, $121, $122
    junction_deviation_mm = 0.01                # $11 [0.01, GRBL's default]; 0: stop at
                                                # every corner

    [tool]                  # what the tool cuts (must agree with the design's [scratch])
    width_mm = 0.1
    depth_mm = 0.01
    min_length_mm = 0.5     # shorter (clipped) strokes are dropped
    tolerance_mm = 0.01     # positional tolerance: duplicate detection, envelope slack 0

    [tool_control]
    mode = "z"              # "z": Z moves only; "spindle": spindle on for the job, Z moves;
                            # "servo": no Z, the on/off commands lower and lift the tool
    on = "M3 S{power}"      # [as shown] template; {power} is replaced by power; tool
                            # words only: M3 M4 M5 M7 M8 M9, S, G4 with P (no $, no moves)
    off = "M5"
    power = 1000.0
    dwell_s = 0.0           # G4 pause after each on/off command (servo travel, spin-up)

    [serial]
    baud = 115200
    rx_buffer_bytes = 128   # GRBL 1.1: 128

    [gcode]
    decimals = 3            # digits after the point for X, Y, Z; the rounding (half the
                            # last digit) may not exceed tool.tolerance_mm
    max_line_length = 79    # GRBL 1.1 accepts at most 79 characters per line
"""

from __future__ import annotations

import math
import re
import string
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from scratchfab.bundled import bundled_name, find_bundled
from scratchfab.model.schema import check_bounds, load_toml, parse_table, spec, to_table
from scratchfab.toolpath.timing import GRBL_JUNCTION_DEVIATION_MM

Range = tuple[float, float]
Corner = Literal["lower-left", "lower-right", "upper-left", "upper-right", "center"]

#: Words GRBL 1.1 rejects (error 20) that other controllers take: refused even in a comment.
_FORBIDDEN_WORDS = (("M", 6.0), ("G", 64.0))


def gcode_number(value: float, decimals: int) -> str:
    """A G-code number: ``decimals`` digits, trailing zeros dropped, never ``-0``.

    The one formatter of the export, the profile's servo commands and the sender's resume
    preamble.
    """
    text = f"{value:.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    if text in ("-0", ""):
        text = "0"
    return text


def _check_range(name: str, value: Range) -> None:
    if not value[0] < value[1]:
        raise ValueError(f"{name}: expected [min, max] with min < max, got {list(value)}")


Z_UNLIMITED_MM: Range = (-1000.0, 1000.0)  # no ``z_mm`` given


@dataclass(frozen=True)
class Envelope:
    """Reachable work coordinates per axis, [min, max] in mm.

    ``coordinates`` says which frame the profile's positions are in: ``"work"``, the work
    coordinates the user sets up on the machine, or ``"machine"``, GRBL's machine
    coordinates after homing with the work offset cleared, which the sender then checks.
    """

    x_mm: Range
    y_mm: Range
    z_mm: Range = Z_UNLIMITED_MM
    coordinates: Literal["work", "machine"] = "work"

    def __post_init__(self) -> None:
        for name in ("x_mm", "y_mm", "z_mm"):
            _check_range(name, getattr(self, name))

    @property
    def max_travel_mm(self) -> tuple[float, float, float | None]:
        """Travel per axis (max - min): what GRBL's $130, $131, $132 must at least allow.

        None for Z when the profile gives no ``z_mm``: it then asks no Z travel of GRBL.
        """
        z = None if self.z_mm == Z_UNLIMITED_MM else self.z_mm[1] - self.z_mm[0]
        return (self.x_mm[1] - self.x_mm[0], self.y_mm[1] - self.y_mm[0], z)

    def xy_text(self) -> str:
        """The XY envelope as prose for messages: ``"X -300 to 0, Y -180 to 0"``."""
        return f"X {self.x_mm[0]:g} to {self.x_mm[1]:g}, Y {self.y_mm[0]:g} to {self.y_mm[1]:g}"

    def contains_xy(self, points: np.ndarray, slack: float = 0.0) -> np.ndarray:
        """(N,) mask of (N, 2) points inside the XY envelope (closed, widened by ``slack``)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return (
            (p[:, 0] >= self.x_mm[0] - slack)
            & (p[:, 0] <= self.x_mm[1] + slack)
            & (p[:, 1] >= self.y_mm[0] - slack)
            & (p[:, 1] <= self.y_mm[1] + slack)
        )


@dataclass(frozen=True)
class Placement:
    """Where the board lies: its (rotated) ``origin`` corner at ``offset_mm``."""

    offset_mm: tuple[float, float] = (0.0, 0.0)
    origin: Corner = "lower-left"
    rotation_deg: int = 0

    def __post_init__(self) -> None:
        if self.rotation_deg not in (0, 90, 180, 270):
            raise ValueError(f"rotation_deg: expected 0, 90, 180 or 270, got {self.rotation_deg}")

    @property
    def origin_text(self) -> str:
        """The board point ``offset_mm`` places, in words: "centre" or "lower-left corner"."""
        return "centre" if self.origin == "center" else f"{self.origin} corner"


@dataclass(frozen=True)
class Heights:
    """Tool Z heights in mm."""

    safe_mm: float = 2.0
    engrave_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.safe_mm <= self.engrave_mm:
            raise ValueError(
                f"safe_mm ({self.safe_mm}) must be above engrave_mm ({self.engrave_mm})"
            )


@dataclass(frozen=True)
class Feeds:
    """Feed rates in mm/min; ``travel_mm_min`` unset means G0 travel."""

    engrave_mm_min: float = field(default=600.0, metadata=spec(gt=0))
    plunge_mm_min: float = field(default=200.0, metadata=spec(gt=0))
    travel_mm_min: float | None = field(default=None, metadata=spec(gt=0))

    def __post_init__(self) -> None:
        check_bounds(self)


@dataclass(frozen=True)
class Motion:
    """Per-axis limits and the corner tolerance as GRBL holds them ($110-$112, $120-$122, $11)."""

    max_rate_mm_min: tuple[float, float, float] = field(
        default=(1000.0, 1000.0, 500.0), metadata=spec(gt=0)
    )
    acceleration_mm_s2: tuple[float, float, float] = field(
        default=(10.0, 10.0, 10.0), metadata=spec(gt=0)
    )
    junction_deviation_mm: float = field(default=GRBL_JUNCTION_DEVIATION_MM, metadata=spec(ge=0))

    def __post_init__(self) -> None:
        check_bounds(self)


@dataclass(frozen=True)
class Tool:
    """The cutting tool: the dent it makes and the limits of what it can cut."""

    width_mm: float = field(metadata=spec(gt=0))
    depth_mm: float = field(metadata=spec(gt=0))
    min_length_mm: float = field(default=0.5, metadata=spec(ge=0))
    tolerance_mm: float = field(default=0.01, metadata=spec(gt=0))

    def __post_init__(self) -> None:
        check_bounds(self)


_TOOL_CODE = re.compile(r"(?:\s*[A-Z]\s*[-+]?(?:\d+\.?\d*|\.\d+))+\s*")
#: One G-code word, a letter and a number (GRBL allows spaces between them).
GCODE_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
#: What a tool command may do: spindle/servo (M3 M4 M5 with S), coolant (M7 M8 M9), dwell (G4 P).
_TOOL_CODES = {"M": (3.0, 4.0, 5.0, 7.0, 8.0, 9.0), "G": (4.0,)}


def _check_tool_command(name: str, template: str, power: float) -> None:
    """Refuse a tool command that could do more than switch the tool, or that GRBL rejects.

    The command is sent once per stroke, so a ``$`` system command (a settings reset, a
    jog), a move, a control byte or a realtime character in it would act on every stroke.

    Raises:
        ValueError: Naming ``name`` and what is wrong.
    """
    try:
        for _, field_name, spec_text, conversion in string.Formatter().parse(template):
            if field_name is not None and (field_name != "power" or spec_text or conversion):
                raise ValueError("another field than a bare {power}")
        text = template.format(power=gcode_number(power, 3))
    except (KeyError, IndexError, ValueError) as exc:
        raise ValueError(
            f"{name}: bad template {template!r} (only {{power}} may be used): {exc}"
        ) from None
    if not all(" " <= c <= "~" for c in text):
        raise ValueError(f"{name}: the command must be one line of printable ASCII, got {text!r}")
    if any(c in text for c in "!?~"):
        raise ValueError(f"{name}: '!', '?' and '~' are GRBL realtime commands")
    upper = text.upper()
    for letter, value in GCODE_WORD.findall(upper.replace(" ", "")):  # M06 too, not M60
        if (letter, float(value)) in _FORBIDDEN_WORDS:
            raise ValueError(
                f"{name}: {letter}{float(value):g} is not supported by GRBL 1.1 (error 20)"
            )
    code = re.sub(r"\([^()]*\)", " ", upper)  # GRBL comments; nested ones are errors
    if not _TOOL_CODE.fullmatch(code):
        raise ValueError(
            f"{name}: {text!r} is not a list of G-code words (a letter and a number each; "
            "no $ commands, ';' or unbalanced parentheses)"
        )
    words = [(letter, float(value)) for letter, value in GCODE_WORD.findall(code)]
    allowed = "M3, M4, M5, M7, M8, M9, S and G4 with P"
    for letter, value in words:
        if letter in _TOOL_CODES and value not in _TOOL_CODES[letter]:
            raise ValueError(
                f"{name}: {letter}{value:g} is not a tool command (allowed: {allowed})"
            )
        if letter not in _TOOL_CODES and letter not in "SP":
            raise ValueError(
                f"{name}: {letter} words do not belong in a tool command (allowed: {allowed})"
            )
        if letter in "SP" and value < 0:
            raise ValueError(f"{name}: {letter}{value:g} is negative")
    if any(letter == "P" for letter, _ in words) != (("G", 4.0) in words):
        raise ValueError(f"{name}: G4 needs its P (seconds), and P only goes with G4")


@dataclass(frozen=True)
class ToolControl:
    """How the tool goes down and up."""

    mode: Literal["z", "spindle", "servo"] = "z"
    on: str = "M3 S{power}"
    off: str = "M5"
    power: float = field(default=1000.0, metadata=spec(ge=0))
    dwell_s: float = field(default=0.0, metadata=spec(ge=0))

    def __post_init__(self) -> None:
        check_bounds(self)
        for name in ("on", "off"):
            _check_tool_command(name, getattr(self, name), self.power)
        if self.command("on") == self.command("off"):
            raise ValueError(f"on and off are the same command ({self.command('on')!r})")

    def command(self, which: Literal["on", "off"]) -> str:
        """The on or off command with the power filled in."""
        return getattr(self, which).format(power=gcode_number(self.power, 3))


@dataclass(frozen=True)
class Serial:
    """Serial link settings for streaming."""

    baud: int = field(default=115200, metadata=spec(gt=0))
    rx_buffer_bytes: int = field(default=128, metadata=spec(ge=16))

    def __post_init__(self) -> None:
        check_bounds(self)


#: Digits after the point G-code coordinates may have.
MAX_DECIMALS = 6


@dataclass(frozen=True)
class GcodeFormat:
    """How G-code lines are written."""

    decimals: int = field(default=3, metadata=spec(ge=0, le=MAX_DECIMALS))
    max_line_length: int = field(default=79, metadata=spec(ge=20))

    def __post_init__(self) -> None:
        check_bounds(self)


@dataclass(frozen=True)
class MachineProfile:
    """A machine profile (see the module docstring for the file format)."""

    envelope: Envelope
    tool: Tool
    name: str = "machine"
    dialect: Literal["grbl-1.1"] = "grbl-1.1"
    start_mm: tuple[float, float] = (0.0, 0.0)
    board: Placement = Placement()
    z: Heights = Heights()
    feeds: Feeds = Feeds()
    motion: Motion = Motion()
    tool_control: ToolControl = ToolControl()
    serial: Serial = Serial()
    gcode: GcodeFormat = GcodeFormat()
    source: str = field(default="<profile>", compare=False, repr=False, init=False)

    def __post_init__(self) -> None:
        if not self.name.isprintable():
            raise ValueError(f"name: {self.name!r} holds control characters (one printable line)")
        if not self.envelope.contains_xy(np.asarray(self.start_mm))[0]:
            raise ValueError(
                f"start_mm ({self.start_mm[0]:g}, {self.start_mm[1]:g}) is outside the "
                f"envelope ({self.envelope.xy_text()})"
            )
        rounding = 0.5 * 10.0**-self.gcode.decimals
        if rounding > self.tool.tolerance_mm * (1 + 1e-9):
            finest = 0.5 * 10.0**-MAX_DECIMALS
            if finest > self.tool.tolerance_mm * (1 + 1e-9):
                advice = (
                    f"no gcode.decimals (at most {MAX_DECIMALS}) meets it: raise "
                    f"tool.tolerance_mm to {finest:g} or more"
                )
            else:
                need = math.ceil(math.log10(0.5 / self.tool.tolerance_mm) - 1e-9)
                advice = f"use gcode.decimals = {need} or more"
            raise ValueError(
                f"gcode.decimals = {self.gcode.decimals} moves a coordinate by up to "
                f"{rounding:g} mm, more than tool.tolerance_mm ({self.tool.tolerance_mm:g}): "
                + advice
            )
        if self.tool_control.mode != "servo":
            self._check_z_heights()
        rates = self.motion.max_rate_mm_min
        feeds = [("engrave_mm_min", self.feeds.engrave_mm_min, min(rates[0], rates[1]))]
        feeds.append(("plunge_mm_min", self.feeds.plunge_mm_min, rates[2]))
        if self.feeds.travel_mm_min is not None:
            feeds.append(("travel_mm_min", self.feeds.travel_mm_min, min(rates[0], rates[1])))
        for key, value, limit in feeds:
            if key == "plunge_mm_min" and self.tool_control.mode == "servo":
                continue
            if value > limit:
                raise ValueError(
                    f"feeds.{key} ({value:g}) exceeds the machine's max rate ({limit:g} mm/min)"
                )

    def _check_z_heights(self) -> None:
        """Both heights inside the envelope, and still apart, as G-code writes them."""
        lo, hi = self.envelope.z_mm
        dec = self.gcode.decimals
        written = {}
        for key in ("safe_mm", "engrave_mm"):
            value = getattr(self.z, key)
            if not lo <= value <= hi:
                raise ValueError(
                    f"z.{key} ({value:g}) is outside the envelope's Z {lo:g} to {hi:g} (z_mm)"
                )
            written[key] = float(gcode_number(value, dec))
            if not lo <= written[key] <= hi:
                raise ValueError(
                    f"z.{key} ({value:g}) is written with gcode.decimals = {dec} as "
                    f"{written[key]:g}, outside the envelope's z_mm {list(self.envelope.z_mm)}"
                )
        if written["safe_mm"] <= written["engrave_mm"]:
            raise ValueError(
                f"z.safe_mm ({self.z.safe_mm:g}) and z.engrave_mm ({self.z.engrave_mm:g}) are "
                f"both written as {written['safe_mm']:g} with gcode.decimals = {dec}; "
                "raise gcode.decimals or move them apart"
            )

    def to_table(self) -> dict[str, Any]:
        """The profile as plain TOML-ready values (round-trips through :func:`profile_from_mapping`)."""
        table: dict[str, Any] = to_table(self)
        return table

    def board_to_machine(self, points: np.ndarray, board_size: tuple[float, float]) -> np.ndarray:
        """Map (N, 2) board points (SPEC frame, centred on the board) to machine XY.

        The board is turned by ``rotation_deg`` about its centre, then shifted so that its
        ``origin`` corner lies at ``offset_mm``.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        turns = self.board.rotation_deg // 90
        c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][turns]
        rotated = np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]], axis=1)
        w, h = board_size
        if turns % 2:
            w, h = h, w
        sx, sy = {
            "lower-left": (1, 1),
            "lower-right": (-1, 1),
            "upper-left": (1, -1),
            "upper-right": (-1, -1),
            "center": (0, 0),
        }[self.board.origin]
        shift = np.array(
            [self.board.offset_mm[0] + sx * w / 2, self.board.offset_mm[1] + sy * h / 2]
        )
        return rotated + shift

    @property
    def envelope_slack_mm(self) -> float:
        """Half a unit of the last written digit: the G-code's precision.

        A stroke's end this close beyond the envelope's edge lies on it as written: the
        toolpath stage moves it onto the edge. :meth:`fitting_offset` keeps a board this
        far inside where it can, clear of the very limit.
        """
        return 0.5 * 10.0 ** (-self.gcode.decimals)

    def offset_range(self, points: np.ndarray, slack: float = 0.0) -> tuple[Range, Range]:
        """The ``[board] offset_mm`` values that keep ``points`` inside the envelope.

        Args:
            points: (N, 2) machine XY as this profile places them (its own offset_mm).
            slack: Keep them this far inside the envelope's edges.

        Returns:
            Per axis, the [low, high] of offset_mm values; low > high on an axis where
            the points span more than the envelope (less twice ``slack``).
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        lo, hi = p.min(axis=0), p.max(axis=0)
        spans = (self.envelope.x_mm, self.envelope.y_mm)
        x, y = (
            (
                self.board.offset_mm[k] + spans[k][0] + slack - float(lo[k]),
                self.board.offset_mm[k] + spans[k][1] - slack - float(hi[k]),
            )
            for k in range(2)
        )
        return x, y

    def fitting_offset(self, board_size: tuple[float, float]) -> tuple[float, float] | None:
        """The ``[board] offset_mm`` nearest the profile's own that puts the whole board inside.

        The board is kept :attr:`envelope_slack_mm` inside the envelope where it is that
        much smaller than the travel. Each coordinate is a whole millimetre where one
        fits, else a tenth, and so on down to the G-code's decimals. The profile's
        ``origin`` and ``rotation_deg`` stay as they are.

        Returns:
            (x, y), or None when the board (so turned) is larger than the travel.
        """
        outline = self.board_outline(board_size)
        ranges = self.offset_range(outline, self.envelope_slack_mm)
        if any(lo > hi for lo, hi in ranges):
            ranges = self.offset_range(outline)
        if any(lo > hi for lo, hi in ranges):
            return None
        x, y = (
            _nearest_round(c, r, self.gcode.decimals)
            for c, r in zip(self.board.offset_mm, ranges, strict=True)
        )
        return x, y

    def origin_xy_text(self) -> tuple[str, str]:
        """``[board] offset_mm`` as the G-code writes numbers (``("20", "20")``; no ``1e-05``).

        The X and Y the board's origin point has in the G-code's work coordinates: the
        numbers of its work zero command (:func:`~scratchfab.machine.sender.work_zero_command`)
        and of the report's setup step.
        """
        x, y = (gcode_number(v, self.gcode.decimals) for v in self.board.offset_mm)
        return x, y

    def board_top(self) -> str:
        """The machine direction the board's top edge (the design's +y) faces: ``"+Y"``, ``"-X"``..."""
        return ("+Y", "-X", "-Y", "+X")[self.board.rotation_deg // 90]

    def board_outline(self, board_size: tuple[float, float]) -> np.ndarray:
        """(4, 2) machine XY of the board corners, counter-clockwise."""
        hw, hh = board_size[0] / 2, board_size[1] / 2
        corners = np.array([[-hw, -hh], [hw, -hh], [hw, hh], [-hw, hh]])
        return self.board_to_machine(corners, board_size)


def _nearest_round(value: float, span: Range, decimals: int) -> float:
    """``value`` moved into ``span``, onto the coarsest grid (1 mm, 0.1 mm, ...) with a point in it."""
    lo, hi = span
    if lo <= value <= hi:
        return value
    for digits in range(decimals + 1):
        unit = 10.0**-digits
        first = math.ceil(round(lo / unit, 6)) * unit
        last = math.floor(round(hi / unit, 6)) * unit
        if first <= last:
            return round(min(max(value, first), last), digits)
    return min(max(value, lo), hi)


def profile_from_mapping(data: Any, source: str) -> MachineProfile:
    """Parse a profile table (as read from TOML); errors name ``source`` and the key."""
    profile = parse_table(MachineProfile, data, source)
    object.__setattr__(profile, "source", source)
    return profile


def load_profile(name_or_path: str | Path | MachineProfile) -> MachineProfile:
    """Load a bundled profile by name, or any profile file by path.

    A profile already loaded is returned as it is, so that callers take either.

    Raises:
        ConfigError: Unknown name, unreadable file, or a key that is wrong (named).
    """
    if isinstance(name_or_path, MachineProfile):
        return name_or_path
    path = find_bundled("machine_profiles", name_or_path, "machine")
    return profile_from_mapping(load_toml(path), str(path))


def profile_ref(profile: MachineProfile) -> str | None:
    """``profile`` as ``--machine`` takes it: a bundled profile's name, else its file.

    None for a profile built in code, or one read from a toolpath's record (no file of its own).
    """
    if bundled := bundled_name("machine_profiles", profile.source):
        return bundled
    return profile.source if Path(profile.source).is_file() else None


def machine_named(name: str, ref: str | None = None, *details: str) -> str:
    """``machine 'NAME' (REF; DETAILS)``: a machine profile as messages name it.

    Args:
        name: The profile's ``name``.
        ref: How the profile is given (:func:`profile_ref`, or a toolpath's record); None: not said.
        details: More to say in the brackets, after ``ref``.
    """
    said = "; ".join(s for s in (ref, *details) if s)
    return f"machine '{name}'" + (f" ({said})" if said else "")
