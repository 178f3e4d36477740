"""The ``verify-render`` stage: render the board in Mitsuba 3 and compare.

Every view is rendered twice at half the sample count with independent seeds. The
output image is their mean, and ``|A - B| / 2`` estimates its Monte Carlo error, so the
reported noise level costs no extra samples. The comparison target is the analytic
``render`` of the same board (``JOB/optimize/renders`` or
:func:`scratchfab.render.renderer.render_scratches`); it is only read, never used to
render. Quality measures follow SPEC section 7 (:mod:`scratchfab.metrics`).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scratchfab.backend import BackendName
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.fileio import write_bytes, write_text
from scratchfab.metrics import quality_report
from scratchfab.model.design import Design, View, load_design
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.verify.jitter import Tolerance, jitter_scratches
from scratchfab.verify.scene import Sky, board_bsdf, scene_dict, use_variant
from scratchfab.verify.sweep import gif_bytes, nearest_frames, sweep_path

#: Samples per pixel by default: about 1-2 % noise at footprints of a few scratch widths.
DEFAULT_SPP = 4096
#: Sweep frames get at most this many samples per pixel.
SWEEP_SPP = 1024

Progress = Callable[[str], None]


class VerifyGateError(ScratchfabError):
    """A view's rho_kk fell below ``--min-rho``: the board should not be cut."""

    exit_code = 3


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
    """

    spp: int = DEFAULT_SPP
    seed: int = 0
    backend: BackendName = "llvm"
    sky: Sky | None = None
    sweep: int = 0
    jitter: Tolerance | None = None
    min_rho: float | None = None


@dataclass(frozen=True)
class ViewRender:
    """One view's Mitsuba render.

    Attributes:
        image: (H, W) float32 linear radiance, the mean of two half renders.
        noise: Estimated relative L2 error of ``image`` (|A - B| / (2 |image|)).
        spp: Samples per pixel actually taken (both halves).
        seconds: Wall time of both halves.
    """

    image: np.ndarray
    noise: float
    spp: int
    seconds: float


def half_spp(spp: int) -> int:
    """Samples of each half, rounded to the a x b grid the multi-jitter sampler uses."""
    n = max(1, math.ceil(spp / 2))
    a = max(1, math.isqrt(n))
    return a * math.ceil(n / a)


class BoardRenderer:
    """Mitsuba renders of one board for any camera (the plugin's grid is built once).

    Args:
        design: Board, light and views.
        scratches: The layout.
        backend: ``"llvm"`` or ``"cuda"``.
        sky: Add the sun-and-sky emitter (renders in the RGB variant, stores luminance).
        flat_weight: The plugin's overlap rule, ``"signed"`` (SPEC section 4) or
            ``"clamped"`` (see :mod:`scratchfab.verify.bsdf`).
    """

    def __init__(
        self,
        design: Design,
        scratches: ScratchSet,
        backend: BackendName = "llvm",
        sky: Sky | None = None,
        flat_weight: str = "signed",
    ) -> None:
        self.mi = use_variant(backend, color=sky is not None)
        self.design = design
        self.scratches = scratches
        self.sky = sky
        self.bsdf = self.mi.load_dict(board_bsdf(design, scratches, flat_weight))

    def render(self, view: View, spp: int, seed: int = 0) -> ViewRender:
        """Render ``view`` with ``spp`` samples per pixel in two independent halves."""
        mi = self.mi
        half = half_spp(spp)
        start = time.perf_counter()
        scene = mi.load_dict(
            scene_dict(self.design, self.scratches, view, half, sky=self.sky, bsdf=self.bsdf)
        )
        halves = []
        for k in range(2):
            img = mi.render(scene, spp=half, seed=2 * seed + k)
            halves.append(np.array(img, dtype=np.float64).reshape(view.height, view.width))
        seconds = time.perf_counter() - start
        a, b = halves
        mean = 0.5 * (a + b)
        norm = float(np.linalg.norm(mean))
        noise = float(np.linalg.norm(a - b)) / (2.0 * norm) if norm > 0 else 0.0
        return ViewRender(mean.astype(np.float32), noise, 2 * half, seconds)


def relative_l2(image: np.ndarray, reference: np.ndarray) -> float:
    """|image - reference| / |reference| over the finite pixels (inf for a black reference)."""
    ok = np.isfinite(image) & np.isfinite(reference)
    diff = np.asarray(image, np.float64)[ok] - np.asarray(reference, np.float64)[ok]
    ref = float(np.linalg.norm(np.asarray(reference, np.float64)[ok]))
    return float(np.linalg.norm(diff)) / ref if ref > 0 else math.inf


def _json_safe(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return _json_safe(value.item())
    return value


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
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Render every view in Mitsuba, compare with the analytic render, write the results.

    Writes ``out_dir/<view>.npy`` and ``.png`` (the render layout), ``metrics.json`` and,
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

    Returns:
        The metrics (also in ``metrics.json``).

    Raises:
        VerifyGateError: After writing everything, when a view's rho_kk < ``min_rho``.
    """
    say = progress or (lambda _msg: None)
    out = Path(out_dir)
    targets = dict(targets or {})
    if analytic is None:
        from scratchfab.render.renderer import render_scratches

        analytic = render_scratches(design, scratches, settings.backend)
        analytic_source = "render_scratches"

    renderer = BoardRenderer(design, scratches, settings.backend)
    results: dict[str, ViewRender] = {}
    for i, view in enumerate(design.views):
        result = renderer.render(view, settings.spp, settings.seed + 1000 * i)
        results[view.name] = result
        say(
            f"verify {view.name}: {view.width}x{view.height} px, {result.spp} spp, "
            f"noise {100 * result.noise:.2f} %, {result.seconds:.1f} s"
        )
    images = {name: r.image for name, r in results.items()}
    quality = _quality(images, targets, cross)

    views: dict[str, Any] = {}
    for view in design.views:
        r = results[view.name]
        entry: dict[str, Any] = {
            "spp": r.spp,
            "seconds": r.seconds,
            "noise": r.noise,
            "rel_l2": None,
            "resolution": [view.width, view.height],
        }
        reference = analytic.get(view.name)
        if reference is not None:
            if reference.shape != r.image.shape:
                raise ConfigError(
                    f"{analytic_source}: view {view.name}: analytic render has shape "
                    f"{reference.shape}, the view is {r.image.shape}"
                )
            entry["rel_l2"] = relative_l2(r.image, reference)
            entry["psnr_vs_render"] = _psnr_vs(r.image, reference)
        q = quality["views"].get(view.name)
        if q is not None:
            entry.update(
                exposure=q["exposure"],
                psnr=q["psnr"],
                rho=q["rho"],
                rho_to=q["rho_to"],
                crosstalk=q["crosstalk"],
            )
        views[view.name] = entry
        rel = entry["rel_l2"]
        say(
            f"verify {view.name}: relative L2 vs render "
            + (f"{100 * rel:.2f} %" if rel is not None else "n/a")
            + (f", rho {entry['rho']:.3f}" if "rho" in entry else "")
        )

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
    if settings.min_rho is not None:
        for name in names:
            rho = views[name].get("rho")
            if rho is not None and not rho >= settings.min_rho:
                failing.append(name)
        metrics["gate"] = {
            "min_rho": settings.min_rho,
            "passed": not failing,
            "failing": failing,
            "unchecked": [n for n in names if views[n].get("rho") is None],
        }

    _write_layout(out, images)
    if sweep_gif is not None:
        write_bytes(out / "sweep.gif", sweep_gif)
    write_text(out / "metrics.json", json.dumps(_json_safe(metrics), indent=2) + "\n")
    if failing:
        worst = min(failing, key=lambda n: views[n]["rho"])
        raise VerifyGateError(
            f"view {worst}: rho_kk {views[worst]['rho']:.3f} is below --min-rho "
            f"{settings.min_rho:g} ({len(failing)} of {len(names)} views fail; see "
            f"{out / 'metrics.json'})"
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
    say: Progress,
) -> dict[str, Any]:
    assert settings.sky is not None
    renderer = BoardRenderer(
        design, scratches, settings.backend, sky=settings.sky, flat_weight="clamped"
    )
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
    say: Progress,
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
            f"jitter {name}: rho {q['rho']:.3f}"
            + (f" (drop {entry['rho_drop']:+.3f})" if "rho_drop" in entry else "")
        )
    return {"tolerance": settings.jitter.as_dict(), "views": views}


def _run_sweep(
    design: Design, scratches: ScratchSet, settings: VerifySettings, say: Progress
) -> tuple[dict[str, Any], bytes]:
    frames, view_params = sweep_path(design, settings.sweep)
    renderer = BoardRenderer(design, scratches, settings.backend, flat_weight="clamped")
    spp = min(settings.spp, SWEEP_SPP)
    images = []
    for i, frame in enumerate(frames):
        images.append(renderer.render(frame.view, spp, settings.seed + 7 * i + 1).image)
        if (i + 1) % 10 == 0 or i + 1 == len(frames):
            say(f"sweep: {i + 1}/{len(frames)} frames")
    info = {
        "frames": len(frames),
        "spp": 2 * half_spp(spp),
        "gif": "sweep.gif",
        "nearest_frame": nearest_frames(frames, view_params),
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
    return info, gif_bytes(images)


def load_job_targets(
    job: Path, design: Design
) -> tuple[dict[str, np.ndarray], dict[tuple[str, str], np.ndarray] | None]:
    """Targets of a job: ``design/targets/<view>.npy``, and T_j->k from the target images.

    The cross targets need the views' target pictures; without them only the diagonal is
    available.
    """
    targets: dict[str, np.ndarray] = {}
    for view in design.views:
        path = job / "design" / "targets" / f"{view.name}.npy"
        if path.is_file():
            targets[view.name] = np.load(path, allow_pickle=False)
    cross = None
    try:
        from scratchfab.design.targets import cross_targets

        cross = cross_targets(design)
    except (ImportError, ScratchfabError, OSError):
        cross = None
    if not targets and cross:
        targets = {k: img for (k, j), img in cross.items() if k == j}
    return targets, cross


def design_targets(
    design: Design,
) -> tuple[dict[str, np.ndarray], dict[tuple[str, str], np.ndarray] | None]:
    """Targets of a design file's views (those that name a target picture)."""
    if not any(v.target for v in design.views):
        return {}, None
    from scratchfab.design.targets import cross_targets

    cross = cross_targets(design)
    return {k: img for (k, j), img in cross.items() if k == j}, cross


def run_verify_job(
    job: str | Path, settings: VerifySettings = VerifySettings(), progress: Progress | None = None
) -> dict[str, Any]:
    """``verify-render JOB``: verify the job's board into ``JOB/verify``.

    The board is ``JOB/optimize/scratches.csv`` (else ``JOB/design/scratches.csv``, as
    ``render JOB`` picks it); the comparison is ``JOB/optimize/renders`` when that
    belongs to the board verified, else a fresh analytic render.

    Raises:
        ConfigError: When the job lacks the design or a layout.
    """
    from scratchfab.render.layout import job_inputs

    folder = Path(job)
    design_file, scratch_file = job_inputs(folder)
    design = load_design(design_file)
    scratches = load_scratches(scratch_file, design.scratch, design.board)
    renders_dir = folder / "optimize" / "renders"
    analytic: dict[str, np.ndarray] | None = None
    if scratch_file.parent.name == "optimize" and all(
        (renders_dir / f"{v.name}.npy").is_file() for v in design.views
    ):
        analytic = {
            v.name: np.load(renders_dir / f"{v.name}.npy", allow_pickle=False) for v in design.views
        }
    source = str(renders_dir) if analytic is not None else "render_scratches"
    targets, cross = load_job_targets(folder, design)
    if progress is not None:
        progress(f"verifying {scratch_file} ({len(scratches)} scratches) against {source}")
    return run_verify(
        design,
        scratches,
        folder / "verify",
        settings,
        analytic=analytic,
        analytic_source=source,
        targets=targets,
        cross=cross,
        progress=progress,
    )
