"""Machining time with acceleration, as GRBL 1.1's planner runs a job.

A move of length L at cruise speed v with acceleration a, from rest to rest, takes
L/v + v/a when it reaches v (L >= v^2/a), else 2 sqrt(L/a) (a triangular profile). Like
GRBL, speed and acceleration along a direction u are the largest that keep every axis
within its own limit: v = min(feed, min_i rate_i/|u_i|), a = min_i accel_i/|u_i|.

GRBL does not stop between consecutive moves unless a command empties its planner (a
spindle or servo M3/M5, a G4 dwell): it passes a corner at up to the speed whose
centripetal acceleration over a circle that deviates ``$11`` mm from the corner stays
within the acceleration along the corner's bisector,
v^2 = a_j $11 sin(t/2) / (1 - sin(t/2)), t the angle between the moves; not faster
than either move's own speed, and no faster than it can still stop at the end of the
path. :func:`path_times` plans that way (whole-path look-ahead; GRBL sees 15 moves,
which makes no difference where corners come every move or two, as in a scratch job).
"""

from __future__ import annotations

import numpy as np

#: GRBL's default junction deviation ``$11`` (mm): a profile's ``[motion]`` default.
GRBL_JUNCTION_DEVIATION_MM = 0.01
#: Beyond this |cos| a corner counts as a straight line (no limit) or a reversal (a stop).
_STRAIGHT_COS = 0.999999


def _limits(
    d: np.ndarray,
    feed_mm_min: np.ndarray | float,
    max_rate_mm_min: tuple[float, float, float],
    acceleration_mm_s2: tuple[float, float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Length, unit vector, cruise speed (mm/s) and acceleration of each move."""
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
    return length, unit, speed, accel


def path_times(
    delta: np.ndarray,
    feed_mm_min: np.ndarray | float,
    max_rate_mm_min: tuple[float, float, float],
    acceleration_mm_s2: tuple[float, float, float],
    rest_before: np.ndarray | None = None,
    junction_deviation_mm: float = GRBL_JUNCTION_DEVIATION_MM,
) -> np.ndarray:
    """Seconds for each move of a path the planner joins wherever nothing stops it.

    The path starts and ends at rest. Moves of no length take no time and join nothing
    (GRBL drops them); a rest before one holds for the next move.

    Args:
        delta: (N, 3) move vectors in mm (X, Y, Z), in order.
        feed_mm_min: (N,) or scalar programmed feed; ``inf`` for a rapid (G0) move.
        max_rate_mm_min: Per-axis maximum rates (GRBL $110-$112).
        acceleration_mm_s2: Per-axis accelerations (GRBL $120-$122).
        rest_before: (N,) bool, True where the machine stops before the move (a command
            that empties the planner comes first); None: only the first.
        junction_deviation_mm: GRBL's ``$11``; 0 stops at every corner.
    """
    d = np.asarray(delta, dtype=np.float64).reshape(-1, 3)
    length, unit, speed, accel = _limits(d, feed_mm_min, max_rate_mm_min, acceleration_mm_s2)
    t = np.zeros_like(length)
    kept = np.flatnonzero(length > 0)
    if len(kept) == 0:
        return t
    rests = np.zeros(len(d), dtype=np.int64) if rest_before is None else np.asarray(rest_before)
    count = np.cumsum(rests)
    rest = np.diff(np.concatenate([[0], count[kept]])) > 0
    rest[0] = True
    L, u, v, a = length[kept], unit[kept], speed[kept], accel[kept]
    # The fastest each move may be entered: its corner with the move before, both cruise speeds.
    cos = -np.einsum("ij,ij->i", u[:-1], u[1:])
    bisector = u[1:] - u[:-1]
    norm = np.sqrt((bisector * bisector).sum(axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        comp = np.abs(bisector / norm[:, None])
        a_corner = np.min(np.asarray(acceleration_mm_s2) / comp, axis=1)
        half = np.sqrt(np.clip(0.5 * (1.0 - cos), 0.0, 1.0))
        corner_sq = a_corner * junction_deviation_mm * half / (1.0 - half)
    corner_sq = np.where(
        cos < -_STRAIGHT_COS, np.inf, np.where(cos > _STRAIGHT_COS, 0.0, corner_sq)
    )
    entry_max = np.zeros(len(L))
    entry_max[1:] = np.minimum(corner_sq, np.minimum(v[1:], v[:-1]) ** 2)
    entry_max[rest] = 0.0
    # Backward pass (each entry low enough to stop in time, the path ending at rest), then
    # forward (reachable from the entry before): as cumulative minima over the running sum
    # of 2 a L, the speed^2 each move can add.
    gain = np.concatenate([[0.0], np.cumsum(2.0 * a * L)])
    back = np.minimum.accumulate(np.append(entry_max + gain[:-1], gain[-1])[::-1])[::-1]
    entry = back[:-1] - gain[:-1]
    entry = np.minimum.accumulate(entry - gain[:-1]) + gain[:-1]
    entry_sq = np.clip(entry, 0.0, None)
    v0 = np.sqrt(entry_sq)
    v1 = np.append(v0[1:], 0.0)
    t[kept] = _profile_times(L, v0, v1, v, a)
    return t


def _profile_times(
    length: np.ndarray, v0: np.ndarray, v1: np.ndarray, vmax: np.ndarray, accel: np.ndarray
) -> np.ndarray:
    """Seconds over moves entered at ``v0``, left at ``v1``, cruising at most ``vmax``."""
    up = (vmax * vmax - v0 * v0) / (2.0 * accel)
    down = (vmax * vmax - v1 * v1) / (2.0 * accel)
    cruise = length - up - down
    peak = np.sqrt(np.maximum(accel * length + 0.5 * (v0 * v0 + v1 * v1), 0.0))
    peak = np.minimum(peak, vmax)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(
            cruise >= 0,
            (2.0 * vmax - v0 - v1) / accel + cruise / vmax,
            (2.0 * peak - v0 - v1) / accel,
        )
