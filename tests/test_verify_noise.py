"""verify's Monte Carlo noise: its estimate of the noise-free rho, checked by brute force
(the same board rendered with many more samples), and the advice a failed gate gives."""

from __future__ import annotations

import contextlib
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from test_verify_render import half_board, two_view_design, write_targets

from scratchfab.cli import main
from scratchfab.metrics import exposed_difference, noise_effect, noise_share, pearson
from scratchfab.verify.noise import (
    diff_noise_advice,
    more_spp,
    noise_advice,
    noise_explains,
    spp_for,
    variance_ratio,
)
from scratchfab.verify.verify import BoardRenderer, VerifyGateError, design_targets

LOW_SPP = 64  # about 40 % noise on the 32 px test views: rho visibly lowered
HIGH_SPP = 16384  # about 2.5 % noise: within 0.001 of the noise-free rho
SEEDS = range(6)


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    """The half/half test board, its design file and CSV, and its targets."""
    root = tmp_path_factory.mktemp("noise")
    design = two_view_design(base=root, targets=write_targets(root))
    design.save(root / "design.toml")
    scratches = half_board(design, 140, seed=3)
    scratches.save(root / "scratches.csv", design.scratch)
    targets, _ = design_targets(design)
    return root, design, scratches, targets


def test_noise_estimate_predicts_the_rho_and_the_map_of_a_render_with_more_samples(board):
    """From low-spp renders alone, the estimate predicts what 256x the samples measure:
    the rise of rho to within a fifth of it, and the noise's part of the difference map
    (what the map loses at high spp) to within a third, at 64 spp and at 16."""
    _, design, scratches, targets = board
    renderer = BoardRenderer(design, scratches)
    for i, view in enumerate(design.views):
        target = targets[view.name]
        high = renderer.render(view, HIGH_SPP, seed=100 + i)
        rho_high = pearson(high.image, target)
        diff_high, _ = exposed_difference(high.image, target)
        measured, predicted, lost, share = [], [], [], []
        for seed in SEEDS:
            low = renderer.render(view, LOW_SPP, seed=10 * seed + i)
            effect = noise_effect(low.image, target, low.variance)
            assert effect.rho == pytest.approx(pearson(low.image, target), abs=1e-12)
            rho_high_predicted = effect.rho_at(variance_ratio(low.spp, high.spp, low.knee_spp))
            assert rho_high_predicted is not None and effect.rho_free is not None
            assert effect.rho_free > rho_high_predicted > effect.rho
            measured.append(effect.rho)
            predicted.append(rho_high_predicted)
            diff_low, _ = exposed_difference(low.image, target)
            lost.append(1 - np.nansum(diff_high**2) / np.nansum(diff_low**2))
            share.append(noise_share(low.image, target, low.variance))
        rise = rho_high - np.mean(measured)
        assert rise > 0.03, (view.name, rise)  # the noise matters here
        assert abs(np.mean(predicted) - rho_high) < 0.2 * rise, (view.name, predicted, rho_high)
        assert abs(np.mean(share) - np.mean(lost)) < np.mean(lost) / 3, (share, lost)
        # At 16 spp the noise is most of the render's own size (about 70 %): it also lowers
        # the exposure, which the map's share must count (s^2 V alone gave half of it).
        lost, share = [], []
        for seed in range(12):
            low = renderer.render(view, 16, seed=10 * seed + i + 7)
            diff_low, _ = exposed_difference(low.image, target)
            lost.append(1 - np.nansum(diff_high**2) / np.nansum(diff_low**2))
            share.append(noise_share(low.image, target, low.variance))
        assert abs(np.mean(share) - np.mean(lost)) < np.mean(lost) / 3, (share, lost)
        # At the high count the estimate moves rho by little: the noise is gone.
        top = noise_effect(high.image, target, high.variance)
        assert top.rho_free is not None and abs(top.rho_free - top.rho) < 0.002


def test_noise_effect_of_a_noise_free_render_is_its_rho():
    rng = np.random.default_rng(5)
    target = rng.uniform(0, 1, (20, 20))
    target[0] = np.nan
    render = 3 * target + rng.normal(0, 0.2, target.shape)
    effect = noise_effect(render, target, np.zeros_like(render))
    assert effect.rho_free == effect.rho == pytest.approx(pearson(render, target))
    assert effect.variance_factor() == 1.0
    # Noise as large as the whole spread leaves nothing to estimate from.
    swamped = noise_effect(render, target, np.full(render.shape, 100.0))
    assert swamped.rho_free is None and swamped.rho_at(4.0) is None


def test_variance_factor_brings_the_noise_cost_to_the_asked_loss():
    rng = np.random.default_rng(8)
    target = rng.uniform(0, 1, (30, 30))
    render = target + rng.normal(0, 0.3, target.shape)  # noise the estimate is told of
    effect = noise_effect(render, target, np.full(render.shape, 0.09))
    assert effect.rho_free is not None
    for loss in (0.05, 0.005, 0.0005):
        factor = effect.variance_factor(loss)
        assert factor is not None and factor > 1
        assert effect.rho_free - effect.rho_at(factor) == pytest.approx(loss, rel=1e-9)


def _metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


def test_a_gate_failed_for_noise_names_the_spp_that_passes_it(board, tmp_path, capsys):
    """Between the measured and the noise-free rho, the gate fails for noise alone: the
    refusal says so and names a --spp, and verify at that spp passes that view."""
    root = board[0]
    args = ["verify-render", "--design", str(root / "design.toml")]
    args += ["--scratches", str(root / "scratches.csv"), "--spp", str(LOW_SPP)]
    main([*args, "--out", str(tmp_path / "plain")])
    views = _metrics(tmp_path / "plain")["views"]
    worst = min(views, key=lambda n: views[n]["rho"])
    rho, free = views[worst]["rho"], views[worst]["rho_noise_free"]
    assert free - rho > 0.02
    capsys.readouterr()
    gate = round((rho + free) / 2, 3)
    with pytest.raises(SystemExit) as exc:
        main([*args, "--out", str(tmp_path / "gate"), "--min-rho", str(gate)])
    assert exc.value.code == 3
    err = capsys.readouterr().err
    assert f"view {worst} looks like its target only to rho" in err
    assert "sampling noise" in err and "explains it" in err
    assert "optimize longer" not in err  # the board is not what falls short
    spp = int(re.search(r"--spp (\d+) brings the noise", err).group(1))
    assert spp > LOW_SPP and spp in TYPED
    again = [a if a != str(LOW_SPP) else str(spp) for a in args]
    with contextlib.suppress(SystemExit):  # the other view may still fall short
        main([*again, "--out", str(tmp_path / "more"), "--min-rho", str(gate)])
    assert _metrics(tmp_path / "more")["views"][worst]["rho"] >= gate
    # A gate above the noise-free rho is the board's shortfall: optimize longer.
    high = round(free + 0.05, 3)
    with pytest.raises(SystemExit):
        main([*args, "--out", str(tmp_path / "high"), "--min-rho", str(high)])
    err = capsys.readouterr().err
    assert "explains it" not in err and "costs rho about" in err
    assert "optimize longer or add scratches (optimize --iterations, design --count)" in err


def test_a_pipeline_refusal_names_the_pipeline_settings():
    entry = {
        "rho": 0.8,
        "rho_noise_free": 0.86,
        "noise_to_signal": 0.16,
        "noise": 0.14,
        "spp": 512,
        "seconds": 10.0,
    }
    exc = VerifyGateError("v", 0.8, 0.9, 1, 2, Path("m.json"), entry=entry)
    said = str(exc.named("[verify] min_rho =", "my.toml"))
    assert said.startswith("my.toml: view v looks like its target only to rho 0.8")
    assert "below [verify] min_rho = 0.9" in said and "[verify] spp = " in said
    assert "[optimize] iterations, [scratch] count" in said and "--" not in said
    explained = VerifyGateError("v", 0.8, 0.82, 1, 2, Path("m.json"), entry=entry)
    said = str(explained.named("[verify] min_rho =", "my.toml"))
    assert "explains it" in said and "[optimize] iterations" not in said


#: The counts the advice names: eight steps an octave (8 to 15 times a power of two).
TYPED = sorted({m << k for m in range(8, 16) for k in range(16)} | set(range(1, 8)))


def gain(spp: int, more: int, knee: float | None) -> float:
    """The noise variance at ``spp`` over that at ``more``: V(n) ~ 1 / (n (1 + n / knee))."""
    if knee is None:
        return more / spp
    return more * (1 + more / knee) / (spp * (1 + spp / knee))


@pytest.mark.parametrize("knee", [None, 300.0, 5000.0])
@pytest.mark.parametrize(
    "rho, free, ratio, gate, explains",
    [
        (0.8, 0.86, 0.16, 0.82, True),
        (0.8, 0.86, 0.16, 0.9, False),
        (0.8, 0.86, 0.16, 0.7, False),  # passes
        (0.8, 0.86, 0.16, None, False),  # no gate
        (0.3, None, None, 0.5, True),  # mostly noise: nothing says the board is short
    ],
)
def test_noise_advice_names_the_fewest_typed_samples_that_do_what_it_says(
    rho, free, ratio, gate, explains, knee
):
    entry = {"rho": rho, "rho_noise_free": free, "noise_to_signal": ratio}
    entry |= {"noise": 0.14, "spp": 512, "seconds": 10.0, "noise_knee_spp": knee}
    assert noise_explains(entry, gate) is explains
    said = noise_advice(entry, gate, "--spp")
    spp = int(re.search(r"--spp (\d+)", said).group(1))
    assert spp in TYPED and spp > 512
    noise = float(re.search(r"noise to about ([\d.]+) %", said).group(1))
    assert noise == pytest.approx(14 / math.sqrt(gain(512, spp, knee)), abs=0.051)
    if free is None:
        assert "outweighs the picture" in said and spp == 16 * 512
        return
    # rho at that spp, from the model the estimate rests on (rho_inf / sqrt(1 + n/s))
    expect = free / math.sqrt(1 + ratio / gain(512, spp, knee))
    assert f"rho to about {expect:.3f}" in said
    allowed = min(0.005, (free - gate) / 2) if explains else 0.005
    assert free - expect <= allowed + 1e-12
    fewer = TYPED[TYPED.index(spp) - 1]  # the next count down
    assert free - free / math.sqrt(1 + ratio / gain(512, fewer, knee)) > allowed


def test_noise_that_costs_little_says_nothing():
    entry = {"rho": 0.899, "rho_noise_free": 0.9, "noise_to_signal": 0.002}
    entry |= {"noise": 0.01, "spp": 8192, "seconds": 10.0}
    assert noise_advice(entry, 0.8, "--spp") == ""
    assert noise_advice({"rho": 0.9}, 0.8, "--spp") == ""  # a metrics.json from before


@pytest.mark.parametrize("knee", [None, 300.0])
def test_a_map_mostly_noise_names_the_spp_that_quiets_it(knee):
    for share in (0.25, 0.5, 0.8, 0.95):
        entry = {"diff_noise_share": share, "spp": 1024, "noise_knee_spp": knee}
        said = diff_noise_advice(entry, "spp")
        spp = int(re.search(r"spp (\d+) brings it under 20 %", said).group(1))
        assert f"about {100 * share:.0f} % of these differences" in said
        k = gain(1024, spp, knee)  # the noise's part falls with its variance
        assert (share / k) / (share / k + 1 - share) <= 0.2 + 1e-12
        k = gain(1024, TYPED[TYPED.index(spp) - 1], knee)
        assert k < 1 or (share / k) / (share / k + 1 - share) > 0.2
    assert diff_noise_advice({"diff_noise_share": 0.24, "spp": 1024}, "spp") == ""
    assert diff_noise_advice({"diff_noise_share": 0.3, "spp": 1}, "spp").startswith("sampling")
    assert "spp 16384 at least" in diff_noise_advice({"diff_noise_share": 1.0, "spp": 1024}, "spp")
    assert more_spp(70) == 72 and more_spp(64) == 64 and more_spp(1025) == 1152
    assert all(more_spp(n) in TYPED and n <= more_spp(n) <= n * 1.125 for n in range(1, 5000))
    assert spp_for(100, 4.0, None) == pytest.approx(400.0)
    assert gain(100, spp_for(100, 4.0, 300.0), 300.0) == pytest.approx(4.0)
    assert variance_ratio(100, 700, 300.0) == pytest.approx(gain(100, 700, 300.0))


def test_the_maps_noise_note_adds_a_title_line_per_clause(monkeypatch):
    from scratchfab.verify import diffmap

    said: list[list[str]] = []
    add_title = diffmap.figures.add_title

    def record(canvas, lines, *args, **kwargs):
        said.append(list(lines))
        return add_title(canvas, lines, *args, **kwargs)

    monkeypatch.setattr(diffmap.figures, "add_title", record)
    diff = np.random.default_rng(2).uniform(-0.3, 0.3, (8, 8))
    note = diff_noise_advice({"diff_noise_share": 0.6, "spp": 512}, "spp")
    diffmap.diff_figure(diff, "v")
    diffmap.diff_figure(diff, "v", note=note)
    plain, noted = said
    assert noted == [*plain, *note.split("; ")] and len(noted) == len(plain) + 2
    assert not any("exposure" in line for line in noted)  # a maker's words


@pytest.mark.parametrize("knee", [None, 300.0])
def test_the_advice_counts_from_two_batches_as_noisy_as_the_render(knee):
    """A render whose noise target added batches records the count of two batches that
    leave its noise (noise_equivalent_spp): the advice names what it names from those two
    batches, and only the time counts from the samples taken."""
    two = {"rho": 0.8, "rho_noise_free": 0.86, "noise_to_signal": 0.16, "noise": 0.14}
    two |= {"spp": 512, "noise_knee_spp": knee, "diff_noise_share": 0.6}
    more = two | {"spp": 1024, "noise_equivalent_spp": 512.0}
    for gate in (0.82, None):
        named = re.sub(r", about .* a view$", "", noise_advice(two, gate, "--spp"))
        assert named and noise_advice(more, gate, "--spp").startswith(named)
    assert diff_noise_advice(more, "spp") == diff_noise_advice(two, "spp")
    bare = {"rho": 0.3, "rho_noise_free": None, "noise_to_signal": None, "noise": 0.9}
    said = noise_advice(bare | {"spp": 1024, "noise_equivalent_spp": 512.0}, None, "--spp")
    assert "--spp 8192 " in said  # 16 times the two batches' 512, not the 1024 taken
