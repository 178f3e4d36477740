"""The component-wise half-vectors against the textbook normalize(wi + wo) over (..., 3) arrays."""

from __future__ import annotations

import numpy as np
import pytest

from scratchfab.design.feasibility import half_vectors_from


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_half_vectors_match_normalized_sums_to_the_last_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    scale = 10.0 ** rng.uniform(-2, 5)
    light = rng.normal(0, 1, 3) * scale
    camera = rng.normal(0, 1, 3) * scale * 3
    light[2], camera[2] = abs(light[2]) + 1e-3, abs(camera[2]) + 1e-3
    points = rng.uniform(-1, 1, (7, 300, 2)) * 10.0 ** rng.uniform(-1, 3)
    p = np.concatenate([points, np.zeros(points.shape[:-1] + (1,))], axis=-1)
    want = _unit(_unit(light - p) + _unit(camera - p))
    got = half_vectors_from(light, camera, points)
    assert got.shape == want.shape
    # the layout and the feasibility report's figures depend on these bits (same sum order)
    assert np.array_equal(got, want)
