from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize, stats

from scratchfab.metrics import exposure, pearson, psnr, quality_report


def _images(rng, shape=(24, 20)):
    t = rng.uniform(0, 1, shape)
    t[:3, :] = np.nan  # off the board
    r = 3.0 * np.nan_to_num(t) + rng.normal(0, 0.05, shape)
    return r, t


def test_exposure_minimises_squared_error(rng):
    r, t = _images(rng)
    mask = np.isfinite(t)
    best = optimize.minimize_scalar(lambda s: np.sum((s * r[mask] - t[mask]) ** 2)).x
    assert exposure(r, t) == pytest.approx(best, rel=1e-6)
    assert exposure(np.zeros_like(r), t) == 0.0


def test_psnr_and_pearson_against_numpy(rng):
    r, t = _images(rng)
    mask = np.isfinite(t)
    s = exposure(r, t)
    mse = np.mean((s * r[mask] - t[mask]) ** 2)
    assert psnr(r, t) == pytest.approx(10 * math.log10(1 / mse))
    assert pearson(r, t) == pytest.approx(stats.pearsonr(r[mask], t[mask]).statistic)
    assert pearson(np.ones_like(r), t) == 0.0


def test_crosstalk_is_beyond_shared_content(rng):
    a = rng.uniform(0, 1, (16, 16))
    b = rng.uniform(0, 1, (16, 16))
    # View k shows only its own image: rho_kk = 1 and crosstalk = 0 exactly.
    report = quality_report(
        {"k": a.copy(), "j": b.copy()}, {"k": a, "j": b}, {("k", "j"): b, ("j", "k"): a}
    )
    assert report["views"]["k"]["rho"] == pytest.approx(1.0)
    assert report["views"]["k"]["crosstalk"]["j"] == pytest.approx(0.0, abs=1e-12)
    # View k shows a mix: crosstalk grows with how much of image j leaks in.
    leaky = quality_report({"k": a + b, "j": b}, {"k": a, "j": b}, {("k", "j"): b, ("j", "k"): a})
    x = leaky["views"]["k"]["crosstalk"]["j"]
    expected = (
        stats.pearsonr((a + b).ravel(), b.ravel()).statistic
        - stats.pearsonr(a.ravel(), b.ravel()).statistic
    )
    assert x == pytest.approx(expected)
    assert x > 0.5
    assert math.isnan(leaky["crosstalk_matrix"][0][0])
