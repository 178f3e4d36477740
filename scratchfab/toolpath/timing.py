"""Machining time with acceleration: each move is a trapezoidal velocity profile.

Every move of a scratch job starts and ends at rest (a cut is followed by a lift, a
servo or spindle command waits for the planner), so a move of length L at cruise speed v
with acceleration a takes L/v + v/a when it reaches v (L >= v^2/a), else 2 sqrt(L/a)
(a triangular profile). Like GRBL, speed and acceleration along a direction u are the
largest that keep every axis within its own limit: v = min(feed, min_i rate_i/|u_i|),
a = min_i accel_i/|u_i|.
"""

from __future__ import annotations

import numpy as np


def move_times(
    delta: np.ndarray,
    feed_mm_min: np.ndarray | float,
    max_rate_mm_min: tuple[float, float, float],
    acceleration_mm_s2: tuple[float, float, float],
) -> np.ndarray:
    """Seconds for each rest-to-rest move.

    Args:
        delta: (N, 3) move vectors in mm (X, Y, Z).
        feed_mm_min: (N,) or scalar programmed feed; ``inf`` for a rapid (G0) move.
        max_rate_mm_min: Per-axis maximum rates (GRBL $110-$112).
        acceleration_mm_s2: Per-axis accelerations (GRBL $120-$122).
    """
    d = np.asarray(delta, dtype=np.float64).reshape(-1, 3)
    length = np.sqrt((d * d).sum(axis=1))
    moving = length > 0
    unit = np.zeros_like(d)
    unit[moving] = d[moving] / length[moving, None]
    comp = np.abs(unit)
    with np.errstate(divide="ignore"):
        rate_limit = np.min(np.asarray(max_rate_mm_min) / 60.0 / comp, axis=1)
        accel = np.min(np.asarray(acceleration_mm_s2) / comp, axis=1)
    speed = np.minimum(
        np.broadcast_to(np.asarray(feed_mm_min, dtype=np.float64) / 60.0, length.shape), rate_limit
    )
    t = np.zeros_like(length)
    s, a, L = speed[moving], accel[moving], length[moving]
    reaches = L >= s * s / a
    t[moving] = np.where(reaches, L / s + s / a, 2.0 * np.sqrt(L / a))
    return t


def trapezoid_time(length: float, speed: float, accel: float) -> float:
    """Seconds to move ``length`` mm from rest to rest at cruise ``speed`` mm/s, ``accel`` mm/s^2."""
    if length <= 0:
        return 0.0
    if length >= speed * speed / accel:
        return length / speed + speed / accel
    return 2.0 * float(np.sqrt(length / accel))
