"""The ``verify-render`` stage: render the board in Mitsuba 3 and compare.

Every view is rendered in independent batches (two at half the sample count each, two
larger ones while a noise target is not met). The output image is their mean and the
batches' spread gives its standard error (for two, ``|A - B| / 2``), so the reported
noise level costs no extra samples. The comparison target is the analytic
``render`` of the same board (``JOB/optimize/renders`` or
:func:`scratchfab.render.renderer.render_scratches`); it is only read, never used to
render. Quality measures follow SPEC section 7 (:mod:`scratchfab.metrics`).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from scratchfab.backend import BackendName
from scratchfab.console import Say, clock
from scratchfab.design.targets import cross_targets, job_cross_targets
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.fileio import load_numpy, write_bytes, write_json
from scratchfab.metrics import noise_effect, noise_share, quality_report, rho_text
from scratchfab.model.design import Design, View, load_design
from scratchfab.model.job import (
    JobLayout,
    diff_map_png,
    job_inputs,
    load_job_design,
    stale_layout_warning,
)
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.optimize.glint import ViewGlint, view_glint
from scratchfab.verify.diffmap import write_diff_map
from scratchfab.verify.gate import gate_applies
from scratchfab.verify.jitter import Tolerance, jitter_scratches
from scratchfab.verify.noise import (
    PartNoise,
    diff_noise_advice,
    noise_advice,
    noise_explains,
    render_knee,
    variance_ratio,
)
from scratchfab.verify.outshine import outshine_advice, shoulder_shares
from scratchfab.verify.scene import Sky, board_bsdf, render_view_spread, scene_dict, use_variant
from scratchfab.verify.sweep import nearest_frames, sweep_gif, sweep_path

if TYPE_CHECKING:
    from scratchfab.pipeline.runner import VerifyMetrics

#: Samples per pixel by default: about 1 % noise where a pixel's footprint spans up to
#: eight scratch widths (the bundled demo), well below 1 % at four.
DEFAULT_SPP = 8192
#: With a noise target, batches are added up to this many times the requested spp.
MAX_SPP_FACTOR = 8
#: Share of the samples that the smooth flat-remainder image gets in ``"spec"`` mode.
FLAT_SPP_FRACTION = 0.125
#: Fewest samples per pixel of any part.
MIN_PART_SPP = 16
#: Sweep frames get at most this many samples per pixel.
SWEEP_SPP = 1024


class VerifyGateError(ScratchfabError):
    """A view's rho_kk fell below the gate: the board should not be cut.

    It keeps the figures, so that each caller can name the threshold as its user set it
    (``--min-rho``, or a pipeline's ``[verify] min_rho``) with :meth:`named`.

    Attributes:
        metrics: Every view's measurements and the gate, as
            :attr:`RunResult.verify <scratchfab.pipeline.runner.RunResult>` would have
            held them, where :func:`~scratchfab.pipeline.runner.run_pipeline` raised it (a
            failing gate ends the run, so the caller gets no ``RunResult``); None from
            :func:`run_verify` itself, whose ``metrics.json`` is ``metrics_file``.
    """

    exit_code = 3
    metrics: VerifyMetrics | None = None

    def __init__(
        self,
        view: str,
        rho: float,
        min_rho: float,
        failing: int,
        views: int,
        metrics_file: Path,
        setting: str = "--min-rho",
        source: str | None = None,
        glints: Mapping[str, float] | None = None,
        entry: Mapping[str, Any] | None = None,
        feasibility: Mapping[str, Any] | None = None,
    ) -> None:
        self.view, self.rho, self.min_rho = view, rho, min_rho
        self.failing, self.views, self.metrics_file = failing, views, metrics_file
        self.glints, self.entry, self.feasibility = dict(glints or {}), entry, feasibility
        where = f"{source}: " if source else ""
        cli = setting.startswith("--")
        noise = noise_advice(
            entry or {}, min_rho, "--spp" if cli else setting.replace("min_rho", "spp")
        )
        advice = [noise] if noise else []
        shoulders = {n: s for n, s in shoulder_shares(feasibility).items() if n in self.glints}
        outshone = outshine_advice(
            self.glints,
            shoulders,
            feasibility,
            "design --count" if cli else "[scratch] count =",
            str(metrics_file.parent / "diff"),
        )
        advice += outshone
        if not outshone and not noise_explains(entry or {}, min_rho):
            advice.append(
                "optimize longer or add scratches ("
                + (
                    "optimize --iterations, design --count"
                    if cli
                    else "[optimize] iterations, [scratch] count"
                )
                + ")"
            )
        super().__init__(
            f"{where}view {view} looks like its target only to rho {rho_text(rho, min_rho)}, below "
            f"{setting} {min_rho:g} ({failing} of {views} views fail; see {metrics_file})"
            + "".join(f"; {a}" for a in advice)
        )

    def named(self, setting: str, source: str) -> VerifyGateError:
        """The same failure (and :attr:`metrics`), its threshold ``setting`` in ``source``."""
        named = VerifyGateError(
            self.view,
            self.rho,
            self.min_rho,
            self.failing,
            self.views,
            self.metrics_file,
            setting,
            source,
            self.glints,
            self.entry,
            self.feasibility,
        )
        named.metrics = self.metrics
        return named

    @property
    def glinting(self) -> tuple[str, ...]:
        """The failing views into which the bare board glints, whether named or not."""
        return tuple(n for n, g in self.glints.items() if g > 0)


def bad_sweep_frames(frames: int) -> str | None:
    """Why ``frames`` is not a sweep length (0: no sweep, else at least 2), or None."""
    if frames == 0 or frames >= 2:
        return None
    return f"expected 0 (no sweep) or at least 2 frames, got {frames}"


@dataclass(frozen=True)
class VerifySettings:
    """What ``verify-render`` does beyond the plain comparison.

    Attributes:
        spp: Samples per pixel (split into two independent halves).
        seed: Base seed of the samplers and the jitter.
        backend: ``"llvm"`` (CPU) or ``"cuda"``.
        sky: Also render under the design light plus sun and sky.
        sweep: Number of sweep frames (0: none).
        jitter: Tolerances to perturb the layout by (None: no jitter run).
        min_rho: Gate: every view's rho_kk must reach this (None: no gate).
        max_noise: Noise target of the comparison renders (None: fixed ``spp``).
    """

    spp: int = DEFAULT_SPP
    seed: int = 0
    backend: BackendName = "llvm"
    sky: Sky | None = None
    sweep: int = 0
    jitter: Tolerance | None = None
    min_rho: float | None = None
    max_noise: float | None = None

    def __post_init__(self) -> None:
        if self.spp < 2:
            raise ValueError(f"spp: expected at least 2 (two independent halves), got {self.spp}")
        if (why := bad_sweep_frames(self.sweep)) is not None:
            raise ValueError(f"sweep: {why}")
        if self.min_rho is not None and not -1 <= self.min_rho <= 1:
            raise ValueError(f"min_rho: expected -1 to 1, got {self.min_rho}")
        if self.max_noise is not None and not self.max_noise > 0:
            raise ValueError(f"max_noise: expected a number > 0, got {self.max_noise}")


@dataclass(frozen=True)
class ViewRender:
    """One view's Mitsuba render.

    Attributes:
        image: (H, W) float32 linear radiance, the mean of the batches.
        noise: Estimated relative L2 error of ``image``: the batches' standard error
            sqrt(sum_i |B_i - mean|^2 / (k (k - 1))) over |mean|.
        spp: Samples per pixel actually taken (all batches).
        seconds: Wall time of all batches.
        variance: (H, W) the estimated variance of each pixel of ``image`` (the squared
            standard error that ``noise`` sums).
        seconds_per_spp: Wall time one more sample per pixel (of ``render``'s ``spp``)
            costs, timed on each part's batches after its first, whose time also holds
            compiling and loading the scene.
        knee_spp: The sample count past which the stratified sampler's noise falls
            faster than 1 / spp (:func:`scratchfab.verify.noise.render_knee`; None: it
            does not, as far as this render shows).
        equivalent_spp: The samples per pixel at which two batches leave this render's
            noise: ``spp`` unless batches were added for a noise target (each batch is
            stratified on its own, so the first ones, of a coarser grid, leave more noise
            than two of the same total); the noise advice counts from it.
    """

    image: np.ndarray
    noise: float
    spp: int
    seconds: float
    variance: np.ndarray
    seconds_per_spp: float
    knee_spp: float | None = None
    equivalent_spp: float | None = None


def half_spp(spp: int) -> int:
    """Samples of each half, rounded to the a x b grid the multi-jitter sampler uses."""
    n = max(1, math.ceil(spp / 2))
    a = max(1, math.isqrt(n))
    return a * math.ceil(n / a)


class BoardRenderer:
    """Mitsuba renders of one board for any camera (the plugin's grid is built once).

    Two modes:

    - ``"spec"`` reproduces SPEC section 4: the scratches' lobes and the signed flat
      remainder are rendered as two images (the plugin's ``lobes = "scratches"`` and
      ``"flat"``), and the flat image is clamped at zero per pixel before the two are
      added, which is the footprint rule ``max(0, |P n B| - sum_i |P n S_i|)``. The flat
      part is smooth and gets ``FLAT_SPP_FRACTION`` of the samples.
    - ``"physical"``: one board whose flat weight is ``max(0, 1 - k(p))`` pointwise, for
      light other than the design's (sky, sweeps).

    Args:
        design: Board, light and views.
        scratches: The layout.
        backend: ``"llvm"`` or ``"cuda"``.
        sky: Add the sun-and-sky emitter (renders in the RGB variant, stores luminance;
            ``"physical"`` mode only).
        mode: ``"spec"`` or ``"physical"``.
    """

    def __init__(
        self,
        design: Design,
        scratches: ScratchSet,
        backend: BackendName = "llvm",
        sky: Sky | None = None,
        mode: str = "spec",
    ) -> None:
        if mode not in ("spec", "physical"):
            raise ValueError(f"mode must be 'spec' or 'physical', got {mode!r}")
        if sky is not None and mode == "spec":
            raise ValueError("a sky needs mode='physical' (SPEC section 4 has one point light)")
        self.mi = use_variant(backend, color=sky is not None)
        self.design = design
        self.scratches = scratches
        self.sky = sky
        self.mode = mode
        load = self.mi.load_dict
        if mode == "spec":
            self.parts = [
                (load(board_bsdf(design, scratches, "signed", "scratches")), 1.0),
                (load(board_bsdf(design, scratches, "signed", "flat")), FLAT_SPP_FRACTION),
            ]
        else:
            self.parts = [(load(board_bsdf(design, scratches, "clamped", "all")), 1.0)]

    def render(
        self, view: View, spp: int, seed: int = 0, max_noise: float | None = None
    ) -> ViewRender:
        """Render ``view`` with ``spp`` samples per pixel in (at least) two batches.

        Args:
            view: The camera.
            spp: Samples per pixel of the first two batches together.
            seed: Base seed; batch k of part p uses ``4096 * seed + 64 * p + k``.
            max_noise: Add batches until the estimated noise is at most this (or
                ``MAX_SPP_FACTOR * spp`` is reached), two at a time, of the size that
                reaches it.
        """
        start = time.perf_counter()
        means = []
        parts: list[PartNoise] = []
        per_spp = 0.0
        taken = 0
        for p, (bsdf, fraction) in enumerate(self.parts):
            part_spp = max(MIN_PART_SPP, round(fraction * spp))
            mean, part, per_sample, samples = self._batches(
                view, bsdf, part_spp, 4096 * seed + 64 * p, max_noise if p == 0 else None
            )
            means.append(mean)
            parts.append(part)
            taken = max(taken, samples)
            per_spp += fraction * per_sample  # a part takes ``fraction`` of each spp
        if self.mode == "spec":
            image = means[0] + np.maximum(means[1], 0.0)
        else:
            image = means[0]
        variance = np.asarray(np.sum([p.leaves for p in parts], axis=0), np.float64)
        norm = float(np.linalg.norm(image))
        noise = math.sqrt(float(np.sum(variance))) / norm if norm > 0 else 0.0
        seconds = time.perf_counter() - start
        knee, equal = render_knee(parts)
        return ViewRender(
            image.astype(np.float32), noise, taken, seconds, variance, per_spp, knee, equal
        )

    def _batches(
        self, view: View, bsdf: Any, spp: int, seed: int, max_noise: float | None
    ) -> tuple[np.ndarray, PartNoise, float, int]:
        """The batches' mean, their noise (:class:`PartNoise`), seconds per sample, samples.

        Per pixel the batches' mean, its squared standard error, and that error as
        unstratified samples would leave it (the samples' own spread over their count).
        The seconds per sample are timed on the batches after the first, whose time also
        holds compiling the kernels and the scene's first use.

        Batches come in rounds of two of one size, the first of ``spp`` samples. While
        the noise is above ``max_noise`` a round of the size that the knee's model says
        meets it is added (:func:`_next_round`, within ``MAX_SPP_FACTOR * spp`` in all):
        each batch is stratified on its own, so two larger batches leave less noise than
        more of the first size (a fine board's 2.5 times less noise than 256 spp took
        1749 spp so, 1198 now, where two batches need 813). The batches of each size
        are one round, and the rounds are weighed by their samples (:func:`_combine`);
        the returned part describes the round of the largest batches, the knee's
        reading (its ``rendered``: the whole image's error).
        """
        mi = self.mi
        half = half_spp(spp)
        scene = mi.load_dict(
            scene_dict(self.design, self.scratches, view, half, sky=self.sky, bsdf=bsdf)
        )
        budget = max(2, (MAX_SPP_FACTOR * spp) // half) * half  # all batches' samples
        groups: dict[int, list[np.ndarray]] = {}  # by size, the batches taken
        spreads: dict[int, np.ndarray | float] = {}  # per pixel, the samples' variance, summed
        size, taken, later = half, 0, 0.0  # later: the batches after the first one's time
        while True:
            for _ in range(2):
                start = time.perf_counter()
                seen = sum(len(g) for g in groups.values())
                image, samples = render_view_spread(scene, size, (seed + seen) % (1 << 32))
                groups.setdefault(size, []).append(image)
                spreads[size] = spreads.get(size, 0.0) + np.asarray(samples, np.float64)
                if taken:
                    later += time.perf_counter() - start
                taken += size
            means, rounds = {}, {}
            for n, batches in groups.items():
                k = len(batches)
                means[n], var = _batch_stats(batches)
                rounds[n] = PartNoise(n, k, var, np.asarray(spreads[n]) / k / (n * k))
            mean, rendered = _combine(list(rounds.values()), list(means.values()))
            norm = float(np.linalg.norm(mean))
            noise = math.sqrt(float(np.sum(rendered))) / norm if norm > 0 else 0.0
            if max_noise is not None and noise > max_noise:
                most = _grid_below((budget - taken) // 2)
                goal = (max_noise * norm) ** 2
                size = _next_round(rounds[size], taken, float(np.sum(rendered)), goal, 2 * most)
                size = min(max(size, half_spp(half)), most)
            if max_noise is None or noise <= max_noise or size < 1:
                last = rounds[max(rounds)]
                part = replace(last, rendered=None if len(rounds) == 1 else rendered)
                return mean, part, later / (taken - half), taken


def _batch_stats(batches: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Mean image and its squared standard error per pixel, sum_i (B_i - mean)^2 / (k (k - 1))."""
    k = len(batches)
    mean = sum(batches[1:], batches[0]) / k
    spread = sum((np.asarray(b, np.float64) - mean) ** 2 for b in batches)
    return mean, np.asarray(spread) / (k * (k - 1))


def _combine(rounds: list[PartNoise], means: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The rounds' mean (each: the batches of one size), weighed by samples, and its error.

    The error: per pixel, the squared standard error of that mean.

    Weights fixed in advance keep the error unbiased (weighed by their measured noise, the
    rounds whose noise came out low would count more, and the error with them); one
    round is returned as it is.
    """
    if len(rounds) == 1:
        return means[0], rounds[0].variance
    weights = np.array([r.batch * r.batches for r in rounds], np.float64)
    weights /= np.sum(weights)
    mean = sum(w * np.asarray(m, np.float64) for w, m in zip(weights, means, strict=True))
    variance = sum(w**2 * r.variance for w, r in zip(weights, rounds, strict=True))
    return np.asarray(mean), np.asarray(variance, np.float64)


def _next_round(last: PartNoise, taken: int, variance: float, goal: float, most: int) -> int:
    """Samples of each batch of the round that brings a render's summed variance to ``goal``.

    The fewest samples ``n`` (two batches, at most ``most``) that, weighed as
    :func:`_combine` weighs them against the ``taken`` samples that leave ``variance``,
    reach it: the knee's model, read from ``last`` (the last round's size), says what
    two batches of ``n`` samples leave.

    Returns:
        The samples of each batch, on the sampler's grid (``most`` where none reach it).
    """
    knee, _ = render_knee([last])
    pair, spp = last.batches / 2 * float(np.sum(last.variance)), 2 * last.batch  # two batches

    def left(n: int) -> float:
        added = n**2 * pair / variance_ratio(spp, n, knee)
        return (taken**2 * variance + added) / (taken + n) ** 2

    low, high = 1, max(1, most)
    if left(high) > goal:
        return half_spp(high)
    while low < high:
        mid = (low + high) // 2
        low, high = (mid + 1, high) if left(mid) > goal else (low, mid)
    return half_spp(low)


def _grid_below(spp: int) -> int:
    """The most samples at most ``spp`` that the multi-jitter sampler's a x b grid takes."""
    if spp < 1:
        return 0
    a = math.isqrt(spp)
    return a * (spp // a)


def relative_l2(image: np.ndarray, reference: np.ndarray) -> float:
    """|image - reference| / |reference| over the finite pixels (inf for a black reference)."""
    ok = np.isfinite(image) & np.isfinite(reference)
    diff = np.asarray(image, np.float64)[ok] - np.asarray(reference, np.float64)[ok]
    ref = float(np.linalg.norm(np.asarray(reference, np.float64)[ok]))
    return float(np.linalg.norm(diff)) / ref if ref > 0 else math.inf


def _quality(
    renders: Mapping[str, np.ndarray],
    targets: Mapping[str, np.ndarray],
    cross: Mapping[tuple[str, str], np.ndarray] | None,
) -> dict[str, Any]:
    with_target = {k: v for k, v in renders.items() if k in targets}
    if not with_target:
        return {"views": {}}
    return quality_report(with_target, targets, cross)


def _write_layout(out_dir: Path, images: Mapping[str, np.ndarray]) -> None:
    from scratchfab.render.layout import write_render_layout

    write_render_layout(out_dir, dict(images))


def view_glints(design: Design, backend: BackendName = "llvm") -> dict[str, ViewGlint]:
    """Per view, where the bare board glints into it, as optimize finds it and leaves it out."""
    from scratchfab.backend import array_module
    from scratchfab.design.feasibility import design_glint_deg
    from scratchfab.render.renderer import ViewRenderer

    m = array_module(backend)
    limit = design_glint_deg(design)
    return {v.name: view_glint(ViewRenderer(design, v, m), limit) for v in design.views}


def _write_diff_maps(
    out_dir: Path,
    images: Mapping[str, np.ndarray],
    targets: Mapping[str, np.ndarray],
    glints: Mapping[str, ViewGlint],
    views: Mapping[str, Mapping[str, Any]],
) -> None:
    """Write ``diff/<view>.png`` for each view with a target, its glint outlined.

    A map that is mostly sampling noise says so (``views``: the metrics' view entries).
    An earlier run's map of a view without a target now is removed: it showed another board.
    """
    for name, image in images.items():
        path = diff_map_png(out_dir, name)
        if name in targets:
            note = diff_noise_advice(views.get(name, {}), "spp")
            write_diff_map(path, image, targets[name], name, glint=glints.get(name), note=note)
        else:
            path.unlink(missing_ok=True)


def run_verify(
    design: Design,
    scratches: ScratchSet,
    out_dir: str | Path,
    settings: VerifySettings = VerifySettings(),
    *,
    analytic: Mapping[str, np.ndarray] | None = None,
    analytic_source: str = "render_scratches",
    targets: Mapping[str, np.ndarray] | None = None,
    cross: Mapping[tuple[str, str], np.ndarray] | None = None,
    progress: Say | None = None,
    feasibility: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Render every view in Mitsuba, compare with the analytic render, write the results.

    Writes ``out_dir/<view>.npy`` and ``.png`` (the render layout), ``metrics.json``,
    ``diff/<view>.png`` for each view with a target (:mod:`scratchfab.verify.diffmap`) and,
    when asked, ``sky/`` (renders under sun and sky), ``sweep.gif`` and the jitter report
    inside ``metrics.json``.

    Args:
        design: The design.
        scratches: The board to verify.
        out_dir: Output folder.
        settings: Sample count, extras and the gate.
        analytic: The analytic render per view; computed with ``render_scratches`` when
            None.
        analytic_source: Where ``analytic`` came from (recorded in the metrics).
        targets: T_k per view (linear, NaN off the board); views without one get no
            quality measures.
        cross: T_j->k keyed (k, j) for the crosstalk matrix.
        progress: Called with one line per finished piece of work.
        feasibility: ``design/feasibility.json`` of the job, for the gate's advice (the
            glint's shoulder and the count that clears it).

    Returns:
        The metrics (also in ``metrics.json``).

    Raises:
        ConfigError: Before any rendering, when ``targets``, ``cross`` or ``analytic``
            name another view or hold an image of another size than its view.
        VerifyGateError: After writing everything, when a view's rho_kk < ``min_rho``.
    """
    say = progress or (lambda _msg: None)
    out = Path(out_dir)
    targets = dict(targets or {})
    shapes = {v.name: (v.height, v.width) for v in design.views}
    given = [("targets", k, k, [k], img) for k, img in targets.items()] + [
        ("cross", f"({k}, {j})", k, [k, j], img) for (k, j), img in (cross or {}).items()
    ]
    for what, key, name, names, image in given:
        if not set(names) <= set(shapes):
            raise ConfigError(f"{what}: {key} names no view of the design ({', '.join(shapes)})")
        if np.shape(image) != shapes[name]:
            raise ConfigError(
                f"{what}: {key}: the image has shape {np.shape(image)}, view {name} is "
                f"{shapes[name]} (H, W)"
            )
    if analytic is None:
        from scratchfab.render.renderer import render_scratches

        analytic = render_scratches(design, scratches, settings.backend)
        analytic_source = "render_scratches"
    for view in design.views:
        reference = analytic.get(view.name)
        if reference is not None and reference.shape != (view.height, view.width):
            raise ConfigError(
                f"{analytic_source}: view {view.name}: the analytic render has shape "
                f"{reference.shape}, the view is {(view.height, view.width)}"
            )

    glints = view_glints(design, settings.backend)
    renderer = BoardRenderer(design, scratches, settings.backend)
    results: dict[str, ViewRender] = {}
    n = len(design.views)
    for i, view in enumerate(design.views):
        result = renderer.render(view, settings.spp, settings.seed + 1000 * i, settings.max_noise)
        results[view.name] = result
        spent = sum(r.seconds for r in results.values())
        asked = ""
        if settings.max_noise is None and result.spp != settings.spp:
            asked = f" ({settings.spp} asked: each batch fills the sampler's square grid)"
        say(
            f"verify {view.name} ({i + 1}/{n}): {view.width}x{view.height} px, {result.spp} spp"
            f"{asked}, "
            f"noise {100 * result.noise:.2f} %, {result.seconds:.1f} s, "
            f"views left about {clock(spent / (i + 1) * (n - i - 1))}"
        )
    images = {name: r.image for name, r in results.items()}
    quality = _quality(images, targets, cross)

    views: dict[str, Any] = {}
    for view in design.views:
        r = results[view.name]
        entry: dict[str, Any] = {
            "spp": r.spp,
            "seconds": r.seconds,
            "seconds_per_spp": r.seconds_per_spp,
            "noise": r.noise,
            "noise_knee_spp": r.knee_spp,
            "noise_equivalent_spp": r.equivalent_spp,
            "rel_l2": None,
            "resolution": [view.width, view.height],
            "glint_share": glints[view.name].board_share,
        }
        reference = analytic.get(view.name)
        if reference is not None:
            entry["rel_l2"] = relative_l2(r.image, reference)
            entry["psnr_vs_render"] = _psnr_vs(r.image, reference)
        q = quality["views"].get(view.name)
        if q is not None:
            effect = noise_effect(r.image, targets[view.name], r.variance)
            entry.update(
                exposure=q["exposure"],
                psnr=q["psnr"],
                rho=q["rho"],
                rho_to=q["rho_to"],
                crosstalk=q["crosstalk"],
                rho_noise_free=effect.rho_free,
                noise_to_signal=effect.noise / effect.signal if effect.signal > 0 else None,
                diff_noise_share=noise_share(r.image, targets[view.name], r.variance),
            )
        views[view.name] = entry
        rel = entry["rel_l2"]
        share = entry["glint_share"]
        say(
            f"verify {view.name}: relative L2 vs render "
            + (f"{100 * rel:.2f} %" if rel is not None else "n/a")
            + (
                f", rho vs target {rho_text(entry['rho'], settings.min_rho)}"
                if "rho" in entry
                else ""
            )
            + (f", the bare board glints on {100 * share:.1f} % of the board" if share else "")
        )
        if (noisy := noise_advice(entry, settings.min_rho, "spp")) and progress is not None:
            say(f"verify {view.name}: {noisy}")

    names = [v.name for v in design.views]
    metrics: dict[str, Any] = {
        "renderer": f"mitsuba {renderer.mi.__version__} {renderer.mi.variant()}, "
        "scratch_board plugin, direct integrator, multijitter sampler, box filter",
        "backend": settings.backend,
        "spp": {name: results[name].spp for name in names},
        "seed": settings.seed,
        "comparison": analytic_source,
        "names": names,
        "views": views,
        "crosstalk_matrix": [
            [views[k].get("crosstalk", {}).get(j) if j != k else None for j in names] for k in names
        ],
        "seconds": sum(r.seconds for r in results.values()),
    }

    if settings.sky is not None:
        metrics["sky"] = _run_sky(design, scratches, out / "sky", settings, targets, cross, say)
    if settings.jitter is not None:
        metrics["jitter"] = _run_jitter(design, scratches, settings, targets, views, say)
    sweep_gif: bytes | None = None
    if settings.sweep > 0:
        metrics["sweep"], sweep_gif = _run_sweep(design, scratches, settings, say)

    failing: list[str] = []
    if settings.min_rho is not None:  # -1 recorded too, as no gate: passed null
        gated = gate_applies(settings.min_rho)
        for name in names:
            rho = views[name].get("rho")
            if gated and rho is not None and not rho >= settings.min_rho:
                failing.append(name)
        metrics["gate"] = {
            "min_rho": settings.min_rho,
            "passed": not failing if gated else None,
            "failing": failing,
            "unchecked": [n for n in names if views[n].get("rho") is None],
        }

    _write_layout(out, images)
    _write_diff_maps(out, images, targets, glints, views)
    if sweep_gif is not None:
        write_bytes(out / "sweep.gif", sweep_gif)
    write_json(out / "metrics.json", metrics)
    if failing and settings.min_rho is not None:  # failing only with a gate
        worst = min(failing, key=lambda n: views[n]["rho"])
        raise VerifyGateError(
            worst,
            views[worst]["rho"],
            settings.min_rho,
            len(failing),
            len(names),
            out / "metrics.json",
            glints={n: views[n]["glint_share"] for n in failing},
            entry=views[worst],
            feasibility=feasibility,
        )
    return metrics


def _psnr_vs(image: np.ndarray, reference: np.ndarray) -> float:
    """PSNR of ``image`` against ``reference`` with the reference's maximum as the peak."""
    peak = float(np.nanmax(reference)) if np.isfinite(reference).any() else 0.0
    err = np.asarray(image, np.float64) - np.asarray(reference, np.float64)
    mse = float(np.nanmean(err * err))
    if peak <= 0 or mse <= 0:
        return math.inf
    return 10.0 * math.log10(peak * peak / mse)


def _run_sky(
    design: Design,
    scratches: ScratchSet,
    out: Path,
    settings: VerifySettings,
    targets: Mapping[str, np.ndarray],
    cross: Mapping[tuple[str, str], np.ndarray] | None,
    say: Say,
) -> dict[str, Any]:
    assert settings.sky is not None
    renderer = BoardRenderer(design, scratches, settings.backend, sky=settings.sky, mode="physical")
    images = {}
    seconds = 0.0
    for i, view in enumerate(design.views):
        r = renderer.render(view, settings.spp, settings.seed + 1000 * i + 7)
        images[view.name] = r.image
        seconds += r.seconds
        say(f"sky {view.name}: {r.seconds:.1f} s, noise {100 * r.noise:.2f} %")
    quality = _quality(images, targets, cross)
    _write_layout(out, images)
    sky = settings.sky
    return {
        "sun_direction": list(sky.sun_direction),
        "strength": sky.strength,
        "turbidity": sky.turbidity,
        "folder": "sky",
        "seconds": seconds,
        "views": {
            name: {"rho": q["rho"], "psnr": q["psnr"], "crosstalk": q["crosstalk"]}
            for name, q in quality["views"].items()
        },
    }


def _run_jitter(
    design: Design,
    scratches: ScratchSet,
    settings: VerifySettings,
    targets: Mapping[str, np.ndarray],
    base: Mapping[str, Any],
    say: Say,
) -> dict[str, Any]:
    assert settings.jitter is not None
    rng = np.random.default_rng(settings.seed + 4242)
    moved = jitter_scratches(scratches, settings.jitter, rng, design.board.half_extent)
    renderer = BoardRenderer(design, moved, settings.backend)
    images = {}
    for i, view in enumerate(design.views):
        images[view.name] = renderer.render(view, settings.spp, settings.seed + 1000 * i + 3).image
    quality = _quality(images, targets, None)
    views = {}
    for name, q in quality["views"].items():
        entry = {"rho": q["rho"], "psnr": q["psnr"]}
        if base[name].get("rho") is not None:
            entry["rho_drop"] = base[name]["rho"] - q["rho"]
            entry["psnr_drop"] = base[name]["psnr"] - q["psnr"]
        views[name] = entry
        say(
            f"jitter {name}: rho vs target {rho_text(q['rho'], settings.min_rho)}"
            + (f" (drop {entry['rho_drop']:+.3f})" if "rho_drop" in entry else "")
        )
    return {"tolerance": settings.jitter.as_dict(), "views": views}


def _run_sweep(
    design: Design, scratches: ScratchSet, settings: VerifySettings, say: Say
) -> tuple[dict[str, Any], bytes]:
    frames, view_params = sweep_path(design, settings.sweep)
    nearest = nearest_frames(frames, view_params)
    renderer = BoardRenderer(design, scratches, settings.backend, mode="physical")
    spp = min(settings.spp, SWEEP_SPP)
    images = []
    started = time.perf_counter()
    for i, frame in enumerate(frames):
        images.append(renderer.render(frame.view, spp, settings.seed + 7 * i + 1).image)
        if (i + 1) % 4 == 0 or i + 1 == len(frames):
            per = (time.perf_counter() - started) / (i + 1)
            say(f"sweep: {i + 1}/{len(frames)} frames, eta {clock(per * (len(frames) - i - 1))}")
    info = {
        "frames": len(frames),
        "spp": 2 * half_spp(spp),
        "gif": "sweep.gif",
        "nearest_frame": nearest,
        "cameras": [
            {
                "param_deg": f.param,
                "position_mm": list(f.view.position_mm or ()),
                "light_position_mm": list(f.view.light_position_mm or ()),
                "fov_deg": f.view.fov,
            }
            for f in frames
        ],
    }
    return info, sweep_gif(images, frames, nearest)


def load_job_targets(
    job: Path, design: Design
) -> tuple[dict[str, np.ndarray], dict[tuple[str, str], np.ndarray] | None]:
    """Targets of a job: ``design/targets/<view>.npy``, and T_j->k from the target images.

    The cross targets need the views' target pictures; without them only the diagonal is
    available.
    """
    targets: dict[str, np.ndarray] = {}
    for view in design.views:
        path = JobLayout(job).design.target_npy(view.name)
        if path.is_file():
            arr = load_numpy(path)
            if arr.shape != (view.height, view.width) or not np.issubdtype(arr.dtype, np.floating):
                raise ConfigError(
                    f"{path}: expected float (H, W) = ({view.height}, {view.width}) as view "
                    f"'{view.name}' is, got {arr.dtype} {arr.shape}; rerun `scratchfab design`"
                )
            targets[view.name] = arr
    cross = job_cross_targets(design)
    if not targets and cross:
        targets = {k: img for (k, j), img in cross.items() if k == j}
    return targets, cross


def design_targets(
    design: Design,
) -> tuple[dict[str, np.ndarray], dict[tuple[str, str], np.ndarray] | None]:
    """Targets of a design file's views (those that name a target picture)."""
    if not any(v.target for v in design.views):
        return {}, None
    cross = cross_targets(design)
    return {k: img for (k, j), img in cross.items() if k == j}, cross


def run_verify_files(
    design_file: Path,
    scratch_file: Path,
    out_dir: Path,
    settings: VerifySettings = VerifySettings(),
    progress: Say | None = None,
) -> dict[str, Any]:
    """``verify-render --design FILE --scratches CSV --out DIR``: :func:`run_verify` on files.

    The targets (for rho and crosstalk) are the design's target pictures, where it names
    them; the comparison is a fresh analytic render.
    """
    design = load_design(design_file)
    scratches = load_scratches(scratch_file, design.scratch, design.board)
    targets, cross = design_targets(design)
    if progress is not None:
        progress(f"verifying {len(scratches)} scratches, {len(design.views)} views")
    return run_verify(
        design,
        scratches,
        out_dir,
        settings,
        targets=targets,
        cross=cross,
        progress=_under(progress),
    )


def _under(progress: Say | None) -> Say | None:
    """``progress`` for a view's lines: indented under the heading (``verifying ...``)."""
    if progress is None:
        return None
    return lambda line: progress(f"  {line}")


def run_verify_job(
    job: str | Path,
    settings: VerifySettings = VerifySettings(),
    progress: Say | None = None,
    out_dir: str | Path | None = None,
) -> dict[str, Any]:
    """``verify-render JOB``: verify the job's board into ``JOB/verify`` (or ``out_dir``).

    The board is ``JOB/optimize/scratches.csv`` (else ``JOB/design/scratches.csv``, as
    ``render JOB`` picks it); the comparison is ``JOB/optimize/renders`` when that
    belongs to the board verified (and its views), else a fresh analytic render. The metrics' ``comparison``
    names those renders relative to the job folder (``optimize/renders``; absolute when
    ``out_dir`` lies outside the job), or ``render_scratches``.

    Raises:
        ConfigError: When the job lacks the design or a layout.
    """
    folder = Path(job)
    layout = JobLayout(folder)
    design_file, scratch_file = job_inputs(folder)
    stale = stale_layout_warning(folder)
    if stale is not None and progress is not None:
        progress(stale)
    design = load_job_design(design_file)
    scratches = load_scratches(scratch_file, design.scratch, design.board)
    renders_dir = layout.optimize_renders
    analytic: dict[str, np.ndarray] | None = None
    if scratch_file == layout.optimized_scratches and all(
        (renders_dir / f"{v.name}.npy").is_file() for v in design.views
    ):
        analytic = {v.name: load_numpy(renders_dir / f"{v.name}.npy") for v in design.views}
        if any(np.shape(analytic[v.name]) != (v.height, v.width) for v in design.views):
            analytic = None  # renders of other views (a design changed since): not this board's
    out = layout.verify_dir if out_dir is None else Path(out_dir)
    source = "render_scratches"
    if analytic is not None:  # relative to the job when the metrics are in it: a copy's own
        inside = any(  # as named (a verify/ linked elsewhere is the job's) or resolved
            Path(os.path.abspath(a)).is_relative_to(os.path.abspath(b))
            for a, b in ((out, folder), (out.resolve(), folder.resolve()))
        )
        source = layout.relative(renders_dir) if inside else os.path.abspath(renders_dir)
    targets, cross = load_job_targets(folder, design)
    if cross is None and progress is not None:
        progress(
            f"warning: no board pictures in {layout.design.boards_dir}: crosstalk is not "
            "measured (rerun design to write them)"
        )
    if progress is not None:  # the renders by the path the job was named by, as scratch_file
        against = (
            f"the optimizer's renders in {renders_dir}"
            if analytic is not None
            else "a fresh analytic render"
        )
        progress(f"verifying {scratch_file} ({len(scratches)} scratches) against {against}")
    return run_verify(
        design,
        scratches,
        out,
        settings,
        analytic=analytic,
        analytic_source=source,
        targets=targets,
        cross=cross,
        progress=_under(progress),
        feasibility=_read_feasibility(layout.design.feasibility_json),
    )


def _read_feasibility(path: Path) -> dict[str, Any] | None:
    """``design/feasibility.json`` for the gate's advice; None where missing or unreadable."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None
