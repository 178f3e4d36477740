"""The quick form: a scene for people who have images but no design file yet.

Cameras stand at equal distance around the board's normal; the light stands above,
straight in front. Every view's half-vector at the board's centre tilts alike, leaving
room for the spread of half-vectors across the board, its horizontal part turned in
equal steps from the diagonal (-1, 1) for the first image to (1, 1) for the last, and
each camera stands at the light's mirror image about its half-vector. Two views then
need perpendicular scratches, which keeps them apart; their cameras stand on a
horizontal arc at azimuths -+a with the light at elevation a, a = 2 atan(tan(T) /
sqrt 2) for T = :data:`TILT_SHARE` of the tool's steepest wall, and their half-vectors
tilt atan(tan(a) / sqrt 2) (14.9 deg for the default tool, a little above T = 14.4:
an exact T measured 1.1 dB lower on the demo's two pictures). Views between them stand
higher than the arc: on it, a middle view's half-vector would tilt less (10.3 deg with
three views), nearer the bare board's own gloss and its neighbours'. A single camera
stands on the normal, and the light at twice T above it: a light closer to the camera
makes the bare board's gloss light up the board's top edge, which only scratches
turned away can darken.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from scratchfab.errors import ConfigError
from scratchfab.model.design import (
    RESERVED_NAME_RE,
    Board,
    Design,
    ScratchTool,
    design_from_mapping,
    polar_from_position,
)
from scratchfab.render.profile import steepest_wall_deg

#: Share of the steepest wall the half-vector at the board's centre tilts for one view
#: (two or more: a little more, the module's docstring).
TILT_SHARE = 0.65
#: Scratches per mm^2 of board for the default count (5000 on 100 x 100 mm).
COUNT_PER_MM2 = 0.5
#: The default count's most: 0.5 per mm^2 up to about 630 x 630 mm. Fewer cost image
#: quality, since the views' pixels do not grow with the board (600 x 600 mm, two views,
#: 40 steps: 20000 scratches 13 dB, 60000 20 dB, 180000 28 dB, as 100 x 100 mm's 5000 reach
#: 22-25), and more cost time (180000: 25 s to lay, 2.5 s a step on one thread; both grow
#: with the count; a 10 m board's 50 million would pass scratch.count's most).
COUNT_CAP = 200_000
#: Camera and light distance for boards up to 100 mm; larger boards scale it.
BASE_DISTANCE_MM = 500.0
#: Quick-form camera resolution (pixels along the long side).
DEFAULT_RESOLUTION = 128
#: The quick form's :attr:`Design.source`, which its messages start with (the user wrote
#: no design file to name).
SOURCE = "quick form"


def view_name(path: Path, taken: set[str]) -> str:
    """A file-name-safe view name from an image's file name, unique ignoring case.

    ``taken`` holds the names given so far, in lower case (a case-insensitive disk keeps
    one file for ``Left`` and ``left``); a Windows device name (``nul``, ``com1``) gets
    a ``view_`` prefix.
    """
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", path.stem).strip("._-") or "view"
    if RESERVED_NAME_RE.match(stem):
        stem = f"view_{stem}"
    name, i = stem, 2
    while name.lower() in taken:
        name = f"{stem}_{i}"
        i += 1
    taken.add(name.lower())
    return name


def centre_tilt_deg(tool: ScratchTool) -> float:
    """TILT_SHARE of the tool's steepest wall (degrees), from which the quick form's tilts follow."""
    return TILT_SHARE * float(steepest_wall_deg(tool.width_mm, tool.depth_mm))


def placement(tool: ScratchTool, n: int) -> tuple[float, list[tuple[float, float]]]:
    """The light's elevation and each camera's (azimuth, elevation), in degrees, for n views.

    Each view's half-vector at the board's centre tilts alike, its horizontal part at
    90 deg from +x for one view, else in equal steps from 135 deg (the first, on the
    left) to 45 deg; each camera is the light's mirror image about it.
    """
    t = math.radians(centre_tilt_deg(tool))
    if n == 1:
        el, tilt = 2.0 * t, t
    else:  # the end cameras on the horizontal arc at azimuth -+el
        el = 2.0 * math.atan(math.tan(t) / math.sqrt(2.0))
        tilt = math.atan(math.tan(el) / math.sqrt(2.0))
    light = np.array([0.0, math.sin(el), math.cos(el)])
    phi = np.radians([90.0] if n == 1 else np.linspace(135.0, 45.0, n))
    h = np.stack(
        [math.sin(tilt) * np.cos(phi), math.sin(tilt) * np.sin(phi), np.full(n, math.cos(tilt))],
        axis=1,
    )
    cameras = 2.0 * (h @ light)[:, None] * h - light
    polar = [polar_from_position((float(x), float(y), float(z))) for x, y, z in cameras]
    return math.degrees(el), [(az, up) for az, up, _ in polar]


def default_count(board_mm: tuple[float, float]) -> int:
    """The quick form's scratch count without --count: COUNT_PER_MM2 of the board, at most COUNT_CAP."""
    return min(COUNT_CAP, _count_for_area(board_mm))


def count_note(board_mm: tuple[float, float]) -> str | None:
    """The line saying the default count was capped on this board, and how to ask for more."""
    wanted = _count_for_area(board_mm)
    if wanted <= COUNT_CAP:
        return None
    width, height = board_mm
    return (
        f"{SOURCE}: {COUNT_CAP} scratches, the default's most ({COUNT_PER_MM2:g} per mm^2 "
        f"would be {wanted} on a {width:g} x {height:g} mm board: more show the images "
        f"better but take longer to lay and to optimize); give --count {wanted} for all of them"
    )


def _count_for_area(board_mm: tuple[float, float]) -> int:
    """COUNT_PER_MM2 scratches on the board's area (at least 1)."""
    return max(1, round(COUNT_PER_MM2 * board_mm[0] * board_mm[1]))


def quick_mapping(
    images: Sequence[str | Path],
    board_mm: tuple[float, float] = (100.0, 100.0),
    count: int | None = None,
    resolution: tuple[int, int] | None = None,
) -> dict[str, Any]:
    """The design tables (TOML-ready) of the quick form for these images."""
    if not images:
        raise ConfigError("quick form: give at least one image")
    width, height = board_mm
    try:
        board = Board(width_mm=width, height_mm=height)
    except ValueError as exc:
        raise ConfigError(f"quick form: board {width:g} x {height:g} mm: {exc}") from None
    tool = ScratchTool()
    light_deg, cameras = placement(tool, len(images))
    distance = BASE_DISTANCE_MM * max(1.0, max(width, height) / 100.0)
    if resolution is None:
        long_side = DEFAULT_RESOLUTION
        aspect = width / height
        resolution = (
            (long_side, max(8, round(long_side / aspect)))
            if aspect >= 1
            else (max(8, round(long_side * aspect)), long_side)
        )
    taken: set[str] = set()
    views = []
    for path, (az, up) in zip(images, cameras, strict=True):
        file = Path(path)
        views.append(
            {
                "name": view_name(file, taken),
                "target": str(file.resolve()),
                "azimuth_deg": round(az, 4) + 0.0,  # + 0.0: no -0.0 in the file
                "elevation_deg": round(up, 4) + 0.0,
                "distance_mm": distance,
                "fov_deg": "auto",
                "resolution": list(resolution),
            }
        )
    el = math.radians(light_deg)
    return {
        "board": {"width_mm": board.width_mm, "height_mm": board.height_mm},
        "light": {
            "position_mm": [
                0.0,
                round(distance * math.sin(el), 4),
                round(distance * math.cos(el), 4),
            ]
        },
        "scratch": {"count": count if count is not None else default_count((width, height))},
        "views": views,
    }


def quick_design(
    images: Sequence[str | Path],
    board_mm: tuple[float, float] = (100.0, 100.0),
    count: int | None = None,
    resolution: tuple[int, int] | None = None,
) -> Design:
    """A resolved design placing one view per image (see the module docstring).

    Raises:
        ConfigError: ``images`` is one path rather than a list of them, or a value is bad.
    """
    if isinstance(images, str | Path):
        raise ConfigError(
            f"{SOURCE}: images: expected a list of image paths, one per view, got the single "
            f"path {str(images)!r} (pass [{str(images)!r}])"
        )
    data = quick_mapping(images, board_mm, count, resolution)
    return design_from_mapping(data, SOURCE, Path.cwd())
