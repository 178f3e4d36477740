"""The dent's shape parameter wbar, solved independently of the analytic renderer.

The profile of SPEC section 3 (the supplement's eq. 2) fixes wbar > 2w by
-(wbar/2) ln(1 - 4w^2/wbar^2) = d. With y = -ln(1 - 4w^2/wbar^2) > 0 and k = d/w this
reads H(y) = y - k sqrt(1 - e^-y) = 0. H is convex with H(0) = 0, negative up to the
root and positive beyond it, and both k and k^2 lie right of the root, so Newton's method
started at min(k, k^2) descends to the root monotonically. This is deliberately another
method than the analytic renderer's bisection; the tests check that both agree.
"""

from __future__ import annotations

import numpy as np

#: Newton steps at most (quadratic convergence needs a handful).
MAX_STEPS = 100


def solve_wbar(width: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Shape parameters wbar (mm) of dents with full widths ``width`` = 2w and depths d.

    Args:
        width: Full dent widths 2w in mm, positive.
        depth: Dent depths d in mm, positive.

    Returns:
        wbar in mm (float64, broadcast shape) with -(wbar/2) ln(1 - 4w^2/wbar^2) = d.
    """
    w = 0.5 * np.asarray(width, dtype=np.float64)
    d = np.asarray(depth, dtype=np.float64)
    w, d = np.broadcast_arrays(w, d)
    k = d / w
    y = np.minimum(k, k * k)
    for _ in range(MAX_STEPS):
        one_minus = -np.expm1(-y)
        root = np.sqrt(one_minus)
        h = y - k * root
        dh = 1.0 - k * np.exp(-y) / (2.0 * root)
        step = h / dh
        y = y - step
        if np.all(np.abs(step) <= 1e-15 * y):
            break
    return 2.0 * w / np.sqrt(-np.expm1(-y))
