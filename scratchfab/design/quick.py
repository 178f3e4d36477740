"""The quick form: a scene for people who have images but no design file yet.

Cameras stand at equal distance on a horizontal arc, symmetric about the board's
normal; the light stands above, straight in front. With camera azimuth a and light
elevation a, the half-vector at the board's centre tilts atan(sqrt(2) tan(a/2)) from
the normal and its horizontal part points along the diagonal (+-1, 1): two views then
need perpendicular scratches, which keeps them apart. The azimuth is chosen so that
this tilt uses :data:`TILT_SHARE` of the tool's steepest wall, leaving room for the
spread of half-vectors across the board. A single camera stands on the normal, and the
light at twice that tilt above it: a light closer to the camera makes the bare board's
own gloss light up the board's top edge, which only scratches turned away can darken.
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
)
from scratchfab.render.profile import steepest_wall_deg

#: Share of the steepest wall used by the half-vector at the board's centre.
TILT_SHARE = 0.65
#: Scratches per mm^2 of board for the default count (5000 on 100 x 100 mm).
COUNT_PER_MM2 = 0.5
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
    """The half-vector tilt at the board's centre the quick form aims for: TILT_SHARE of the wall."""
    return TILT_SHARE * float(steepest_wall_deg(tool.width_mm, tool.depth_mm))


def camera_azimuth_deg(tool: ScratchTool) -> float:
    """Camera azimuth (= light elevation) whose centre half-vector tilts TILT_SHARE of the wall."""
    tilt = math.radians(centre_tilt_deg(tool))
    return math.degrees(2.0 * math.atan(math.tan(tilt) / math.sqrt(2.0)))


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
    az = camera_azimuth_deg(tool)
    distance = BASE_DISTANCE_MM * max(1.0, max(width, height) / 100.0)
    if resolution is None:
        long_side = DEFAULT_RESOLUTION
        aspect = width / height
        resolution = (
            (long_side, max(8, round(long_side / aspect)))
            if aspect >= 1
            else (max(8, round(long_side * aspect)), long_side)
        )
    n = len(images)
    azimuths = np.linspace(-az, az, n) if n > 1 else np.array([0.0])
    taken: set[str] = set()
    views = []
    for path, a in zip(images, azimuths, strict=True):
        file = Path(path)
        views.append(
            {
                "name": view_name(file, taken),
                "target": str(file.resolve()),
                "azimuth_deg": float(round(a, 4)),
                "elevation_deg": 0.0,
                "distance_mm": distance,
                "fov_deg": "auto",
                "resolution": list(resolution),
            }
        )
    # One camera on the normal: the half-vector tilts half the light's elevation.
    el = math.radians(az if n > 1 else 2.0 * centre_tilt_deg(tool))
    return {
        "board": {"width_mm": board.width_mm, "height_mm": board.height_mm},
        "light": {
            "position_mm": [
                0.0,
                round(distance * math.sin(el), 4),
                round(distance * math.cos(el), 4),
            ]
        },
        "scratch": {
            "count": count if count is not None else max(1, round(COUNT_PER_MM2 * width * height))
        },
        "views": views,
    }


def quick_design(
    images: Sequence[str | Path],
    board_mm: tuple[float, float] = (100.0, 100.0),
    count: int | None = None,
    resolution: tuple[int, int] | None = None,
) -> Design:
    """A resolved design placing one view per image (see the module docstring)."""
    data = quick_mapping(images, board_mm, count, resolution)
    return design_from_mapping(data, SOURCE, Path.cwd())
