"""The toolpath stage: board scratches -> ordered strokes in machine coordinates.

:func:`plan_toolpath` maps the scratches onto the bed (the profile's board placement),
clips them to the board and the envelope, drops those shorter than the tool's minimum,
merges overlapping collinear duplicates, orders them (:mod:`scratchfab.toolpath.order`)
and estimates the machining time (:mod:`scratchfab.toolpath.timing`). The result,
:class:`Toolpath`, is what ``JOB/toolpath/toolpath.json`` holds and what the exporters
write.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from PIL import Image, ImageDraw

from scratchfab import figures
from scratchfab.bundled import bundled_name
from scratchfab.console import duration_text
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.fileio import decode_json, read_input, save_png, write_text
from scratchfab.machine.profile import (
    MachineProfile,
    gcode_number,
    machine_named,
    profile_from_mapping,
)
from scratchfab.model.design import Board, ScratchTool
from scratchfab.model.scratches import ON_BOARD_TOLERANCE_MM, ScratchSet
from scratchfab.toolpath.geometry import clip_strokes, merge_collinear, onto_box
from scratchfab.toolpath.inputs import checked_record
from scratchfab.toolpath.order import (
    OrderOptions,
    OrderProgress,
    OrderProgressCallback,
    order_strokes,
    tour_travel,
)
from scratchfab.toolpath.timing import path_times

FORMAT = "scratchfab-toolpath"
VERSION = 1
#: What to do about a board wholly outside the machine's envelope (said by the toolpath
#: stage, which refuses it, and by ``scratchfab run`` before design).
OUTSIDE_ADVICE = (
    "set the machine profile's [board] offset_mm to where the board lies on the bed "
    "(inside the envelope), or correct the profile's [envelope]"
)


def xy_text(points: np.ndarray) -> str:
    """Machine XY points as prose, to 0.1 mm: ``"(-220, -150), (-190, -150)"``."""
    rounded = np.asarray(points, dtype=np.float64).reshape(-1, 2).round(1) + 0.0  # no -0
    return ", ".join(f"({x:g}, {y:g})" for x, y in rounded.tolist())


def envelope_text(profile: MachineProfile) -> str:
    """``"the envelope of machine 'NAME' (X -300 to 0, Y -180 to 0)"``."""
    return f"the envelope of machine '{profile.name}' ({profile.envelope.xy_text()})"


def _offset_text(offset: tuple[float, float]) -> str:
    """An offset_mm as the profile writes it: ``[-220, -161]``."""
    return f"[{gcode_number(offset[0], 6)}, {gcode_number(offset[1], 6)}]"


def oversize_text(profile: MachineProfile, board_size: tuple[float, float]) -> str | None:
    """Why no ``[board] offset_mm`` can put the whole board in the envelope, or None.

    The board is larger than the machine's travel on an axis (after the profile's quarter
    turns); the text names the spans, the design keys and the largest board that fits
    and, when the board would fit turned a quarter, the ``rotation_deg`` and the
    ``offset_mm`` that do it.
    """
    turned = profile.board.rotation_deg % 180 == 90
    spans = (board_size[1], board_size[0]) if turned else board_size
    keys = ("height_mm", "width_mm") if turned else ("width_mm", "height_mm")
    travel = profile.envelope.max_travel_mm[:2]
    over = [
        f"the board spans {span:g} mm in {axis} (the design's [board] {key}) but the "
        f"machine's {axis} travel is {room:g} mm"
        for axis, span, key, room in zip("XY", spans, keys, travel, strict=True)
        if span > room
    ]
    if not over:
        return None
    most = (travel[1], travel[0]) if turned else travel
    text = (
        f"{' and '.join(over)}: no offset_mm in the profile's [board] can fit it; make the "
        f"board at most {most[0]:g} x {most[1]:g} mm (width_mm x height_mm)"
    )
    other = (profile.board.rotation_deg + 90) % 360
    quarter = replace(profile, board=replace(profile.board, rotation_deg=other))
    offset = quarter.fitting_offset(board_size)
    if offset is not None:
        text += (
            f" or turn it a quarter (the profile's [board] rotation_deg = {other} with "
            f"offset_mm = {_offset_text(offset)})"
        )
    return text


def fit_advice(profile: MachineProfile, board_size: tuple[float, float]) -> str:
    """What to change so that the machine reaches the whole board.

    :func:`oversize_text` for a board larger than the travel, else the ``[board]
    offset_mm`` nearest the profile's that fits
    (:meth:`~scratchfab.machine.profile.MachineProfile.fitting_offset`) and the range
    of those that do, in the profile's convention (its origin corner, its rotation); for
    a board that lies inside the envelope as placed, that no offset is to change. The
    offset named keeps the board clear of the envelope's edges where it can: a range's
    end in whole millimetres puts the board on an edge, so the offset lies a unit inside
    it, and the text says why.
    """
    too_big = oversize_text(profile, board_size)
    offset = profile.fitting_offset(board_size)
    if too_big is not None or offset is None:
        return (too_big or OUTSIDE_ADVICE) + _copy_advice(profile)
    (x0, x1), (y0, y1) = profile.offset_range(profile.board_outline(board_size))
    now = profile.board.offset_mm
    if x0 <= now[0] <= x1 and y0 <= now[1] <= y1:
        # No offset to name: the board lies inside the envelope where it is.
        return (
            f"the profile's [board] offset_mm = {_offset_text(now)} already puts the whole "
            "board inside the envelope: what is cut short lies beyond the board's own edges "
            "(check the scratches against the design's [board] width_mm and height_mm)"
        )
    place = profile.board
    corner = place.origin_text
    turned = f" (turned by rotation_deg = {place.rotation_deg})" if place.rotation_deg else ""
    dec = profile.gcode.decimals
    clear = all(lo < v < hi for v, (lo, hi) in zip(offset, ((x0, x1), (y0, y1)), strict=True))
    why = " that keeps the board clear of the envelope's edges" if clear else ""
    return (
        f"set the profile's [board] offset_mm = {_offset_text(offset)} (the nearest to "
        f"its {_offset_text(now)}{why}), where the "
        f"board's {corner}{turned} then lies: the whole board fits with any offset_mm "
        f"from X {_range_text(x0, x1, dec)} and Y {_range_text(y0, y1, dec)}"
    ) + _copy_advice(profile)


def _range_text(lo: float, hi: float, decimals: int) -> str:
    """``-238.271 to -61.729``: the range ``[lo, hi]``, its ends rounded inward to ``decimals``.

    Each end as written lies in the range (rounded to nearest, one could lie outside it,
    farther than the toolpath stage keeps on the edge); float noise below 1e-6 of a unit
    is not rounded inward. Where no value with ``decimals`` lies inside, the ends to 6
    decimals.
    """
    unit = 10.0**-decimals
    first = math.ceil(round(lo / unit, 6)) * unit
    last = math.floor(round(hi / unit, 6)) * unit
    if first > last:
        first, last, decimals = lo, hi, 6
    return f"{gcode_number(first, decimals)} to {gcode_number(last, decimals)}"


def _copy_advice(profile: MachineProfile) -> str:
    """For a bundled profile: where the change goes (a copy), else nothing.

    The bundled file lives inside the installed package: an edit there is lost on the
    next install, and a copy elsewhere is not read by ``--machine NAME``.
    """
    name = bundled_name("machine_profiles", profile.source)
    if name is None:
        return ""
    return (
        f" ('{name}' is a bundled profile: copy {profile.source} to a file of your own, make "
        "the change there and give that file as --machine, or a pipeline's [toolpath] machine)"
    )


def partial_text(stats: dict[str, Any]) -> str | None:
    """What the envelope cuts off a planned board (:func:`plan_toolpath`'s stats), or None.

    Said by ``toolpath``, ``export`` and written into the G-code's header.
    """
    outside, clipped = int(stats.get("outside_count", 0)), int(stats.get("clipped_count", 0))
    if not outside and not clipped:
        return None
    return (
        f"{outside} of {stats.get('input_count', '?')} scratches lie outside the machine's "
        f"envelope (not cut) and {clipped} are clipped to it"
    )


@dataclass(frozen=True, eq=False)
class Toolpath:
    """Ordered strokes in machine coordinates.

    Attributes:
        strokes: (N, 2, 2) stroke k runs from strokes[k, 0] to strokes[k, 1] (machine mm),
            in cut order.
        source_rows: (N,) the scratch (0-based, input order) each stroke comes from; for
            merged duplicates, the longest of them.
        board_mm: Board width and height.
        outline: (4, 2) board corners on the bed, counter-clockwise.
        profile: The machine profile the strokes were planned for.
        stats: Counts, lengths (mm) and the time estimate (s); see :func:`plan_toolpath`.
        inputs: The files it was planned from, as the toolpath stage records them
            (:func:`scratchfab.toolpath.inputs.record_inputs`); None when not recorded.
        file: The ``toolpath.json`` it was loaded from (None: planned in memory); the
            paths in ``inputs`` are relative to its folder.
    """

    strokes: np.ndarray
    source_rows: np.ndarray
    board_mm: tuple[float, float]
    outline: np.ndarray
    profile: MachineProfile
    stats: dict[str, Any] = field(default_factory=dict)
    inputs: dict[str, Any] | None = None
    file: Path | None = None

    def __len__(self) -> int:
        return len(self.strokes)

    @property
    def start(self) -> np.ndarray:
        """The machine's start (and end) position, XY mm."""
        return np.asarray(self.profile.start_mm, dtype=np.float64)

    @property
    def strokes_id(self) -> str:
        """16 hex digits of the SHA-256 of the ordered strokes (float64, machine mm).

        The G-code's header carries it, so that ``stream JOB`` can tell a G-code exported
        from an earlier plan than ``toolpath.json``'s (floats are written exactly, so a
        loaded toolpath gives its planned strokes' id).
        """
        data = np.ascontiguousarray(self.strokes, dtype=np.float64).tobytes()
        return hashlib.sha256(data).hexdigest()[:16]

    def to_json(self) -> str:
        """The toolpath as JSON text (floats written exactly)."""
        data = {
            "format": FORMAT,
            "version": VERSION,
            "machine": self.profile.to_table(),
            "machine_source": self.profile.source,
            "board_mm": list(self.board_mm),
            "outline_mm": self.outline.tolist(),
            "start_mm": list(self.profile.start_mm),
            "statistics": self.stats,
            **({"inputs": self.inputs} if self.inputs is not None else {}),
            "source_rows": self.source_rows.tolist(),
            "strokes": self.strokes.reshape(-1, 4).tolist(),
        }
        return json.dumps(data, indent=1) + "\n"

    def save(self, path: str | Path) -> None:
        """Write ``toolpath.json`` atomically."""
        write_text(path, self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> Toolpath:
        """Read a ``toolpath.json`` written by :meth:`save`.

        Raises:
            ConfigError: Naming the file and what is wrong.
        """
        file = Path(path)
        raw = read_input(
            file, "a toolpath JSON file", "file not found (run `scratchfab toolpath` first)"
        )
        try:
            data = decode_json(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{file}: not a toolpath JSON file ({exc})") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ConfigError(f"{file}: not a scratchfab toolpath (format != {FORMAT!r})")
        if data.get("version") != VERSION:
            raise ConfigError(f"{file}: version {data.get('version')!r}, expected {VERSION}")
        try:
            strokes = np.asarray(data["strokes"], dtype=np.float64).reshape(-1, 2, 2)
            rows = np.asarray(data["source_rows"], dtype=np.int64).reshape(-1)
            outline = np.asarray(data["outline_mm"], dtype=np.float64).reshape(4, 2)
            board = (float(data["board_mm"][0]), float(data["board_mm"][1]))
            stats = dict(data["statistics"])
        except (KeyError, TypeError, ValueError, IndexError, OverflowError) as exc:
            raise ConfigError(f"{file}: malformed toolpath ({exc!r})") from None
        if len(rows) != len(strokes):
            raise ConfigError(f"{file}: malformed toolpath (strokes and source_rows differ)")
        for key, values in (("strokes", strokes), ("outline_mm", outline), ("board_mm", board)):
            if not np.all(np.isfinite(values)):
                raise ConfigError(f"{file}: malformed toolpath ({key} must be finite numbers)")
        if min(board) <= 0:
            raise ConfigError(f"{file}: malformed toolpath (board_mm must be positive)")
        profile = profile_from_mapping(data.get("machine"), f"{file}: machine")
        inputs = checked_record(data.get("inputs"), str(file))
        return cls(strokes, rows, board, outline, profile, stats, inputs, file)


def _differs(a: float | np.ndarray, b: float) -> Any:
    """Whether a tool size differs from the machine's ``b`` (beyond 0.1 %)."""
    return np.abs(np.asarray(a) - b) > 1e-3 * b + 1e-12


def tool_mismatch(profile: MachineProfile, design_tool: ScratchTool) -> str | None:
    """Why the design's ``[scratch]`` tool is not the machine's, or None (it is)."""
    for key in ("width_mm", "depth_mm"):
        want, have = getattr(profile.tool, key), getattr(design_tool, key)
        if _differs(have, want):
            return (
                f"the design's [scratch] {key} = {have:g} but machine '{profile.name}' "
                f"({profile.source}) cuts tool.{key} = {want:g}; use a matching machine "
                "profile or design"
            )
    return None


def check_tool(
    profile: MachineProfile, design_tool: ScratchTool | None, scratches: ScratchSet
) -> None:
    """Refuse a design whose tool differs from the machine's.

    Raises:
        ScratchfabError: Naming both values (and the first differing scratch row).
    """
    tool = profile.tool
    if design_tool is not None and (why := tool_mismatch(profile, design_tool)) is not None:
        raise ScratchfabError(why)
    for column, values, want in (
        ("width", scratches.width, tool.width_mm),
        ("depth", scratches.depth, tool.depth_mm),
    ):
        bad = np.flatnonzero(_differs(values, want))
        if len(bad):
            row = int(bad[0])
            raise ScratchfabError(
                f"scratch {row + 1} (line {row + 2}) has {column} {values[row]:g} mm but machine "
                f"'{profile.name}' cuts {want:g} mm ({len(bad)} scratches differ)"
            )


def estimate_time(strokes: np.ndarray, profile: MachineProfile) -> float:
    """Seconds to run the job as the G-code writer emits it and GRBL plans it.

    Moves, in the writer's order, join at GRBL's corner speeds (``$11`` taken from the
    profile's ``junction_deviation_mm``) except where a command empties the planner: the
    servo's ``M3`` and ``M5`` around every cut, the spindle's start and stop. Each servo
    lowering and lift waits ``dwell_s`` (and so does the lift before the first travel);
    the travel back to the start is included, the time to reach the start is not.

    Args:
        strokes: (N, 2, 2) strokes in cut order, each from ``[k, 0]`` to ``[k, 1]``
            (machine XY, mm), as :attr:`Toolpath.strokes`.
        profile: The machine (start position, feeds, motion limits, tool control).
    """
    n = len(strokes)
    start = np.asarray(profile.start_mm, dtype=np.float64)
    if n == 0:
        return 0.0
    motion = profile.motion
    control = profile.tool_control
    stops = np.vstack([start[None, :], strokes[:, 1]])
    goes = np.vstack([strokes[:, 0], start[None, :]])
    travel = np.zeros((n + 1, 3))
    travel[:, :2] = goes - stops
    cut = np.zeros((n, 3))
    cut[:, :2] = strokes[:, 1] - strokes[:, 0]
    travel_feed = profile.feeds.travel_mm_min or math.inf
    if control.mode == "servo":
        # travel, M3, G4, cut, M5, G4 per stroke: every move starts and ends at rest.
        moves = np.stack([travel[:-1], cut], axis=1).reshape(-1, 3)
        feeds = np.tile([travel_feed, profile.feeds.engrave_mm_min], n)
        rest = np.ones(2 * n + 1, dtype=bool)
        dwells = (2 * n + 1) * control.dwell_s
    else:
        # travel, plunge, cut, lift per stroke, joined at corners; the spindle's M5 before
        # the travel back empties the planner (the Z mode's M5 changes nothing).
        dz = profile.z.safe_mm - profile.z.engrave_mm
        plunge = np.broadcast_to([0.0, 0.0, -dz], (n, 3))
        lift = np.broadcast_to([0.0, 0.0, dz], (n, 3))
        moves = np.stack([travel[:-1], plunge, cut, lift], axis=1).reshape(-1, 3)
        feeds = np.tile(
            [travel_feed, profile.feeds.plunge_mm_min, profile.feeds.engrave_mm_min, math.inf], n
        )
        rest = np.zeros(4 * n + 1, dtype=bool)
        rest[-1] = control.mode == "spindle"
        dwells = control.dwell_s if control.mode == "spindle" else 0.0
    moves = np.vstack([moves, travel[-1:]])
    feeds = np.append(feeds, travel_feed)
    rest[0] = True
    seconds = path_times(
        moves,
        feeds,
        motion.max_rate_mm_min,
        motion.acceleration_mm_s2,
        rest_before=rest,
        junction_deviation_mm=motion.junction_deviation_mm,
    )
    return float(seconds.sum() + dwells)


def edge_slack(profile: MachineProfile) -> float:
    """How far beyond the envelope's edge a value may lie and still be on it (mm).

    Half a written digit (:attr:`~scratchfab.machine.profile.MachineProfile.envelope_slack_mm`)
    or a scratch file's tolerance (:data:`~scratchfab.model.scratches.ON_BOARD_TOLERANCE_MM`),
    whichever is larger: the toolpath stage moves a stroke's end this close onto the edge.
    """
    return max(profile.envelope_slack_mm, ON_BOARD_TOLERANCE_MM)


def unreached_text(
    profile: MachineProfile, board_size: tuple[float, float], stats: dict[str, Any]
) -> str | None:
    """What the machine cannot reach of a planned board and what to change, or None.

    In the toolpath stage's words: the scratches its envelope leaves out or clips
    (:func:`partial_text`), its travel, and
    :func:`fit_advice`.

    Args:
        profile: The machine.
        board_size: The board's width and height (mm).
        stats: :func:`plan_toolpath`'s counts.
    """
    lost = partial_text(stats)
    if lost is None:
        return None
    travel = profile.envelope.max_travel_mm
    advice = fit_advice(profile, board_size)
    return (
        f"{machine_named(profile.name, profile.source)} cannot reach the whole "
        f"{board_size[0]:g} x {board_size[1]:g} mm board: {lost}; its travel is "
        f"{travel[0]:g} x {travel[1]:g} mm ({profile.envelope.xy_text()}). "
        f"{advice[0].upper()}{advice[1:]}"
    )


def plan_toolpath(
    scratches: ScratchSet,
    board: Board,
    profile: MachineProfile,
    design_tool: ScratchTool | None = None,
    options: OrderOptions | None = None,
    progress: OrderProgressCallback | None = None,
) -> Toolpath:
    """Turn a board's scratches into ordered machine strokes.

    Args:
        scratches: The scratches in board coordinates (SPEC section 3).
        board: The board (its size; scratches are clipped to it, and those with no part
            on it are left out as off the board).
        profile: The machine.
        design_tool: The design's ``[scratch]`` table; its width and depth must match the
            profile's tool.
        options: Ordering options (deterministic for given options).
        progress: Called with :class:`~scratchfab.toolpath.order.OrderProgress` reports:
            first a message naming the scratches and the machine, then the ordering's
            (:func:`~scratchfab.toolpath.order.order_strokes`); the toolpath is the same
            with it or without.

    Returns:
        The toolpath; ``stats`` holds ``input_count``, ``off_board_count`` (no part on
        the board), ``outside_count`` (on the board, no part of it within the envelope),
        ``clipped_count``, ``short_count``, ``merged_count``
        (strokes absorbed by duplicates), ``count``, ``cut_length_mm``,
        ``travel_length_mm``, ``travel_input_order_mm``, ``travel_greedy_mm``,
        ``kept_input_order``, ``local_search_moves`` and ``estimated_time_s``.

    Raises:
        ScratchfabError: The tools differ, an end point is NaN or infinite, or the board
            does not meet the envelope.
    """
    if progress is not None:
        progress(OrderProgress.note(f"ordering {len(scratches)} scratches for {profile.name} ..."))
    check_tool(profile, design_tool, scratches)
    bad = np.flatnonzero(~np.all(np.isfinite(np.hstack([scratches.p0, scratches.p1])), axis=1))
    if len(bad):
        row = int(bad[0])
        raise ScratchfabError(
            f"scratch {row + 1} (line {row + 2}) has an end point that is not a finite number "
            f"({len(bad)} scratches); nothing planned"
        )
    size = (board.width_mm, board.height_mm)
    outline = profile.board_outline(size)
    env = profile.envelope
    # The board turns by quarter turns only: its outline is an axis-aligned rectangle, and
    # so is its part within the envelope, the region the strokes are clipped to.
    lo = np.maximum(outline.min(axis=0), [env.x_mm[0], env.y_mm[0]])
    hi = np.minimum(outline.max(axis=0), [env.x_mm[1], env.y_mm[1]])
    if np.any(lo >= hi):
        raise ScratchfabError(
            f"{profile.source}: the {size[0]:g} x {size[1]:g} mm board (corners "
            f"{xy_text(outline)}) lies wholly outside {envelope_text(profile)}, so nothing "
            f"can be cut; {fit_advice(profile, size)}"
        )
    # An end within half a written digit beyond the region's edge lies on it as the G-code
    # writes it, and one within a scratch file's tolerance lies on the board as read: it
    # is moved onto the edge, not cut off (a stroke along the edge of a board as large as
    # the travel is kept). The G-code writer rounds a value on the edge to the nearest
    # written value inside the envelope.
    slack = edge_slack(profile)
    m0 = onto_box(profile.board_to_machine(scratches.p0, size), lo, hi, slack)
    m1 = onto_box(profile.board_to_machine(scratches.p1, size), lo, hi, slack)
    keep, q0, q1 = clip_strokes(m0, m1, shapely.box(*lo, *hi))
    # Left out: those with no part on the board (given in memory: a scratch file's are
    # checked when read) are off the board, the rest outside the envelope.
    left_out = np.setdiff1d(np.arange(len(scratches)), keep)
    board_box = shapely.box(*outline.min(axis=0), *outline.max(axis=0))
    outside = left_out[clip_strokes(m0[left_out], m1[left_out], board_box)[0]]
    # Clipped by the envelope: an end beyond it (further than the slack), not one that the
    # board's own edge clips.
    beyond = ~(env.contains_xy(m0) & env.contains_xy(m1))
    clipped = int(np.count_nonzero(beyond[keep]))
    lengths = np.hypot(*(q1 - q0).T)
    # A stroke must also survive rounding to the written decimals with a non-zero length.
    min_length = max(profile.tool.min_length_mm, 2.0 * 10.0 ** (-profile.gcode.decimals))
    long_enough = lengths >= min_length
    keep, q0, q1 = keep[long_enough], q0[long_enough], q1[long_enough]
    r0, r1, groups = merge_collinear(q0, q1, profile.tool.tolerance_mm)
    # Never beyond the region: clipped ends lie on its edges up to float rounding, and a
    # merged stroke runs along its longest member's line, within the tolerance of the rest.
    r0, r1 = np.clip(r0, lo, hi), np.clip(r1, lo, hi)
    kept_lengths = lengths[long_enough]  # once: per group it was quadratic (100k: 10 s)
    longest = [keep[g[np.argmax(kept_lengths[g])]] for g in groups]
    rows = np.array(longest, dtype=np.int64).reshape(-1)
    # Merged strokes may be a little shorter than the tool allows only if a member was.
    result = order_strokes(r0, r1, profile.start_mm, options, progress)
    first = np.where(result.reverse[:, None], r1[result.order], r0[result.order])
    last = np.where(result.reverse[:, None], r0[result.order], r1[result.order])
    strokes = np.stack([first, last], axis=1).reshape(-1, 2, 2)
    travel = tour_travel(strokes[:, 0], strokes[:, 1], np.asarray(profile.start_mm))
    stats: dict[str, Any] = {
        "input_count": len(scratches),
        "off_board_count": int(len(left_out) - len(outside)),
        "outside_count": len(outside),
        "clipped_count": clipped,
        "short_count": int(np.count_nonzero(~long_enough)),
        "merged_count": int(len(q0) - len(r0)),
        "count": len(strokes),
        "cut_length_mm": float(np.hypot(*(strokes[:, 1] - strokes[:, 0]).T).sum()),
        "travel_length_mm": travel,
        "travel_input_order_mm": result.travel_input_mm,
        "travel_greedy_mm": result.travel_greedy_mm,
        "kept_input_order": result.kept_input,
        "local_search_moves": result.moves,
        "estimated_time_s": estimate_time(strokes, profile),
    }
    return Toolpath(strokes, rows[result.order], size, outline, profile, stats)


#: Preview colours (Okabe-Ito based, apart under red-green blindness).
CUT_RGB = (0, 0, 0)
TRAVEL_RGB = figures.OKABE_ITO["vermillion"]
BOARD_RGB = (150, 150, 150)
ENVELOPE_RGB = (60, 90, 220)
START_RGB = figures.OKABE_ITO["bluish_green"]
TOP_RGB = figures.OKABE_ITO["reddish_purple"]
#: Pixels around the drawn extent, so marks on its edge are not cut off.
PREVIEW_MARGIN_PX = 16


@dataclass
class PreviewFigure:
    """The drawn preview and its geometry.

    Attributes:
        image: The whole picture (title band on top, key on the right).
        origin_px: Pixel of the extent's lower-left corner ``lo_mm``.
        lo_mm: Lower-left corner of the drawn extent, machine mm.
        px_per_mm: Scale.
        start_inside: Whether the start position lies in the picture.
        legend_box: The key's box.
        legend: The key's rows.
    """

    image: Image.Image
    origin_px: tuple[float, float]
    lo_mm: np.ndarray
    px_per_mm: float
    start_inside: bool
    legend_box: tuple[int, int, int, int]
    legend: list[figures.LegendItem]

    def to_px(self, p: np.ndarray) -> np.ndarray:
        """Machine XY (..., 2) mm to picture pixels (x right, y down)."""
        q = (np.asarray(p, dtype=np.float64) - self.lo_mm) * self.px_per_mm
        return np.stack([self.origin_px[0] + q[..., 0], self.origin_px[1] - q[..., 1]], axis=-1)


def _leave_box(
    inside: np.ndarray, outside: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """Where the segment from ``inside`` (in the box) to ``outside`` crosses the box's edge."""
    d = outside - inside
    t = 1.0
    for k in range(2):
        if d[k] > 0:
            t = min(t, (hi[k] - inside[k]) / d[k])
        elif d[k] < 0:
            t = min(t, (lo[k] - inside[k]) / d[k])
    return inside + max(t, 0.0) * d


def preview_figure(toolpath: Toolpath, max_px: int = 1200) -> PreviewFigure:
    """Draw the board outline, cuts, travel moves, envelope and start with a title and key.

    The picture frames the board and the strokes; it takes in the start position too
    unless that more than doubles the area, and then the travel legs to and from the
    start end in arrows on the picture's edge, labelled with the start's coordinates.
    """
    pts = [toolpath.outline]
    if len(toolpath):
        pts.append(toolpath.strokes.reshape(-1, 2))
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    extra = 0.05 * float((hi - lo).max())
    lo, hi = lo - extra, hi + extra
    start = toolpath.start
    with_start = np.minimum(lo, start), np.maximum(hi, start)
    start_inside = bool(np.prod(with_start[1] - with_start[0]) <= 2.0 * np.prod(hi - lo))
    if start_inside:
        lo, hi = with_start
    span = np.maximum(hi - lo, 1e-9)
    m = PREVIEW_MARGIN_PX
    scale = (max_px - 2 * m) / float(span.max())
    w = int(math.ceil(span[0] * scale)) + 2 * m
    h = int(math.ceil(span[1] * scale)) + 2 * m

    def px(p: np.ndarray) -> list[tuple[float, float]]:
        q = (np.asarray(p, dtype=np.float64).reshape(-1, 2) - lo) * scale
        return [(float(a) + m, h - m - float(b)) for a, b in q]

    image = Image.new("RGB", (w, h), "white")
    draw = ImageDraw.Draw(image)
    env = toolpath.profile.envelope
    ex = np.array(env.x_mm, dtype=np.float64)
    ey = np.array(env.y_mm, dtype=np.float64)
    (bx0, by0), (bx1, by1) = px(np.array([[ex[0], ey[1]], [ex[1], ey[0]]]))
    # Edges beyond the margin stay out of the picture; those inside are drawn whole.
    box = (max(bx0, -10.0), max(by0, -10.0), min(bx1, w + 10.0), min(by1, h + 10.0))
    envelope_shown = (
        (0 <= bx0 <= w or 0 <= bx1 <= w or 0 <= by0 <= h or 0 <= by1 <= h)
        and box[0] < box[2]
        and box[1] < box[3]
    )
    if box[0] < box[2] and box[1] < box[3]:
        draw.rectangle(box, outline=ENVELOPE_RGB, width=2)
    draw.line(px(np.vstack([toolpath.outline, toolpath.outline[:1]])), fill=BOARD_RGB, width=2)
    size = figures.TEXT_PX
    if len(toolpath):
        legs_from = np.vstack([start[None, :], toolpath.strokes[:, 1]])
        legs_to = np.vstack([toolpath.strokes[:, 0], start[None, :]])
        inner = slice(None) if start_inside else slice(1, -1)
        for a, b in zip(px(legs_from[inner]), px(legs_to[inner]), strict=True):
            draw.line([a, b], fill=TRAVEL_RGB, width=1)
        if not start_inside:
            exits = []
            for near in (toolpath.strokes[0, 0], toolpath.strokes[-1, 1]):
                edge = _leave_box(near, start, lo, hi)
                (a, b) = px(np.vstack([near, edge]))
                figures.draw_arrow(draw, a, b, TRAVEL_RGB, width=2, head=10)
                exits.append(b)
            label = f"to start ({start[0]:g}, {start[1]:g}) mm"
            tw, th = figures.text_size(label, size)
            cx = float(np.mean([e[0] for e in exits]))
            cy = float(np.mean([e[1] for e in exits]))
            # Inside the picture, on the side of the exits away from the edge.
            tx = min(max(cx - tw / 2, m), w - m - tw)
            ty = min(max(cy + (14 if cy < h / 2 else -14 - th), m), h - m - th)
            draw.rectangle((tx - 3, ty - 1, tx + tw + 3, ty + th + 3), fill=(255, 255, 255))
            draw.text((tx, ty), label, fill=TRAVEL_RGB, font=figures.font(size))
        for a, b in zip(px(toolpath.strokes[:, 0]), px(toolpath.strokes[:, 1]), strict=True):
            draw.line([a, b], fill=CUT_RGB, width=1)
    if start_inside:
        ((sx, sy),) = px(start[None, :])
        draw.ellipse([sx - 6, sy - 6, sx + 6, sy + 6], outline=START_RGB, width=2)
    _draw_board_top(draw, toolpath, px, size)

    items = [
        figures.LegendItem("cut", CUT_RGB, "line"),
        figures.LegendItem("travel (tool up)", TRAVEL_RGB, "line"),
        figures.LegendItem("board outline", BOARD_RGB, "line"),
        figures.LegendItem("board top edge (design +y)", TOP_RGB, "arrow"),
    ]
    if envelope_shown:
        items.append(figures.LegendItem("machine envelope", ENVELOPE_RGB, "line"))
    if start_inside:
        items.append(
            figures.LegendItem(f"start/end ({start[0]:g}, {start[1]:g}) mm", START_RGB, "ring")
        )
    else:
        items.append(figures.LegendItem("travel to/from start (off picture)", TRAVEL_RGB, "arrow"))
    lw, lh = figures.legend_size(items, size)
    panel = lw + 2 * m
    canvas = figures.pad(image, (0, 0, panel, max(0, lh + 80 + m - h)))
    legend_box = figures.draw_legend(canvas, items, (w + m, m), size)
    figures.draw_scale_bar(canvas, scale, (w + m + 2, legend_box[3] + 30), max_px=lw - 70)
    stats = toolpath.stats
    title = [
        f"{toolpath.profile.name}: {len(toolpath)} strokes, "
        f"cut {float(stats.get('cut_length_mm', 0.0)):.0f} mm, "
        f"travel {float(stats.get('travel_length_mm', 0.0)):.0f} mm, "
        f"about {duration_text(float(stats.get('estimated_time_s', 0.0)))}",
        f"board {toolpath.board_mm[0]:g} x {toolpath.board_mm[1]:g} mm in machine coordinates, "
        f"+y up; the board's top edge faces machine {toolpath.profile.board_top()}",
    ]
    out = figures.add_title(canvas, title, size + 1, margin=m)
    dy = out.height - canvas.height
    shifted = (legend_box[0], legend_box[1] + dy, legend_box[2], legend_box[3] + dy)
    return PreviewFigure(
        out, (float(m), float(h - m + dy)), lo, scale, start_inside, shifted, items
    )


def _draw_board_top(
    draw: ImageDraw.ImageDraw,
    toolpath: Toolpath,
    px: Callable[[np.ndarray], list[tuple[float, float]]],
    size: int,
) -> None:
    """An arrow out of the middle of the board's top edge (the design's +y), labelled "board top".

    A board turned on the bed looks the same cut; this tells which way up it hangs.
    """
    half = 0.5 * toolpath.board_mm[1]
    mid, out = toolpath.profile.board_to_machine(
        np.array([[0.0, half], [0.0, half + 1.0]]), toolpath.board_mm
    )
    (a, b) = px(np.vstack([mid, out]))
    d = np.array([b[0] - a[0], b[1] - a[1]])
    d /= max(float(np.hypot(*d)), 1e-9)
    tip = (a[0] + 30.0 * float(d[0]), a[1] + 30.0 * float(d[1]))
    figures.draw_arrow(draw, a, tip, TOP_RGB, width=2, head=10)
    tw, th = figures.text_size("board top", size)
    tx = tip[0] + 6.0 * float(d[0]) - tw / 2 + 0.5 * tw * float(d[0])
    ty = tip[1] + 6.0 * float(d[1]) - th / 2 + 0.5 * th * float(d[1])
    mode, draw.fontmode = draw.fontmode, "1"  # one colour, the key's, not anti-aliased shades
    draw.text((tx, ty), "board top", fill=TOP_RGB, font=figures.font(size))
    draw.fontmode = mode


def write_preview(toolpath: Toolpath, path: str | Path, max_px: int = 1200) -> None:
    """Write the PNG of :func:`preview_figure`: cuts, travel, board, envelope, start, key."""
    save_png(path, preview_figure(toolpath, max_px).image)
