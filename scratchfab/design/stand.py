"""Where to stand and where to put the light, in words a person follows at the board.

Angles are from the board's front (its normal, +z) with its top edge up (+y);
distances from its centre. ``design`` prints these lines and ``run``'s report.html
shows them under "Where to stand".
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scratchfab.model.design import Design, Vec3, View, polar_from_position

#: How :func:`stand_text` names the camera's reference direction.
FRONT = "the board’s front"
#: How :func:`stand_text` names the light's.
BOARD = "the board"


def side(azimuth: float) -> str:
    """``straight in front`` or ``22° to the left``: where an azimuth (degrees) lies."""
    if round(abs(azimuth)) == 0:
        return "straight in front"
    return f"{abs(azimuth):.0f}° to the {'left' if azimuth < 0 else 'right'}"


def place(position: Vec3 | Sequence[float] | np.ndarray, subject: str) -> str:
    """``22° to the left of the board's front, level with its centre, 50 cm away``.

    Args:
        position: A point in board coordinates (mm), the board's centre at the origin.
        subject: What the side is reckoned from (:data:`FRONT`, :data:`BOARD`); straight
            ahead it is always "the board", since "straight in front of the board's
            front" would say the front twice.
    """
    x, y, z = (float(v) for v in position)
    azimuth, elevation, distance = polar_from_position((x, y, z))
    parts = [f"{side(azimuth)} of {BOARD if round(abs(azimuth)) == 0 else subject}"]
    if round(abs(elevation)) == 0:
        parts.append("level with its centre")
    else:
        parts.append(f"{abs(elevation):.0f}° {'above' if elevation > 0 else 'below'} its centre")
    parts.append(f"{distance / 10:.0f} cm away")
    return ", ".join(parts)


def stand_text(design: Design, view: View, light: bool = True) -> str:
    """One resolved view's place and (with ``light``) its light's, as report.html words it.

    ``stand 22° to the left of the board’s front, level with its centre, 50 cm away;
    light straight in front of the board, 22° above its centre, 50 cm away``
    """
    text = f"stand {place(view.camera_position, FRONT)}"
    return f"{text}; light {place(design.light_for(view), BOARD)}" if light else text


def stand_lines(design: Design) -> list[str]:
    """What ``design`` prints at its end: a heading, one line per view, and the light's.

    When every view shares one light it gets a line of its own; otherwise each view's
    line names its own light as :func:`stand_text` does.
    """
    lights = {tuple(design.light_for(view).tolist()) for view in design.views}
    lines = [
        f"where to stand (angles from {FRONT}, its normal, with its top edge up; "
        "distances from its centre):"
    ]
    for view in design.views:
        lines.append(f"  {view.name}: {stand_text(design, view, light=len(lights) > 1)}")
    if len(lights) == 1:
        # "the light", not "light": a view may be named "light" (from light.png)
        lines.append(f"  the light: {place(next(iter(lights)), BOARD)}")
    return lines
