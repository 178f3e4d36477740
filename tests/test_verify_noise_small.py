"""verify's sample-count advice on a coarse board: 60 mm at 32 px, 200 scratches.

Each pixel spans about 19 scratch widths there: the noise falls as 1 / spp up to some
thousand samples, and the small gain the strata show at 64 spp (about 0.93) is no sign of
the knee (near 7000 spp). Reading a knee from it named as little as 0.46 times the count
that reaches the noise measured at 2048 spp (a reviewer's job: 3328 spp advised, 10.2 %
noise measured at 3360 against the 6.1 % promised). References: the noise variance that
renders at 2048 spp measure, and the rho loss a render at the advised count measures.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import scratchfab
from scratchfab.design.layout import initial_layout
from scratchfab.design.targets import view_targets
from scratchfab.metrics import NOISE_RHO_LOSS, noise_effect
from scratchfab.model.design import design_from_mapping
from scratchfab.verify.noise import noise_advice, spp_for
from scratchfab.verify.verify import BoardRenderer

DEMO_PICTURES = Path(scratchfab.__file__).parent / "data" / "demo"
GOAL_SPP = 2048
SEEDS = range(16)  # with the knee read from the gain, 3 of them named under 0.7 times


def coarse_design():
    """The bundled demo's geometry (sun and house, 22 degrees either side) at 32 px."""
    views = [
        {
            "name": name,
            "target": f"{name}.png",
            "azimuth_deg": azimuth,
            "elevation_deg": 0.0,
            "distance_mm": 500.0,
            "fov_deg": "auto",
            "resolution": [32, 32],
        }
        for name, azimuth in (("sun", -22.0), ("house", 22.0))
    ]
    tables = {
        "board": {"width_mm": 60.0, "height_mm": 60.0, "roughness": 0.05, "margin_mm": 2.0},
        "light": {"position_mm": [0.0, 187.3, 463.6]},
        "scratch": {
            "width_mm": 0.1,
            "depth_mm": 0.01,
            "count": 200,
            "min_length_mm": 2.0,
            "max_length_mm": 12.0,
        },
        "views": views,
    }
    return design_from_mapping(tables, "<coarse test board>", DEMO_PICTURES)


@pytest.fixture(scope="module")
def coarse():
    """The board, its renderer, its targets, and per view the noise variance at GOAL_SPP
    (the mean of two renders) with the samples taken."""
    design = coarse_design()
    targets = view_targets(design)
    renderer = BoardRenderer(design, initial_layout(design, targets, seed=0))
    goals = {}
    for i, view in enumerate(design.views):
        renders = [renderer.render(view, GOAL_SPP, seed=900 + 10 * s + i) for s in range(2)]
        goals[view.name] = (np.mean([float(np.sum(r.variance)) for r in renders]), renders[0].spp)
    return design, renderer, targets, goals


def test_from_64_spp_the_named_count_reaches_the_noise_measured_there(coarse):
    """The count the advice's model names for the variance measured at 2048 spp is never
    much below it and on average at most 1.6 times it (these renders show no knee: 1 / spp
    names 1.0 to 2.0 times it, 1.3 and 1.5 in the mean, the renders' own spread)."""
    design, renderer, _, goals = coarse
    for i, view in enumerate(design.views):
        variance, taken = goals[view.name]
        counts = []
        for seed in SEEDS:
            low = renderer.render(view, 64, seed=seed + 1000 * i)
            assert low.equivalent_spp is not None
            factor = float(np.sum(low.variance)) / variance
            counts.append(spp_for(low.equivalent_spp, factor, low.knee_spp) / taken)
        assert min(counts) > 0.85 and np.mean(counts) < 1.6, (view.name, counts)


def test_a_rerun_at_the_advised_count_meets_the_goal(coarse):
    """The reviewer's case: the house view at 64 spp, seed 12 of this board (with the knee
    read from its gain the advice named 0.7 times the count needed). At the count the
    advice names the noise costs rho at most about NOISE_RHO_LOSS, and the noise is about
    what it says."""
    design, renderer, targets, _ = coarse
    view = design.views[1]
    low = renderer.render(view, 64, seed=12 + 1000)
    effect = noise_effect(low.image, targets[view.name], low.variance)
    entry = {
        "rho": effect.rho,
        "rho_noise_free": effect.rho_free,
        "noise_to_signal": effect.noise / effect.signal,
        "noise": low.noise,
        "spp": low.spp,
        "noise_knee_spp": low.knee_spp,
        "noise_equivalent_spp": low.equivalent_spp,
    }
    said = noise_advice(entry, None, "--spp")
    found = re.search(r"--spp (\d+) brings the noise to about ([\d.]+) %", said)
    assert found, said
    spp, promised = int(found.group(1)), float(found.group(2)) / 100
    rerun = renderer.render(view, spp, seed=77)
    again = noise_effect(rerun.image, targets[view.name], rerun.variance)
    assert again.rho_free is not None
    assert again.rho_free - again.rho < 1.25 * NOISE_RHO_LOSS, (spp, again)
    assert rerun.noise < 1.15 * promised, (spp, rerun.noise, promised)
