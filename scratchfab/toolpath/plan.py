"""The toolpath stage: board scratches -> ordered strokes in machine coordinates.

:func:`plan_toolpath` maps the scratches onto the bed (the profile's board placement),
clips them to the board and the envelope, drops those shorter than the tool's minimum,
merges overlapping collinear duplicates, orders them (:mod:`scratchfab.toolpath.order`)
and estimates the machining time (:mod:`scratchfab.toolpath.timing`). The result,
:class:`Toolpath`, is what ``JOB/toolpath/toolpath.json`` holds and what the exporters
write.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from PIL import Image, ImageDraw

from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.fileio import save_png, write_text
from scratchfab.machine.profile import MachineProfile, profile_from_mapping
from scratchfab.model.design import Board, ScratchTool
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath.geometry import clip_strokes, merge_collinear
from scratchfab.toolpath.order import OrderOptions, order_strokes, tour_travel
from scratchfab.toolpath.timing import move_times

FORMAT = "scratchfab-toolpath"
VERSION = 1


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
    """

    strokes: np.ndarray
    source_rows: np.ndarray
    board_mm: tuple[float, float]
    outline: np.ndarray
    profile: MachineProfile
    stats: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.strokes)

    @property
    def start(self) -> np.ndarray:
        """The machine's start (and end) position, XY mm."""
        return np.asarray(self.profile.start_mm, dtype=np.float64)

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
        try:
            data = json.loads(file.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"{file}: file not found (run `scratchfab toolpath` first)") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
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
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ConfigError(f"{file}: malformed toolpath ({exc!r})") from None
        if len(rows) != len(strokes) or not np.all(np.isfinite(strokes)):
            raise ConfigError(f"{file}: malformed toolpath (strokes and source_rows differ)")
        profile = profile_from_mapping(data.get("machine"), f"{file}: machine")
        return cls(strokes, rows, board, outline, profile, stats)


def check_tool(
    profile: MachineProfile, design_tool: ScratchTool | None, scratches: ScratchSet
) -> None:
    """Refuse a design whose tool differs from the machine's.

    Raises:
        ScratchfabError: Naming both values (and the first differing scratch row).
    """
    tool = profile.tool

    def differs(a: float | np.ndarray, b: float) -> Any:
        return np.abs(np.asarray(a) - b) > 1e-3 * b + 1e-12

    if design_tool is not None:
        for key in ("width_mm", "depth_mm"):
            want, have = getattr(tool, key), getattr(design_tool, key)
            if differs(have, want):
                raise ScratchfabError(
                    f"the design's [scratch] {key} = {have:g} but machine '{profile.name}' "
                    f"({profile.source}) cuts tool.{key} = {want:g}; use a matching machine "
                    "profile or design"
                )
    for column, values, want in (
        ("width", scratches.width, tool.width_mm),
        ("depth", scratches.depth, tool.depth_mm),
    ):
        bad = np.flatnonzero(differs(values, want))
        if len(bad):
            row = int(bad[0])
            raise ScratchfabError(
                f"scratch {row + 1} (line {row + 2}) has {column} {values[row]:g} mm but machine "
                f"'{profile.name}' cuts {want:g} mm ({len(bad)} scratches differ)"
            )


def estimate_time(strokes: np.ndarray, profile: MachineProfile) -> float:
    """Seconds to run the job as the G-code writer emits it (trapezoidal moves, dwells)."""
    n = len(strokes)
    start = np.asarray(profile.start_mm, dtype=np.float64)
    if n == 0:
        return 0.0
    motion = profile.motion
    stops = np.vstack([start[None, :], strokes[:, 1]])
    goes = np.vstack([strokes[:, 0], start[None, :]])
    travel = np.zeros((n + 1, 3))
    travel[:, :2] = goes - stops
    travel_feed = profile.feeds.travel_mm_min or math.inf
    seconds = move_times(travel, travel_feed, motion.max_rate_mm_min, motion.acceleration_mm_s2)
    cuts = np.zeros((n, 3))
    cuts[:, :2] = strokes[:, 1] - strokes[:, 0]
    seconds_cut = move_times(
        cuts, profile.feeds.engrave_mm_min, motion.max_rate_mm_min, motion.acceleration_mm_s2
    )
    total = float(seconds.sum() + seconds_cut.sum())
    control = profile.tool_control
    if control.mode == "servo":
        total += (2 * n + 1) * control.dwell_s
    else:
        dz = profile.z.safe_mm - profile.z.engrave_mm
        plunge, lift = move_times(
            np.array([[0.0, 0.0, -dz], [0.0, 0.0, dz]]),
            np.array([profile.feeds.plunge_mm_min, math.inf]),
            motion.max_rate_mm_min,
            motion.acceleration_mm_s2,
        )
        total += n * float(plunge + lift)
        if control.mode == "spindle":
            total += control.dwell_s
    return total


def plan_toolpath(
    scratches: ScratchSet,
    board: Board,
    profile: MachineProfile,
    design_tool: ScratchTool | None = None,
    options: OrderOptions | None = None,
) -> Toolpath:
    """Turn a board's scratches into ordered machine strokes.

    Args:
        scratches: The scratches in board coordinates (SPEC section 3).
        board: The board (its size; scratches are clipped to it).
        profile: The machine.
        design_tool: The design's ``[scratch]`` table; its width and depth must match the
            profile's tool.
        options: Ordering options (deterministic for given options).

    Returns:
        The toolpath; ``stats`` holds ``input_count``, ``outside_count`` (no part on the
        board within the envelope), ``clipped_count``, ``short_count``, ``merged_count``
        (strokes absorbed by duplicates), ``count``, ``cut_length_mm``,
        ``travel_length_mm``, ``travel_input_order_mm``, ``travel_greedy_mm``,
        ``kept_input_order``, ``local_search_moves`` and ``estimated_time_s``.

    Raises:
        ScratchfabError: The tools differ, or the board does not meet the envelope.
    """
    check_tool(profile, design_tool, scratches)
    size = (board.width_mm, board.height_mm)
    outline = profile.board_outline(size)
    env = profile.envelope
    # Shrink the envelope by half a unit of the last written digit, so that rounding the
    # coordinates for G-code can never push one outside.
    slack = 0.5 * 10.0 ** (-profile.gcode.decimals)
    region = shapely.Polygon(outline).intersection(
        shapely.box(
            env.x_mm[0] + slack, env.y_mm[0] + slack, env.x_mm[1] - slack, env.y_mm[1] - slack
        )
    )
    if region.is_empty or region.area <= 0:
        raise ScratchfabError(
            f"machine '{profile.name}': the board (corners {outline.round(3).tolist()}) lies "
            f"outside the envelope x {list(env.x_mm)}, y {list(env.y_mm)}; check [board] offset_mm"
        )
    m0 = profile.board_to_machine(scratches.p0, size)
    m1 = profile.board_to_machine(scratches.p1, size)
    keep, q0, q1 = clip_strokes(m0, m1, region)
    clipped = int(
        np.count_nonzero(
            np.any(np.abs(np.stack([q0 - m0[keep], q1 - m1[keep]])) > 1e-9, axis=(0, 2))
        )
    )
    lengths = np.hypot(*(q1 - q0).T)
    # A stroke must also survive rounding to the written decimals with a non-zero length.
    min_length = max(profile.tool.min_length_mm, 2.0 * 10.0 ** (-profile.gcode.decimals))
    long_enough = lengths >= min_length
    keep, q0, q1 = keep[long_enough], q0[long_enough], q1[long_enough]
    r0, r1, groups = merge_collinear(q0, q1, profile.tool.tolerance_mm)
    rows = np.array(
        [keep[g[np.argmax(lengths[long_enough][g])]] for g in groups], dtype=np.int64
    ).reshape(-1)
    # Merged strokes may be a little shorter than the tool allows only if a member was.
    result = order_strokes(r0, r1, profile.start_mm, options)
    first = np.where(result.reverse[:, None], r1[result.order], r0[result.order])
    last = np.where(result.reverse[:, None], r0[result.order], r1[result.order])
    strokes = np.stack([first, last], axis=1).reshape(-1, 2, 2)
    travel = tour_travel(strokes[:, 0], strokes[:, 1], np.asarray(profile.start_mm))
    stats: dict[str, Any] = {
        "input_count": len(scratches),
        "outside_count": int(len(scratches) - len(long_enough)),
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


def write_preview(toolpath: Toolpath, path: str | Path, max_px: int = 1200) -> None:
    """PNG of the board outline (grey), the cuts (black) and the travel moves (red), +y up.

    The machine's envelope is drawn in blue where it crosses the picture, so a board
    that sticks out of it shows where scratches were clipped or dropped. The start
    position (green ring) is framed too unless it lies far off the board; the travel
    legs to and from it then run off the picture.
    """
    pts = [toolpath.outline]
    if len(toolpath):
        pts.append(toolpath.strokes.reshape(-1, 2))
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    # Frame the board; take the start position in only if that does not shrink it much.
    pad = 0.05 * float((hi - lo).max())
    lo, hi = lo - pad, hi + pad
    with_start = np.minimum(lo, toolpath.start), np.maximum(hi, toolpath.start)
    if np.prod(with_start[1] - with_start[0]) <= 2.0 * np.prod(hi - lo):
        lo, hi = with_start
    span = np.maximum(hi - lo, 1e-9)
    margin = 20
    scale = (max_px - 2 * margin) / float(span.max())
    w = int(math.ceil(span[0] * scale)) + 2 * margin
    h = int(math.ceil(span[1] * scale)) + 2 * margin

    def px(p: np.ndarray) -> np.ndarray:
        q = (np.asarray(p).reshape(-1, 2) - lo) * scale
        return np.stack([q[:, 0] + margin, h - margin - q[:, 1]], axis=1)

    image = Image.new("RGB", (w, h), "white")
    draw = ImageDraw.Draw(image)
    env = toolpath.profile.envelope
    box = px(np.array([[env.x_mm[0], env.y_mm[1]], [env.x_mm[1], env.y_mm[0]]]))
    box = np.clip(box, -10.0, [w + 10.0, h + 10.0])  # edges out of the picture stay out
    draw.rectangle([tuple(box[0]), tuple(box[1])], outline=(60, 90, 220), width=2)
    ring = px(np.vstack([toolpath.outline, toolpath.outline[:1]]))
    draw.line([tuple(p) for p in ring.tolist()], fill=(150, 150, 150), width=2)
    if len(toolpath):
        start = toolpath.start[None, :]
        stops = px(np.vstack([start, toolpath.strokes[:, 1]])).tolist()
        goes = px(np.vstack([toolpath.strokes[:, 0], start])).tolist()
        for a, b in zip(stops, goes, strict=True):
            draw.line([tuple(a), tuple(b)], fill=(230, 60, 60), width=1)
        for a, b in zip(
            px(toolpath.strokes[:, 0]).tolist(), px(toolpath.strokes[:, 1]).tolist(), strict=True
        ):
            draw.line([tuple(a), tuple(b)], fill=(0, 0, 0), width=1)
    sx, sy = px(toolpath.start[None, :])[0]
    draw.ellipse([sx - 5, sy - 5, sx + 5, sy + 5], outline=(0, 120, 0), width=2)
    save_png(path, image)
