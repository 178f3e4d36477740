"""Benchmark of the optimizer's result quality against its settings; prints JSON.

Each case changes a few settings from the pipeline's own (``[optimize]`` and the design's
scratch count) and runs ``design`` (once per layout seed and count) then ``optimize`` on
every layout seed. Per case and seed it records the final loss (fresh pairs) and its
image part (the mean of the views' E_k, without the merge and bound penalties), each
view's PSNR and rho_kk, the largest crosstalk x_kj, the length cut twice as the merge
penalty counts it (``length_cut_twice_mm``: pairs within 35 degrees of parallel, each
weighed by how close, :func:`~scratchfab.optimize.loss.length_cut_twice`), the scratches
closer than the tool and within 10 degrees of parallel (``within_10deg_*``: which both
renderers add as if each were alone, while the machine cuts one wider dent: their count,
how many of them cross, and their length cut twice unweighted), the total cut length
(``cut_length_mm``) and the share of it cut twice (``cut_twice_share``), the optimize
stage's wall time and seconds per step, and the loss and mean PSNR along the way (from
``log.csv``: a loss still falling at the end asks for more iterations, a flat tail for
fewer). Per case it gives the means over seeds and, against the first case, the paired differences (mean and
sample standard deviation over seeds) in per cent or dB, among them the loss each case
had reached when the first case's run ended (``loss_at_reference_time``: which setting
is better in the same time). ``--verify SPP`` also renders each result in Mitsuba
(``verify-render``, no sweep) and reports its PSNR and rho, to check that a gain is not
the optimizer's own renderer's.

The optimize stage with ``jitter_deg = 0`` (the default) draws nothing at random, so
the seeds that vary a run are the design stage's layout seeds (``--seeds``).

A case is a comma-separated list of ``key=value``: any field of
:class:`~scratchfab.optimize.options.OptimizeOptions` (``iterations``,
``lr_position_mm``, ``refresh_every``, ``prune_tolerance``, ``lr_start_scale``, ...),
``count`` (the design's scratch count) or ``lr_scale`` (multiplies the three learning
rates); ``default`` is the pipeline as it is. A value is JSON, or else a word
(``lr_schedule=linear``). Cases are separated by ``;``.

``--pipeline full`` is the repository's ``pipelines/full-size.toml`` (40,000 scratches,
three views at 512 x 512: about 2 s a step on 2 CPU cores, 10 minutes a run). A line
every ``--progress`` steps on stderr shows a long run's progress.

Usage: python benchmarks/bench_quality.py [--pipeline demo|full|FILE.toml] [--seeds 0,1,2]
       [--iterations N] [--cases "default;lr_scale=2;refresh_every=16"]
       [--count N] [--resolution N] [--verify SPP] [--threads N] [--progress N] [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import json
import math
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from scratchfab.design.stage import run_design
from scratchfab.model.job import JobLayout
from scratchfab.optimize.loss import length_cut_twice, segment_distance_np
from scratchfab.optimize.options import OptimizeOptions
from scratchfab.optimize.stage import Progress, run_optimize
from scratchfab.pipeline.config import load_pipeline

#: The cases the study runs by default: the pipeline's settings, then one change each.
DEFAULT_CASES = (
    "default",
    "lr_scale=0.5",
    "lr_scale=2",
    "lr_scale=4",
    "lr_start_scale=3,lr_end_scale=0.5",
    "lr_position_mm=0.1",
    "lr_angle_deg=1.0",
    "lr_length_mm=0.1",
    "refresh_every=4",
    "refresh_every=16",
    "merge_weight=0",
    "merge_weight=0.05",
    "jitter_deg=3",
    "count=1000",
    "count=3000",
)

QUICK_CASES = ("default", "lr_scale=2")

#: ``--pipeline`` names beyond the bundled ones: the repository's example pipelines.
REPO_PIPELINES = {"full": Path(__file__).resolve().parents[1] / "pipelines" / "full-size.toml"}

#: Pairs within this many degrees of parallel are the ``within_10deg_*`` figures.
NEAR_PARALLEL_DEG = 10.0
#: The figures of :func:`cut_twice`, averaged per case.
CUT_TWICE_KEYS = (
    "length_cut_twice_mm",
    "within_10deg_pairs",
    "within_10deg_crossing",
    "within_10deg_length_mm",
)

#: Keys a case may set beyond OptimizeOptions' fields.
EXTRA_KEYS = ("count", "lr_scale")


def parse_case(text: str, base: OptimizeOptions) -> tuple[OptimizeOptions, int | None]:
    """The options and design count (None: the design's) of one case's text."""
    text = text.strip()
    fields = {f.name: f for f in dataclasses.fields(OptimizeOptions)}
    changes: dict[str, Any] = {}
    count: int | None = None
    scale = 1.0
    if text != "default":
        for item in text.split(","):
            key, sep, raw = item.partition("=")
            key = key.strip()
            if not sep or (key not in fields and key not in EXTRA_KEYS):
                raise SystemExit(f"bench_quality: case {text!r}: unknown setting {key!r}")
            value: Any = None
            if raw.strip() not in ("", "none"):
                try:
                    value = json.loads(raw)
                except json.JSONDecodeError:
                    value = raw.strip()
            if key == "count":
                count = int(value)
            elif key == "lr_scale":
                scale = float(value)
            else:
                changes[key] = value
    options = dataclasses.replace(base, **changes)
    if scale != 1.0:
        options = dataclasses.replace(
            options,
            lr_position_mm=options.lr_position_mm * scale,
            lr_angle_deg=options.lr_angle_deg * scale,
            lr_length_mm=options.lr_length_mm * scale,
        )
    return options, count


def read_log(path: Path) -> list[dict[str, float]]:
    """Rows of ``log.csv`` as floats."""
    with open(path) as fh:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(fh)]


def mean_psnr(row: dict[str, Any], names: list[str]) -> float:
    """Mean of the views' PSNR in a log row."""
    return statistics.fmean(float(row[f"psnr_{k}"]) for k in names)


def curve(rows: list[dict[str, float]], names: list[str], points: int = 8) -> list[list[float]]:
    """[iteration, seconds, loss, mean PSNR] at about ``points`` evenly spaced log rows."""
    if not rows:
        return []
    picks = sorted({round(i * (len(rows) - 1) / (points - 1)) for i in range(points)})
    return [
        [
            int(rows[i]["iteration"]),
            round(rows[i]["seconds"], 2),
            round(rows[i]["loss"], 6),
            round(mean_psnr(rows[i], names), 3),
        ]
        for i in picks
    ]


def tail_drop(rows: list[dict[str, float]], fraction: float = 0.25) -> float:
    """Relative loss drop over the last ``fraction`` of the logged steps (0: flat)."""
    if len(rows) < 4:
        return math.nan
    start = rows[int((1 - fraction) * (len(rows) - 1))]["loss"]
    return (start - rows[-1]["loss"]) / start if start > 0 else math.nan


def image_error(job: Path, names: list[str]) -> float:
    """Mean over views of the loss's linear image error E_k (no merge or bound penalty)."""
    layout = JobLayout(job)
    errors = []
    for k in names:
        render = np.load(layout.optimize_renders / f"{k}.npy").astype(np.float64)
        target = np.load(layout.design.target_npy(k))
        ok = np.isfinite(target)
        r, t = render[ok], target[ok]
        s = float(r @ t) / max(float(r @ r), 1e-300)
        errors.append(float(np.sum((s * r - t) ** 2)) / max(float(t @ t), 1e-300))
    return statistics.fmean(errors)


def cut_twice(scratches: Any) -> dict[str, float]:
    """The length the machine cuts twice: as the merge penalty counts it, and unweighted.

    Returns ``length_cut_twice_mm``, the merge penalty's sum over the pairs the final
    loss takes (within 35 degrees of parallel and closer than the tool's width, each the
    mean of the two scratches' lengths within the width of the other weighted by
    relu(1 - q / w)^2: :func:`~scratchfab.optimize.loss.length_cut_twice`), and of those
    pairs the ones within NEAR_PARALLEL_DEG (10) of parallel, which both renderers add as if each
    were alone where the machine cuts one wider dent: ``within_10deg_pairs`` (their
    count), ``within_10deg_crossing`` (those that cross, whatever their ends' distances)
    and ``within_10deg_length_mm`` (the same mean length, unweighted: side by side a
    pair counts its shared length, crossing at angle a about 2 w / sin(a)).
    """
    tool = float(np.max(scratches.width))
    p0, p1 = scratches.p0, scratches.p1
    i, j, weighted = length_cut_twice(p0, p1, tool)
    out = {
        "length_cut_twice_mm": float(weighted.sum()),
        "within_10deg_pairs": 0,
        "within_10deg_crossing": 0,
        "within_10deg_length_mm": 0.0,
    }
    if len(i) == 0:
        return out
    i, j = i.astype(np.int64), j.astype(np.int64)
    d = segment_distance_np(p0, p1, i, j)
    u = p1 - p0
    u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    cos = np.abs(np.sum(u[i] * u[j], axis=1))
    keep = (d < tool) & (cos >= math.cos(math.radians(NEAR_PARALLEL_DEG)))
    i, j = i[keep], j[keep]
    length = 0.5 * (near_length(p0, p1, i, j, tool) + near_length(p0, p1, j, i, tool))
    out["within_10deg_pairs"] = int(len(i))
    out["within_10deg_crossing"] = int(np.count_nonzero(d[keep] == 0))
    out["within_10deg_length_mm"] = float(length.sum())
    return out


def near_length(
    p0: np.ndarray, p1: np.ndarray, i: np.ndarray, j: np.ndarray, reach: float, rounds: int = 48
) -> np.ndarray:
    """Length of each segment i that lies closer than ``reach`` to segment j.

    The distance from a point running along segment i to segment j is convex in the
    running parameter, so the close part is one interval: a golden-section search finds
    the nearest point, bisections on either side the interval's ends (``rounds`` halvings
    each, far below a micrometre on any board).
    """
    a, e = p0[i], p1[i] - p0[i]
    c, f = p0[j], p1[j] - p0[j]
    ff = np.maximum(np.sum(f * f, axis=1), 1e-300)

    def dist(t: np.ndarray) -> np.ndarray:
        q = a + t[:, None] * e - c
        s = np.clip(np.sum(q * f, axis=1) / ff, 0.0, 1.0)
        return np.linalg.norm(q - s[:, None] * f, axis=1)

    g = (math.sqrt(5.0) - 1.0) / 2.0
    lo, hi = np.zeros(len(i)), np.ones(len(i))
    for _ in range(rounds):
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        left = dist(m1) < dist(m2)
        hi = np.where(left, m2, hi)
        lo = np.where(left, lo, m1)
    best = 0.5 * (lo + hi)
    inside = dist(best) < reach

    def edge(end: float) -> np.ndarray:
        near, far = best.copy(), np.full(len(i), end)
        for _ in range(rounds):
            mid = 0.5 * (near + far)
            close = dist(mid) < reach
            near = np.where(close, mid, near)
            far = np.where(close, far, mid)
        return np.where(dist(np.full(len(i), end)) < reach, end, near)

    start, end = edge(0.0), edge(1.0)
    return np.where(inside, (end - start) * np.linalg.norm(e, axis=1), 0.0)


def progress_printer(label: str, every: int) -> Callable[[Progress], None]:
    """A progress callback that prints every ``every`` steps (and the last) to stderr."""

    def report(p: Progress) -> None:
        if every > 0 and not p.message and (p.iteration % every == 0 or p.iteration == p.total):
            print(
                f"  {label}: step {p.iteration}/{p.total} loss {p.loss:.5f} "
                f"{p.elapsed_s:.0f} s, about {p.eta_s:.0f} s left",
                file=sys.stderr,
                flush=True,
            )

    return report


def run_one(
    design_job: Path,
    work: Path,
    options: OptimizeOptions,
    verify_spp: int,
    progress: Callable[[Progress], None] | None = None,
) -> dict[str, Any]:
    """Optimize a copy of ``design_job`` with ``options``; the figures of the result."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    shutil.copytree(design_job / "design", work / "design")
    t0 = time.perf_counter()
    result = run_optimize(work, options, progress=progress)
    wall = time.perf_counter() - t0
    quality = result.quality
    names = list(quality["names"])
    rows = read_log(JobLayout(work).optimize_log)
    crosstalk = [x for k in names for x in quality["views"][k]["crosstalk"].values()]
    cut_length = float(np.hypot(*(result.scratches.p1 - result.scratches.p0).T).sum())
    twice = cut_twice(result.scratches)
    out: dict[str, Any] = {
        "loss": result.loss,
        "image_error": image_error(work, names),
        **twice,
        "cut_twice_share": twice["length_cut_twice_mm"] / max(cut_length, 1e-300),
        "psnr": {k: quality["views"][k]["psnr"] for k in names},
        "rho": {k: quality["views"][k]["rho"] for k in names},
        "psnr_mean": statistics.fmean(quality["views"][k]["psnr"] for k in names),
        "rho_min": min(quality["views"][k]["rho"] for k in names),
        "crosstalk_max": max(crosstalk) if crosstalk else math.nan,
        "scratches": len(result.scratches),
        "cut_length_mm": cut_length,
        "seconds": wall,
        "seconds_per_iteration": result.seconds_per_iteration,
        "tail_drop": tail_drop(rows),
        "curve": curve(rows, names),
        "_trace": [(r["seconds"], r["loss"]) for r in rows],
    }
    if result.prune is not None:
        out["prune_removed"] = result.prune.removed
        out["prune_time_saved_s"] = result.prune.time_saved_s
    if verify_spp > 0:
        from scratchfab.verify.verify import VerifySettings, run_verify_job

        metrics = run_verify_job(work, VerifySettings(spp=verify_spp))
        views = metrics["views"]
        out["verify"] = {
            "psnr": {k: views[k]["psnr"] for k in names},
            "rho": {k: views[k]["rho"] for k in names},
            "psnr_mean": statistics.fmean(views[k]["psnr"] for k in names),
            "noise": {k: views[k]["noise"] for k in names},
        }
    return out


def loss_at(trace: list[tuple[float, float]], seconds: float, final: float) -> float:
    """The loss a run had reached after ``seconds`` of optimizing (its final if it ended)."""
    if not trace or trace[-1][0] <= seconds:
        return final
    before = [loss for t, loss in trace if t <= seconds]
    return before[-1] if before else trace[0][1]


def paired(case: list[dict[str, Any]], ref: list[dict[str, Any]]) -> dict[str, Any]:
    """Differences from the reference case, seed by seed: [mean, sample deviation]."""

    def stats(key: str, ref_key: str | None = None, ratio: bool = True) -> list[float]:
        values = [
            100 * (c[key] / r[ref_key or key] - 1) if ratio else c[key] - r[ref_key or key]
            for c, r in zip(case, ref, strict=True)
        ]
        sd = statistics.stdev(values) if len(values) > 1 else math.nan
        return [round(statistics.fmean(values), 3), round(sd, 3)]

    return {
        "loss_pct": stats("loss"),
        "image_error_pct": stats("image_error"),
        "psnr_mean_db": stats("psnr_mean", ratio=False),
        "length_cut_twice_pct": stats("length_cut_twice_mm"),
        "within_10deg_pairs_pct": stats("within_10deg_pairs"),
        "within_10deg_length_pct": stats("within_10deg_length_mm"),
        "seconds_pct": stats("seconds"),
        "seconds_per_iteration_pct": stats("seconds_per_iteration"),
        "loss_at_reference_time_pct": stats("loss_at_reference_time", "loss"),
    }


def main(argv: list[str] | None = None) -> None:
    """Run the cases and print the JSON report."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--pipeline", default="demo", help="bundled name, 'full' (full-size) or pipeline file"
    )
    parser.add_argument("--seeds", default="0,1,2", help="layout seeds, comma-separated")
    parser.add_argument("--iterations", type=int, help="steps (default: the pipeline's)")
    parser.add_argument("--cases", help="cases separated by ';' (see the module's help)")
    parser.add_argument("--count", type=int, help="design scratch count (default: the file's)")
    parser.add_argument("--resolution", type=int, help="every view's resolution, square")
    parser.add_argument("--verify", type=int, default=0, metavar="SPP", help="Mitsuba check")
    parser.add_argument("--threads", type=int, default=1, help="optimize threads (1: exact)")
    parser.add_argument("--progress", type=int, default=25, help="steps between lines (0: none)")
    parser.add_argument("--quick", action="store_true", help="one seed, 40 steps, 2 cases")
    parser.add_argument("--keep", type=Path, help="keep the job folders under this folder")
    args = parser.parse_args(argv)

    pipe = load_pipeline(REPO_PIPELINES.get(args.pipeline, args.pipeline))
    seeds = [0] if args.quick else [int(s) for s in args.seeds.split(",")]
    iterations = 40 if args.quick else args.iterations
    texts = (
        [c for c in args.cases.split(";") if c.strip()]
        if args.cases
        else list(QUICK_CASES if args.quick else DEFAULT_CASES)
    )
    base = dataclasses.replace(
        pipe.optimize,
        threads=args.threads,
        resume=False,
        iterations=pipe.optimize.iterations if iterations is None else iterations,
    )
    cases = {t: parse_case(t, base) for t in texts}
    resolution = (args.resolution, args.resolution) if args.resolution else None

    with contextlib.ExitStack() as stack:
        root = (
            args.keep
            if args.keep is not None
            else Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="bench_quality-")))
        )
        designs: dict[tuple[int, int | None], Path] = {}
        results: dict[str, list[dict[str, Any]]] = {}
        for text, (options, count) in cases.items():
            count = count if count is not None else args.count
            runs = []
            for seed in seeds:
                key = (seed, count)
                if key not in designs:
                    job = root / f"design-s{seed}-n{count or 'file'}"
                    if job.exists():
                        shutil.rmtree(job)
                    run_design(pipe.path, job, count=count, resolution=resolution, seed=seed)
                    designs[key] = job
                slug = "".join(c if c.isalnum() or c in "._-" else "_" for c in text)
                label = f"{text} seed {seed}"
                report_step = progress_printer(label, args.progress)
                run = run_one(
                    designs[key], root / f"{slug}-s{seed}", options, args.verify, report_step
                )
                run["seed"] = seed
                runs.append(run)
                print(
                    f"{text} seed {seed}: loss {run['loss']:.5f} psnr {run['psnr_mean']:.2f} "
                    f"cut twice {run['length_cut_twice_mm']:.0f} of "
                    f"{run['cut_length_mm']:.0f} mm, {run['seconds']:.1f} s",
                    file=sys.stderr,
                )
            results[text] = runs

    ref = results[texts[0]]
    for runs in results.values():
        for run, r in zip(runs, ref, strict=True):
            run["loss_at_reference_time"] = loss_at(run["_trace"], r["_trace"][-1][0], run["loss"])
    for runs in results.values():
        for run in runs:
            del run["_trace"]
    report: dict[str, Any] = {
        "pipeline": str(pipe.path),
        "seeds": seeds,
        "iterations": base.iterations,
        "threads": args.threads,
        "reference_case": texts[0],
        "curve_columns": ["iteration", "seconds", "loss", "psnr_mean"],
        "cases": {},
    }
    for text, runs in results.items():
        entry: dict[str, Any] = {
            "loss": statistics.fmean(r["loss"] for r in runs),
            "image_error": statistics.fmean(r["image_error"] for r in runs),
            **{key: statistics.fmean(r[key] for r in runs) for key in CUT_TWICE_KEYS},
            "psnr_mean": statistics.fmean(r["psnr_mean"] for r in runs),
            "rho_min": statistics.fmean(r["rho_min"] for r in runs),
            "crosstalk_max": statistics.fmean(r["crosstalk_max"] for r in runs),
            "seconds": statistics.fmean(r["seconds"] for r in runs),
            "cut_length_mm": statistics.fmean(r["cut_length_mm"] for r in runs),
            "cut_twice_share": statistics.fmean(r["cut_twice_share"] for r in runs),
            "tail_drop": statistics.fmean(r["tail_drop"] for r in runs),
            "vs_reference": paired(runs, ref),
            "runs": runs,
        }
        if all("verify" in r for r in runs):
            entry["verify_psnr_mean"] = statistics.fmean(r["verify"]["psnr_mean"] for r in runs)
        report["cases"][text] = entry
    print(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
