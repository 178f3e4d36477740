"""The scratch's cross-section (SPEC section 3; the supplement's eqs. 2 and 6).

A tool of full width ``2w`` and depth ``d`` cuts the dent
``z(x) = -(wbar/2) ln(1 - 4x^2/wbar^2) - d`` for ``|x| <= w``. The shape parameter
``wbar > 2w`` solves ``-(wbar/2) ln(1 - 4w^2/wbar^2) = d`` (eq. 2). All functions take
scalars or numpy arrays and compute in float64.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def _phi(s: np.ndarray) -> np.ndarray:
    """-ln(1 - s^2) / s: eq. 2 divided by w in the variable s = 2w/wbar (0 < s <= 1).

    At s = 1 (a bisection midpoint next to 1 rounds there) this is +inf, the right limit.
    """
    with np.errstate(divide="ignore"):
        return -np.log1p(-s * s) / s


def solve_wbar(width_mm: ArrayLike, depth_mm: ArrayLike) -> np.ndarray:
    """The shape parameter wbar of eq. 2 for a tool of ``width_mm`` = 2w and ``depth_mm`` = d.

    With s = 2w/wbar, eq. 2 reads phi(s) = -ln(1 - s^2)/s = d/w, and phi increases
    strictly from 0 to infinity on (0, 1). Bisection on that bracket (64 halvings reach the
    spacing of doubles on (0, 1)) gives s, and wbar = 2w/s, to machine precision.

    Args:
        width_mm: full tool width 2w (> 0), scalar or array.
        depth_mm: dent depth d (> 0), scalar or array (broadcast against width).

    Returns:
        wbar in mm, float64, with the broadcast shape (a 0-d array for scalars).
    """
    w = 0.5 * np.asarray(width_mm, dtype=np.float64)
    d = np.asarray(depth_mm, dtype=np.float64)
    w, d = np.broadcast_arrays(w, d)
    if np.any(~(w > 0)) or np.any(~(d > 0)):
        raise ValueError("width and depth must be positive")
    kappa = d / w
    lo = np.zeros_like(kappa)
    hi = np.ones_like(kappa)
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        above = _phi(mid) > kappa
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    return 2.0 * w / (0.5 * (lo + hi))


def profile_height(x: ArrayLike, wbar: ArrayLike, depth_mm: ArrayLike) -> np.ndarray:
    """Height z(x) of the dent (SPEC section 3); z(0) = -d and z(+-w) = 0."""
    x = np.asarray(x, dtype=np.float64)
    wbar = np.asarray(wbar, dtype=np.float64)
    return -0.5 * wbar * np.log1p(-4.0 * x * x / (wbar * wbar)) - np.asarray(depth_mm, np.float64)


def profile_normal(x: ArrayLike, wbar: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Unit normal n(x) = (nx, nz) of the dent (SPEC section 3)."""
    x = np.asarray(x, dtype=np.float64)
    wbar = np.asarray(wbar, dtype=np.float64)
    den = wbar * wbar + 4.0 * x * x
    return -4.0 * wbar * x / den, (wbar * wbar - 4.0 * x * x) / den


def steepest_wall_deg(width_mm: ArrayLike, depth_mm: ArrayLike) -> np.ndarray:
    """Tilt of the steepest wall (at |x| = w) from the board normal: 2 atan(2w/wbar), degrees."""
    width = np.asarray(width_mm, dtype=np.float64)
    return np.degrees(2.0 * np.arctan(width / solve_wbar(width_mm, depth_mm)))
