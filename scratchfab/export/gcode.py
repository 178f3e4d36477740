"""G-code for GRBL 1.1 (SPEC section 6; the GRBL facts in shared/references).

What the writer guarantees, because GRBL rejects or misreads anything else:

- units and modes first (``G21 G90 G17 G94``); a feed on the first ``G1`` and wherever
  it changes (GRBL has no default feed: error 22);
- only words GRBL 1.1 runs (no ``M6``, no ``G64``: error 20), LF line ends,
  comments without ``!``, ``?`` or ``~`` (realtime bytes, acted on even inside comments)
  and lines no longer than the profile's ``max_line_length`` (GRBL: 79, error 11);
- every coordinate, as written (rounded to ``decimals``), inside the profile's envelope,
  checked before anything is written; a stroke outside is refused by number;
- the job ends with the tool up, the spindle or servo off and the tool back at the
  start position.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scratchfab.errors import ScratchfabError
from scratchfab.fileio import write_bytes
from scratchfab.machine.profile import MachineProfile, gcode_number
from scratchfab.toolpath.inputs import initial_layout
from scratchfab.toolpath.plan import Toolpath, edge_slack, estimate_time, partial_text

_COMMENT_SAFE = re.compile(r"[^A-Za-z0-9 .,:_+=/-]")


def comment(text: str, max_length: int | None = None) -> str:
    """A ``( ... )`` comment with only harmless characters (no realtime bytes, no parens).

    Cut to ``max_length`` characters, parentheses included, where one is given: a
    comment must never make a line the controller refuses.
    """
    body = _COMMENT_SAFE.sub(" ", text).strip()
    if max_length is not None:
        body = body[: max(0, max_length - 2)].rstrip()
    return "(" + body + ")"


class _Grid:
    """Writes coordinates rounded to ``decimals``, never outside the envelope.

    A value is rounded to the nearest multiple of 10^-decimals; should that leave the
    envelope (a value within half a unit of its edge), the nearest multiple inside is
    written instead. A value further beyond the edge than the toolpath stage moves onto
    it (:func:`edge_slack`) is a bug, never clamped: it raises.
    """

    def __init__(self, profile: MachineProfile) -> None:
        self.dec = profile.gcode.decimals
        unit = 10.0 ** (-self.dec)
        env = profile.envelope
        self.bounds: dict[str, tuple[float, float]] = {}
        self.envelope = {"X": env.x_mm, "Y": env.y_mm, "Z": env.z_mm}
        self.slack = edge_slack(profile)
        for axis, (lo, hi) in self.envelope.items():
            first = math.ceil(lo / unit) - 1
            while float(gcode_number(first * unit, self.dec)) < lo:
                first += 1
            last = math.floor(hi / unit) + 1
            while float(gcode_number(last * unit, self.dec)) > hi:
                last -= 1
            if first > last:
                raise ScratchfabError(
                    f"envelope {axis.lower()}_mm {[lo, hi]} holds no value with "
                    f"{self.dec} decimals; nothing written"
                )
            self.bounds[axis] = (
                float(gcode_number(first * unit, self.dec)),
                float(gcode_number(last * unit, self.dec)),
            )

    def word(self, axis: str, value: float) -> str:
        """``axis`` and ``value`` as written, e.g. ``X-12.5``.

        Raises:
            RuntimeError: ``value`` beyond the envelope by more than the edge slack (the
                envelope check, run first, refuses any such stroke: clamped, it would
                silently move a cut).
        """
        env_lo, env_hi = self.envelope[axis]
        if not env_lo - self.slack <= value <= env_hi + self.slack:
            raise RuntimeError(
                f"internal error: G-code {axis} {value!r} lies beyond the envelope "
                f"{axis.lower()}_mm {[env_lo, env_hi]} by more than {self.slack:g} mm, "
                "which the envelope check should have refused; nothing written"
            )
        lo, hi = self.bounds[axis]
        q = round(value, self.dec)
        if q < lo:
            q = lo
        elif q > hi:
            q = hi
        return f"{axis}{gcode_number(q, self.dec)}"


def check_envelope(strokes: np.ndarray, rows: np.ndarray, profile: MachineProfile) -> None:
    """Refuse a job that leaves the envelope, before anything is written.

    The profile's own values (start, Z heights as written) are checked when it is
    loaded (:class:`~scratchfab.machine.profile.MachineProfile`).

    Raises:
        ScratchfabError: Naming the first stroke outside (1-based, cut order) and its
            scratch row.
    """
    env = profile.envelope
    pts = strokes.reshape(-1, 2)
    inside = env.contains_xy(pts)
    if not np.all(inside):
        k = int(np.flatnonzero(~inside)[0])
        s = k // 2
        x, y = pts[k]
        raise ScratchfabError(
            f"stroke {s + 1} (scratch row {int(rows[s]) + 1}) reaches ({x:g}, {y:g}), outside "
            f"machine '{profile.name}' envelope x {list(env.x_mm)}, y {list(env.y_mm)}; "
            "nothing written"
        )


#: The header comment's key for :attr:`~scratchfab.toolpath.plan.Toolpath.strokes_id`.
STROKES_ID = "toolpath strokes"
#: The header comments' key for a board the envelope cut short (:func:`partial_notes`).
PARTIAL_BOARD = "PARTIAL BOARD"
#: The header comment of a toolpath planned from the design's initial layout.
NOT_OPTIMIZED = "NOT OPTIMIZED"
_NOT_OPTIMIZED_NOTE = f"{NOT_OPTIMIZED}: from the initial layout of the design"
#: How many lines from the top :func:`read_header` reads: the header precedes any move.
HEADER_LINES = 12


@dataclass(frozen=True)
class GcodeHeader:
    """What a G-code file's header comments say (:func:`read_header`).

    Attributes:
        strokes_id: The strokes id it was exported from (:data:`STROKES_ID`), else None.
        partial: What the envelope cut off the board (:func:`partial_text`'s words, or a
            plain account where the counts were not written), else None.
        not_optimized: Planned from the design's initial layout (:data:`NOT_OPTIMIZED`).
    """

    strokes_id: str | None = None
    partial: str | None = None
    not_optimized: bool = False


def partial_notes(stats: dict[str, Any], max_length: int) -> list[str]:
    """The header comments of a board the envelope cut short; none for a whole board.

    Two comments, each whole within ``max_length`` (a count cut short would misstate it):
    where one would not fit, the bare :data:`PARTIAL_BOARD`, which :func:`read_header`
    still recognises.
    """
    if partial_text(stats) is None:
        return []
    notes = [
        f"{PARTIAL_BOARD}: {stats.get('outside_count', 0)} of {stats.get('input_count', '?')} "
        "scratches outside the envelope",
        f"{PARTIAL_BOARD}: {stats.get('clipped_count', 0)} clipped",
    ]
    return [note if len(comment(note)) <= max_length else PARTIAL_BOARD for note in notes]


# an earlier export wrote one comment: "..., N clipped" at the end of the first
_OUTSIDE = re.compile(
    rf"{PARTIAL_BOARD}: (\d+) of (\d+|\?) scratches outside the envelope(?:, (\d+) clipped)?"
)
_CLIPPED = re.compile(rf"{PARTIAL_BOARD}: (\d+) clipped")


def read_header(lines: Iterable[str]) -> GcodeHeader:
    """What the header comments of a G-code file's first lines say (:data:`HEADER_LINES`).

    Reads what :func:`gcode_lines` writes, and the single ``PARTIAL BOARD`` comment of
    earlier exports; a file without these comments (a foreign one) gives an empty header.
    """
    strokes_id: str | None = None
    partial = not_optimized = False
    stats: dict[str, Any] = {}
    for line in itertools.islice(lines, HEADER_LINES):
        text = line.strip()
        if not (text.startswith("(") and text.endswith(")")):
            continue
        body = text[1:-1].strip()
        if found := re.fullmatch(rf"{STROKES_ID} ([0-9a-f]{{16}})", body):
            strokes_id = found[1]
        not_optimized = not_optimized or body.startswith(NOT_OPTIMIZED)
        if not body.startswith(PARTIAL_BOARD):
            continue
        partial = True
        if found := _OUTSIDE.match(body):
            stats["outside_count"], stats["input_count"] = int(found[1]), found[2]
            if found[3] is not None:
                stats["clipped_count"] = int(found[3])
        if found := _CLIPPED.match(body):
            stats["clipped_count"] = int(found[1])
    if not partial:
        return GcodeHeader(strokes_id, None, not_optimized)
    # both counts, or neither: a count missing would read as 0
    counted = partial_text(stats) if {"outside_count", "clipped_count"} <= stats.keys() else None
    return GcodeHeader(
        strokes_id,
        counted or f"the envelope cut the board short (its header says {PARTIAL_BOARD})",
        not_optimized,
    )


def gcode_lines(toolpath: Toolpath, profile: MachineProfile | None = None) -> list[str]:
    """The program as lines (without line ends), after the envelope check.

    Args:
        toolpath: The ordered strokes (machine mm).
        profile: The machine: feeds, Z heights, tool control, G-code format; default the
            toolpath's own.

    Raises:
        ScratchfabError: A stroke outside the machine's envelope, or a line with a control
            character or over the profile's ``max_line_length``.
    """
    prof = profile or toolpath.profile
    check_envelope(toolpath.strokes, toolpath.source_rows, prof)
    grid = _Grid(prof)
    ctl = prof.tool_control
    feeds = prof.feeds
    stats = toolpath.stats
    limit = prof.gcode.max_line_length
    notes = [
        f"scratchfab toolpath for {prof.name}",
        f"{len(toolpath)} strokes, cut {stats.get('cut_length_mm', 0.0):.1f} mm, "
        f"travel {stats.get('travel_length_mm', 0.0):.1f} mm, "
        f"about {estimate_time(toolpath.strokes, prof) / 60:.1f} min",
        f"board top edge, design +y, faces machine {prof.board_top()}",
        f"{STROKES_ID} {toolpath.strokes_id}",
    ]
    notes += partial_notes(stats, limit)
    if initial_layout(toolpath) is not None:
        fits = len(comment(_NOT_OPTIMIZED_NOTE)) <= limit
        notes.append(_NOT_OPTIMIZED_NOTE if fits else NOT_OPTIMIZED)
    lines = ["G21 G90 G17 G94", *(comment(text, limit) for text in notes)]
    modal_feed: list[float | None] = [None]

    def xy(p: np.ndarray) -> str:
        return f"{grid.word('X', p[0])} {grid.word('Y', p[1])}"

    def feed_move(words: str, feed: float) -> str:
        if modal_feed[0] != feed:
            modal_feed[0] = feed
            return f"G1 {words} F{gcode_number(feed, 1)}"
        return f"G1 {words}"

    def dwell() -> list[str]:
        return [f"G4 P{gcode_number(ctl.dwell_s, 3)}"] if ctl.dwell_s > 0 else []

    def travel(p: np.ndarray) -> str:
        if feeds.travel_mm_min is None:
            return f"G0 {xy(p)}"
        return feed_move(xy(p), feeds.travel_mm_min)

    # a servo lifts the tool: no Z is written, and its profile's unused heights are unchecked
    safe = "" if ctl.mode == "servo" else f"G0 {grid.word('Z', prof.z.safe_mm)}"
    start = np.asarray(prof.start_mm, dtype=np.float64)
    if ctl.mode == "servo":
        lines += [ctl.command("off"), *dwell()]
    else:
        lines.append(safe)
        if ctl.mode == "spindle":
            lines += [ctl.command("on"), *dwell()]
    lines.append(travel(start))
    for a, b in toolpath.strokes:
        lines.append(travel(a))
        if ctl.mode == "servo":
            lines += [ctl.command("on"), *dwell()]
        else:
            lines.append(feed_move(grid.word("Z", prof.z.engrave_mm), feeds.plunge_mm_min))
        lines.append(feed_move(xy(b), feeds.engrave_mm_min))
        if ctl.mode == "servo":
            lines += [ctl.command("off"), *dwell()]
        else:
            lines.append(safe)
    if ctl.mode != "servo":
        lines.append(ctl.command("off") if ctl.mode == "spindle" else "M5")
    lines += [travel(start), "M2"]
    for number, line in enumerate(lines, start=1):
        if not all(" " <= c <= "~" for c in line):  # a control or realtime byte acts at once
            raise ScratchfabError(f"G-code line {number} holds a control character: {line!r}")
        if len(line) > limit:
            raise ScratchfabError(
                f"G-code line {number} is {len(line)} characters, over the machine's "
                f"max_line_length {limit}: {line[:40]}...; nothing written"
            )
    return lines


def gcode_stats(lines: list[str], dec: int | None = None) -> dict[str, Any]:
    """Line count, bytes, longest line and the bounding box of the X/Y/Z words.

    Args:
        lines: The program's lines, without line ends.
        dec: The coordinate decimals it was written with (recorded; None when unknown).
    """
    text_bytes = sum(len(line) + 1 for line in lines)
    axes: dict[str, list[float]] = {"X": [], "Y": [], "Z": []}
    for line in lines:
        if line.startswith("("):
            continue
        for word in line.split():
            if word[0] in axes:
                axes[word[0]].append(float(word[1:]))
    bbox = {f"{axis.lower()}_mm": [min(v), max(v)] if v else None for axis, v in axes.items()}
    return {
        "lines": len(lines),
        "bytes": text_bytes,
        "max_line_length": max((len(line) for line in lines), default=0),
        "bbox": bbox,
        "decimals": dec,
    }


def gcode_text(toolpath: Toolpath, profile: MachineProfile | None = None) -> str:
    """:func:`gcode_lines` as the file's text (LF line ends, ASCII)."""
    return _file_text(gcode_lines(toolpath, profile))


def _file_text(lines: list[str]) -> str:
    """The G-code file's text of its lines: the one place that joins them."""
    return "\n".join(lines) + "\n"


def write_gcode(
    toolpath: Toolpath, profile: MachineProfile | None, path: str | Path
) -> dict[str, Any]:
    """Write the G-code file atomically; returns :func:`gcode_stats` of what was written.

    Raises:
        ScratchfabError: As :func:`gcode_lines`; nothing is written.
    """
    prof = profile or toolpath.profile
    lines = gcode_lines(toolpath, prof)
    write_bytes(path, _file_text(lines).encode("ascii"))
    return gcode_stats(lines, prof.gcode.decimals)
