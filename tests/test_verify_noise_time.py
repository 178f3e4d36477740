"""The time verify's noise advice gives for the sample count it names.

A render's first batch of each part also compiles its kernels and first uses the scene,
so scaling a whole low-spp render's time by the sample factor overstated the time of the
named count many times over (a 16 spp demo view: "about 1 min a view" for 4096 spp, which
take 3 s). References: a clock that a stand-in renderer advances by a known start-up time
on each scene's first batch plus a known time per sample, and the estimate's own formula.
"""

from __future__ import annotations

import math
import re
from types import SimpleNamespace

import numpy as np
import pytest
from test_verify_noise import board  # noqa: F401  (the module's fixture)

from scratchfab.console import duration_text
from scratchfab.verify import verify as verify_module
from scratchfab.verify.noise import noise_advice, render_seconds
from scratchfab.verify.verify import FLAT_SPP_FRACTION, MIN_PART_SPP, BoardRenderer, half_spp

START_S = 5.0  # each scene's first batch: compiling, first use
PER_SAMPLE_S = 0.002  # each sample per pixel of a batch


class FakeClock:
    """``time.perf_counter`` that only the stand-in renderer moves."""

    def __init__(self) -> None:
        self.now = 0.0
        self.seen: set[int] = set()

    def perf_counter(self) -> float:
        return self.now

    def render_view_spread(self, scene, spp: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        if id(scene) not in self.seen:
            self.seen.add(id(scene))
            self.now += START_S
        self.now += spp * PER_SAMPLE_S
        image = np.random.default_rng(seed).uniform(0.5, 1.5, (4, 4))
        return image, np.ones_like(image)


@pytest.mark.parametrize("spp", [32, 256, 1000])
def test_the_render_times_a_sample_apart_from_the_first_batches(board, monkeypatch, spp):  # noqa: F811
    _, design, scratches, _ = board
    renderer = BoardRenderer(design, scratches)
    clock = FakeClock()
    monkeypatch.setattr(verify_module, "render_view_spread", clock.render_view_spread)
    monkeypatch.setattr(verify_module, "time", SimpleNamespace(perf_counter=clock.perf_counter))
    result = renderer.render(design.views[0], spp)
    # Two batches per part (spec mode: the scratches at spp, the flat part at a fraction).
    parts = [spp, max(MIN_PART_SPP, round(FLAT_SPP_FRACTION * spp))]
    assert result.seconds == pytest.approx(
        sum(START_S + 2 * half_spp(n) * PER_SAMPLE_S for n in parts)
    )
    # One more sample per pixel: one more for the scratches, the fraction for the flat part.
    assert result.seconds_per_spp == pytest.approx((1 + FLAT_SPP_FRACTION) * PER_SAMPLE_S)


def entry(**more: float) -> dict:
    """A view that noise costs rho 0.06 at 128 spp, as metrics.json records it."""
    return {"rho": 0.8, "rho_noise_free": 0.86, "noise_to_signal": 0.16, "noise": 0.3} | more


def test_the_advice_adds_the_samples_time_to_the_renders_own():
    timed = entry(spp=128, seconds=3.0, seconds_per_spp=0.001)
    said = noise_advice(timed, None, "--spp")
    more = int(re.search(r"--spp (\d+)", said).group(1))
    assert more >= 8 * 128
    took = 3.0 + (more - 128) * 0.001
    assert said.endswith(f"about {duration_text(took)} a view")
    assert render_seconds(timed, more) == pytest.approx(took)
    # Scaling the whole time (start-up included) says what it said before: far longer.
    assert duration_text(3.0 * more / 128) != duration_text(took)
    assert render_seconds(timed, 64) == 3.0  # fewer samples: no less than it took


def test_a_metrics_json_without_the_sample_time_scales_the_whole_time():
    old = entry(spp=128, seconds=3.0)
    said = noise_advice(old, None, "--spp")
    more = int(re.search(r"--spp (\d+)", said).group(1))
    assert said.endswith(f"about {duration_text(3.0 * more / 128)} a view")
    for bad in (math.nan, -1.0, "x"):
        assert render_seconds(entry(spp=128, seconds=3.0, seconds_per_spp=bad), 256) == 6.0
    assert render_seconds(entry(spp=128), 256) is None
    assert "a view" not in noise_advice(entry(spp=128), None, "--spp")
