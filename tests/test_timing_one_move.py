"""The emulator's one-move timing in plain floats equals the ETA's numpy forms to the bit.

The GRBL emulator plans a move at a time (:func:`one_move_limits`,
:func:`one_corner_speed_sq`, :func:`one_profile_seconds`); the ETA plans whole paths
(:func:`move_limits`, :func:`corner_speed_sq`, :func:`profile_seconds`). Both are GRBL's
planner: on random moves, corners and profiles (axis-aligned ones, straight runs,
reversals, zero limits and entries above the cruise among them) each value is the same
float.
"""

from __future__ import annotations

import numpy as np

from scratchfab.toolpath.timing import (
    corner_speed_sq,
    move_limits,
    one_corner_speed_sq,
    one_move_limits,
    one_profile_seconds,
    profile_seconds,
)


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """Moves of every kind: random, on one or two axes, tiny and long."""
    d = rng.normal(size=(n, 3)) * rng.choice([1e-3, 1.0, 300.0], size=(n, 1))
    d[rng.random((n, 3)) < 0.2] = 0.0  # axes a move does not use
    d[: n // 10] = np.round(d[: n // 10], 3)  # on a 0.001 mm grid, as the G-code writes
    return d


def test_one_move_limits_is_move_limits():
    rng = np.random.default_rng(11)
    delta = _directions(rng, 3000)
    delta[0] = 0.0  # a move of no length
    for rates, accels in [
        ((2000.0, 1500.0, 600.0), (100.0, 80.0, 50.0)),
        ((500.0, 0.0, 300.0), (10.0, 0.0, 5.0)),  # a limit of 0 on an axis
    ]:
        length, unit, speed, accel = move_limits(delta, np.inf, rates, accels)
        for k, d in enumerate(delta.tolist()):
            got = one_move_limits(tuple(d), rates, accels)
            want = (length[k], tuple(unit[k].tolist()), speed[k], accel[k])
            assert got == want, (d, got, want)


def test_one_corner_speed_sq_is_corner_speed_sq():
    rng = np.random.default_rng(12)
    moves = _directions(rng, 4000)
    moves = moves[np.linalg.norm(moves, axis=1) > 0]
    units = moves / np.linalg.norm(moves, axis=1)[:, None]
    before, after = units[:-1].copy(), units[1:].copy()
    after[:50] = before[:50]  # straight on
    after[50:100] = -before[50:100]  # reversals
    after[100:150] = before[100:150] + 1e-7  # all but straight
    accels = (100.0, 80.0, 50.0)
    for deviation in (0.01, 0.0):
        want = corner_speed_sq(before, after, accels, deviation)
        for k in range(len(before)):
            b, a = tuple(before[k].tolist()), tuple(after[k].tolist())
            got = one_corner_speed_sq(b, a, accels, deviation)
            assert got == want[k], (b, a, got, want[k])


def test_one_profile_seconds_is_profile_seconds():
    rng = np.random.default_rng(13)
    n = 5000
    length = rng.choice([1e-3, 0.1, 2.0, 100.0], size=n) * rng.random(n)
    vmax = rng.uniform(1 / 60, 50.0, size=n)
    accel = rng.choice([1e-9, 10.0, 1e5], size=n)
    v0 = vmax * rng.uniform(0.0, 1.5, size=n)  # some enter faster than the cruise
    v1 = vmax * rng.uniform(0.0, 1.0, size=n)
    v0[:200], v1[200:400] = 0.0, 0.0
    want = profile_seconds(length, v0, v1, vmax, accel)
    for k in range(n):
        args = (length[k], v0[k], v1[k], vmax[k], accel[k])
        got = one_profile_seconds(*(float(a) for a in args))
        assert got == want[k], (args, got, want[k])
