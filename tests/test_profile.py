from __future__ import annotations

import warnings

import mpmath
import numpy as np
import pytest

from scratchfab.render.profile import (
    profile_height,
    profile_normal,
    solve_wbar,
    steepest_wall_deg,
)

RATIOS = np.geomspace(1e-3, 10.0, 60)  # depth / width
WIDTHS = np.array([0.01, 0.1, 0.5, 3.0])


EPS = np.finfo(np.float64).eps


def _eq2(wbar, w, d):
    return -(wbar / 2) * np.log1p(-4 * w * w / (wbar * wbar)) - d


def _conditioning(wbar, w, d):
    """wbar |dG/dwbar| + d: how far eq. 2's residual moves when wbar moves by one ulp."""
    s2 = 4 * w * w / (wbar * wbar)
    return np.abs(d - wbar * s2 / (1 - s2)) + d


def test_solve_wbar_residual_is_machine_precision():
    width, ratio = np.meshgrid(WIDTHS, RATIOS, indexing="ij")
    depth = width * ratio
    wbar = solve_wbar(width, depth)
    assert wbar.shape == width.shape
    assert np.all(wbar > width)
    resid = np.abs(_eq2(wbar, width / 2, depth))
    # deep dents (s -> 1) make eq. 2 ill-conditioned; the residual is a few ulps of wbar
    assert np.all(resid <= 8 * EPS * _conditioning(wbar, width / 2, depth))
    shallow = ratio < 0.5
    assert (resid[shallow] / depth[shallow]).max() < 2e-15


def test_solve_wbar_matches_mpmath_to_an_ulp_or_two():
    mpmath.mp.dps = 40
    for width in WIDTHS:
        for ratio in RATIOS[::6]:
            depth = float(width * ratio)
            kappa = mpmath.mpf(depth) / (mpmath.mpf(float(width)) / 2)
            lo, hi = mpmath.mpf(0), mpmath.mpf(1)
            for _ in range(150):
                mid = (lo + hi) / 2
                if -mpmath.log(1 - mid * mid) / mid > kappa:
                    hi = mid
                else:
                    lo = mid
            ref = float(mpmath.mpf(float(width)) / lo)
            assert abs(solve_wbar(width, depth) - ref) <= 3 * EPS * ref


def test_solve_wbar_is_monotone_and_scalar():
    wbar = solve_wbar(0.1, 0.1 * RATIOS)
    assert np.all(np.diff(wbar) < 0)  # deeper dent: smaller wbar, steeper walls
    walls = steepest_wall_deg(0.1, 0.1 * RATIOS)
    assert np.all(np.diff(walls) > 0)
    assert 0 < walls[0] < 1 and 89 < walls[-1] < 90
    assert np.ndim(solve_wbar(0.1, 0.01)) == 0


def test_solve_wbar_at_the_deepest_dent_the_schema_allows_is_silent_and_exact():
    """depth/width = 30 (DENT_RATIO's top): the bisection's midpoint rounds to s = 1, where
    phi = +inf is the right limit; it used to print numpy's 'divide by zero' warning."""
    from scratchfab.model.design import DENT_RATIO

    width, depth = 0.1, 0.1 * DENT_RATIO[1]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wbar = float(solve_wbar(width, depth))
    # eq. 2 gives s = 2w/wbar with 1 - s^2 = exp(-d/w) ~ 1e-26: s is 1 to double precision
    kappa = mpmath.mpf(depth) / (mpmath.mpf(width) / 2)
    s_exact = mpmath.mpf(1)
    with mpmath.workdps(60):
        for _ in range(20):  # s = sqrt(1 - exp(-kappa s)): a contraction near s = 1
            s_exact = mpmath.sqrt(1 - mpmath.exp(-kappa * s_exact))
    assert 1 - s_exact < 1e-20
    assert wbar == pytest.approx(width / float(s_exact), rel=2 * EPS)


def test_solve_wbar_rejects_nonpositive():
    with pytest.raises(ValueError):
        solve_wbar(0.1, 0.0)


@pytest.mark.parametrize("ratio", [1e-3, 0.1, 1.0, 10.0])
def test_height_and_normal(ratio):
    width = 0.2
    depth = width * ratio
    wbar = solve_wbar(width, depth)
    w = width / 2
    assert profile_height(0.0, wbar, depth) == pytest.approx(-depth, rel=1e-14)
    tol = 16 * EPS * _conditioning(wbar, w, depth)
    assert abs(profile_height(w, wbar, depth)) < tol
    assert abs(profile_height(-w, wbar, depth)) < tol
    x = np.linspace(-w, w, 41)
    nx, nz = profile_normal(x, wbar)
    np.testing.assert_allclose(nx * nx + nz * nz, 1.0, rtol=1e-14)
    # the normal is perpendicular to the profile's tangent (1, z'(x)), z' by central differences
    step = 1e-6 * w
    xs = np.clip(x, -w + step, w - step)
    dz = (profile_height(xs + step, wbar, depth) - profile_height(xs - step, wbar, depth)) / (
        2 * step
    )
    nx, nz = profile_normal(xs, wbar)
    np.testing.assert_allclose(nx + nz * dz, 0.0, atol=1e-6 * max(1.0, np.abs(dz).max()))
    assert np.all(nz > 0)
    nx, nz = profile_normal(w, wbar)
    wall = np.degrees(np.arctan2(-nx, nz))
    assert wall == pytest.approx(steepest_wall_deg(width, depth), rel=1e-12)
