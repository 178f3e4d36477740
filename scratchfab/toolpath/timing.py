"""Machining time with acceleration, as GRBL 1.1's planner runs a job.

A move of length L at cruise speed v with acceleration a, from rest to rest, takes
L/v + v/a when it reaches v (L >= v^2/a), else 2 sqrt(L/a) (a triangular profile). Like
GRBL, speed and acceleration along a direction u are the largest that keep every axis
within its own limit: v = min(feed, min_i rate_i/|u_i|), a = min_i accel_i/|u_i|
(:func:`move_limits`).

GRBL does not stop between consecutive moves unless a command empties its planner (a
spindle or servo M3/M5, a G4 dwell): it passes a corner at up to the speed whose
centripetal acceleration over a circle that deviates ``$11`` mm from the corner stays
within the acceleration along the corner's bisector,
v^2 = a_j $11 sin(t/2) / (1 - sin(t/2)), t the angle between the moves
(:func:`corner_speed_sq`); not faster than either move's own speed, and no faster than it
can still stop at the end of what it has planned. :func:`path_times` plans a whole path
that way (whole-path look-ahead; GRBL sees 15 moves, which makes no difference where
corners come every move or two, as in a scratch job). The GRBL emulator
(:mod:`scratchfab.machine.grblsim`) plans over the blocks its planner holds with the same
pieces, a move at a time in plain floats (:func:`one_move_limits`,
:func:`one_corner_speed_sq`, :func:`exit_speed_sq`, :func:`one_profile_seconds`,
:func:`profile_at`), each equal to its numpy form to the bit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

#: GRBL's default junction deviation ``$11`` (mm): a profile's ``[motion]`` default.
GRBL_JUNCTION_DEVIATION_MM = 0.01
#: Beyond this |cos| a corner counts as a straight line (no limit) or a reversal (a stop).
_STRAIGHT_COS = 0.999999


def move_limits(
    delta: np.ndarray,
    feed_mm_min: np.ndarray | float,
    max_rate_mm_min: Sequence[float],
    acceleration_mm_s2: Sequence[float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Length (mm), unit vector, cruise speed (mm/s) and acceleration (mm/s^2) of each move.

    Args:
        delta: (N, 3) move vectors in mm.
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
    # An axis the move does not use limits nothing (GRBL skips it), even at a limit of 0.
    with np.errstate(divide="ignore", invalid="ignore"):
        rate_limit = np.min(
            np.where(comp > 0, np.asarray(max_rate_mm_min) / 60.0 / comp, np.inf), axis=1
        )
        accel = np.min(np.where(comp > 0, np.asarray(acceleration_mm_s2) / comp, np.inf), axis=1)
    speed = np.minimum(
        np.broadcast_to(np.asarray(feed_mm_min, dtype=np.float64) / 60.0, length.shape), rate_limit
    )
    return length, unit, speed, accel


Vector3 = tuple[float, float, float]


def _axis_limit(comp: Vector3, limits: Sequence[float]) -> float:
    """The least ``limit / comp`` over the axes a direction uses (``inf``: none)."""
    return min((lim / c for c, lim in zip(comp, limits, strict=True) if c > 0), default=math.inf)


def one_move_limits(
    delta: Vector3, max_rate_mm_min: Sequence[float], acceleration_mm_s2: Sequence[float]
) -> tuple[float, Vector3, float, float]:
    """:func:`move_limits` of one rapid move in plain floats, equal to it to the bit.

    The GRBL emulator plans a move at a time, where numpy's per-call cost is most of the
    work. Returns length (mm), unit vector, the fastest speed (mm/s) and acceleration.
    """
    dx, dy, dz = delta
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    unit = (dx / length, dy / length, dz / length) if length > 0 else (0.0, 0.0, 0.0)
    comp = (abs(unit[0]), abs(unit[1]), abs(unit[2]))
    rates = [r / 60.0 for r in max_rate_mm_min]
    return length, unit, _axis_limit(comp, rates), _axis_limit(comp, acceleration_mm_s2)


def one_corner_speed_sq(
    before: Vector3,
    after: Vector3,
    acceleration_mm_s2: Sequence[float],
    junction_deviation_mm: float,
) -> float:
    """:func:`corner_speed_sq` of one corner in plain floats, equal to it to the bit."""
    cos = -(before[0] * after[0] + before[1] * after[1] + before[2] * after[2])
    if cos < -_STRAIGHT_COS:
        return math.inf
    if cos > _STRAIGHT_COS:
        return 0.0
    bx, by, bz = after[0] - before[0], after[1] - before[1], after[2] - before[2]
    norm = math.sqrt(bx * bx + by * by + bz * bz)
    a_corner = _axis_limit((abs(bx / norm), abs(by / norm), abs(bz / norm)), acceleration_mm_s2)
    half = math.sqrt(min(max(0.5 * (1.0 - cos), 0.0), 1.0))
    return a_corner * junction_deviation_mm * half / (1.0 - half)


def corner_speed_sq(
    before: ArrayLike,
    after: ArrayLike,
    acceleration_mm_s2: Sequence[float],
    junction_deviation_mm: float,
) -> np.ndarray:
    """The fastest speed^2 through each corner from unit vector ``before`` to ``after``.

    GRBL's junction deviation: ``inf`` for a straight continuation, 0 for a reversal.

    Args:
        before: (N, 3) unit vectors of the moves into the corners.
        after: (N, 3) unit vectors of the moves out of them.
        acceleration_mm_s2: Per-axis accelerations (GRBL $120-$122).
        junction_deviation_mm: GRBL's ``$11``; 0 stops at every corner.
    """
    u0 = np.asarray(before, dtype=np.float64).reshape(-1, 3)
    u1 = np.asarray(after, dtype=np.float64).reshape(-1, 3)
    # Summed in order, as :func:`one_corner_speed_sq` does (einsum's order is the CPU's).
    cos = -(u0[:, 0] * u1[:, 0] + u0[:, 1] * u1[:, 1] + u0[:, 2] * u1[:, 2])
    bisector = u1 - u0
    norm = np.sqrt((bisector * bisector).sum(axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        comp = np.abs(bisector / norm[:, None])
        a_corner = np.min(np.where(comp > 0, np.asarray(acceleration_mm_s2) / comp, np.inf), axis=1)
        half = np.sqrt(np.clip(0.5 * (1.0 - cos), 0.0, 1.0))
        corner_sq = a_corner * junction_deviation_mm * half / (1.0 - half)
    return np.where(cos < -_STRAIGHT_COS, np.inf, np.where(cos > _STRAIGHT_COS, 0.0, corner_sq))


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
    length, unit, speed, accel = move_limits(d, feed_mm_min, max_rate_mm_min, acceleration_mm_s2)
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
    corner_sq = corner_speed_sq(u[:-1], u[1:], acceleration_mm_s2, junction_deviation_mm)
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
    t[kept] = profile_seconds(L, v0, v1, v, a)
    return t


def exit_speed_sq(entry_sq: float, gain: float, later: Sequence[tuple[float, float]]) -> float:
    """Speed^2 leaving a move, as GRBL's planner sets it over the moves queued behind it.

    No more than the move can reach from its entry, and low enough that every later move
    can still slow down for its own entry limit and the last one stop at its end (GRBL's
    newest block always ends at rest): the backward and forward passes of
    :func:`path_times`, seen from the first move.

    Args:
        entry_sq: Speed^2 entering the move.
        gain: 2 a L of the move (the speed^2 it can add or shed).
        later: ``(entry_max_sq, gain)`` of each move queued behind it, in order; an entry
            limit of 0 stops the machine there.
    """
    best = entry_sq + gain
    shed = 0.0  # speed^2 the later moves can shed before the one at hand
    for entry_max, g in later:
        best = min(best, entry_max + shed)
        shed += g
    return min(best, shed)


def profile_seconds(
    length: np.ndarray | float,
    v0: np.ndarray | float,
    v1: np.ndarray | float,
    vmax: np.ndarray | float,
    accel: np.ndarray | float,
) -> np.ndarray:
    """Seconds over moves entered at ``v0``, left at ``v1``, cruising at most ``vmax``.

    A move entered faster than ``vmax`` (a lowered override) first slows down to it at
    ``accel``; ``v1`` is at most ``vmax``. GRBL's deceleration-only profile (a feed hold)
    is ``vmax = v0``.
    """
    up = np.abs(vmax * vmax - v0 * v0) / (2.0 * accel)
    down = (vmax * vmax - v1 * v1) / (2.0 * accel)
    cruise = length - up - down
    peak = np.sqrt(np.maximum(accel * length + 0.5 * (v0 * v0 + v1 * v1), 0.0))
    peak = np.where(v0 > vmax, v0, np.minimum(peak, vmax))  # from above: only down
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(
            cruise >= 0,
            (2.0 * vmax - v0 - v1 + 2.0 * np.maximum(v0 - vmax, 0.0)) / accel + cruise / vmax,
            (2.0 * peak - v0 - v1) / accel,
        )


def one_profile_seconds(length: float, v0: float, v1: float, vmax: float, accel: float) -> float:
    """:func:`profile_seconds` of one move in plain floats, equal to it to the bit.

    ``vmax`` and ``accel`` positive (the emulator's cruise is at least 1 mm/min).
    """
    up = abs(vmax * vmax - v0 * v0) / (2.0 * accel)
    down = (vmax * vmax - v1 * v1) / (2.0 * accel)
    cruise = length - up - down
    if cruise >= 0:
        return (2.0 * vmax - v0 - v1 + 2.0 * max(v0 - vmax, 0.0)) / accel + cruise / vmax
    peak = math.sqrt(max(accel * length + 0.5 * (v0 * v0 + v1 * v1), 0.0))
    peak = v0 if v0 > vmax else min(peak, vmax)
    return (2.0 * peak - v0 - v1) / accel


def profile_at(
    elapsed: float, length: float, v0: float, v1: float, vmax: float, accel: float
) -> tuple[float, float]:
    """Distance (mm) and speed (mm/s) ``elapsed`` seconds into one move's profile.

    The profile of :func:`profile_seconds`: from ``v0`` to ``vmax`` at ``accel`` (up, or
    down from a ``v0`` above it), cruising, down to ``v1`` at the end (a trapezoid, or a
    triangle on a short move).
    """
    up = abs(vmax * vmax - v0 * v0) / (2.0 * accel)
    down = (vmax * vmax - v1 * v1) / (2.0 * accel)
    if up + down <= length:
        peak, cruise_s = vmax, (length - up - down) / vmax
    else:
        peak = math.sqrt(max(accel * length + 0.5 * (v0 * v0 + v1 * v1), 0.0))
        peak, cruise_s = max(peak, v0, v1), 0.0
    ramp = accel if peak >= v0 else -accel  # the first ramp: up, or down to the cruise
    rise = (peak - v0) / ramp
    if elapsed <= rise:
        return min(v0 * elapsed + 0.5 * ramp * elapsed * elapsed, length), v0 + ramp * elapsed
    done = (v0 + peak) * 0.5 * rise
    if elapsed <= rise + cruise_s:
        return min(done + peak * (elapsed - rise), length), peak
    fall = min(elapsed - rise - cruise_s, (peak - v1) / accel)
    done += peak * cruise_s + peak * fall - 0.5 * accel * fall * fall
    return min(done, length), peak - accel * fall
