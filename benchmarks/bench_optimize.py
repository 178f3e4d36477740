"""Benchmark of the optimize stage; prints JSON.

Cases:
- ``demo``: the bundled ``demo`` pipeline through ``design`` then ``optimize``: seconds per
  iteration, time and iterations to the quality bar (every rho_kk >= 0.8 and
  x_kj <= 0.2, from ``log.csv``), final quality by the optimizer's own render and by the
  brute-force reference renderer of the tests.
- ``large``: a 100 mm, 3-view (left, right, and low: 45 degrees below the board's normal,
  opposite the light), 512 x 512 px, 40k-scratch board with analytic targets, starting
  from the tests' uniform random layout (a harder start than the design stage's).
  ``--large-until-bar N`` steps it until the quality bar (measured, up to N steps);
  otherwise a few steps are timed and the time to the bar is extrapolated from the
  demo's iteration count, labelled so.
- ``refresh``: one pair refresh (``LayoutOptimizer._refresh``) on the full-size pipeline
  (150 mm, 3 views) laid out by the design stage at several scratch counts: seconds of
  each part (pixel pairs per view, ``find_pairs`` and the ``raster_pairs`` in it,
  merge-candidate neighbour pairs, the whole refresh with ``--threads`` Dr.Jit threads,
  which finds the merge candidates on a second thread, and on one thread; best of
  ``--refresh-repeats``), the neighbour pairs' peak of numpy memory (tracemalloc), the
  pair counts, and each one's growth exponent (log-log slope over the counts).
- ``steps``: where one step's time goes, on the demo (``--steps-pipeline full-size`` for
  ``pipelines/full-size.toml``, sized by ``--steps-count`` and ``--steps-resolution``):
  mean wall seconds of ``LayoutOptimizer.step`` after the first (which compiles), split
  into Dr.Jit kernel execution (the renderer's pair kernels, forward and backward, apart
  from the rest; from ``dr.kernel_history``), the pair refresh (amortised) and host time
  (tracing, AD bookkeeping, Adam, numpy copies); beside it the stage's per-step extras
  outside ``step``: ``quality_report`` for log.csv and one checkpoint write (every
  ``checkpoint_every`` steps).

``--quick`` runs only the refresh case, small, and the steps case on the demo (seconds).

Usage: python benchmarks/bench_optimize.py [--demo-iterations N] [--large-steps N]
       [--large-until-bar N] [--skip-large] [--skip-demo] [--refresh-counts N,N,..]
       [--skip-refresh] [--steps N] [--steps-pipeline demo|full-size]
       [--steps-count N] [--steps-resolution N] [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from scratchfab.bundled import bundled_dir  # noqa: E402
from scratchfab.metrics import quality_report  # noqa: E402
from scratchfab.model.job import JobLayout  # noqa: E402
from scratchfab.optimize.checkpoint import save_checkpoint  # noqa: E402
from scratchfab.optimize.loss import Space  # noqa: E402
from scratchfab.optimize.optimizer import LayoutOptimizer  # noqa: E402
from scratchfab.optimize.stage import OptimizeOptions, run_optimize  # noqa: E402


def peak_rss_mb() -> int | None:
    """This process's peak resident memory in MB (None where the OS does not say)."""
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return round(peak / (1 << 20) if sys.platform == "darwin" else peak / 1024)  # bytes / KiB


def _bar_row(log: Path) -> dict[str, float] | None:
    with open(log) as fh:
        for row in csv.DictReader(fh):
            rhos = [float(v) for k, v in row.items() if k.startswith("rho_")]
            xs = [float(v) for k, v in row.items() if k.startswith("x_")]
            if all(r >= 0.8 for r in rhos) and all(x <= 0.2 for x in xs):
                return {"iteration": int(row["iteration"]), "seconds": float(row["seconds"])}
    return None


def _summary(q: dict) -> dict:
    return {
        k: {
            "psnr": round(v["psnr"], 2),
            "rho": round(v["rho"], 4),
            "crosstalk": {j: round(x, 4) for j, x in v["crosstalk"].items()},
        }
        for k, v in q["views"].items()
    }


def bench_demo(iterations: int, threads: int, space: Space) -> dict:
    from reference_render import reference_render

    from scratchfab.design.targets import cross_targets
    from scratchfab.model.design import load_design

    with tempfile.TemporaryDirectory() as tmp:
        job = Path(tmp) / "demo"
        _design(job)
        start = time.perf_counter()
        result = run_optimize(
            job, OptimizeOptions(iterations=iterations, threads=threads, space=space)
        )
        wall = time.perf_counter() - start
        layout = JobLayout(job)
        design = load_design(layout.design.design_toml)
        targets = {v.name: np.load(layout.design.target_npy(v.name)) for v in design.views}
        cross = cross_targets(design)
        t0 = time.perf_counter()
        ref = reference_render(
            design, result.scratches, samples_per_pixel=64, across=24, along_step_mm=0.05
        )
        ref_s = time.perf_counter() - t0
        bar = _bar_row(layout.optimize_log)
        with open(layout.optimize_log) as fh:
            first = next(csv.DictReader(fh))
        return {
            "board": "demo: 60 mm, 2 views 80x80 px, 2000 scratches",
            "space": space,
            "threads": threads,
            "iterations": result.iterations,
            "seconds_per_iteration": round(result.seconds_per_iteration, 4),
            "optimize_wall_s": round(wall, 1),
            "quality_bar_reached_at": bar,
            "initial_quality": {
                k: float(v) for k, v in first.items() if k.startswith(("rho_", "x_", "psnr_"))
            },
            "final_quality_own_render": _summary(result.quality),
            "final_quality_reference_render": _summary(quality_report(ref, targets, cross)),
            "reference_render_s": round(ref_s, 1),
        }


def _design(job: Path, pipeline: Path | None = None, *extra: str) -> None:
    from scratchfab.cli import main

    source = pipeline or bundled_dir("pipelines") / "demo.toml"
    try:
        with contextlib.redirect_stdout(sys.stderr):  # stdout carries the JSON alone
            main(["design", str(source), "--out", str(job), *extra])
    except SystemExit as exc:
        if exc.code:
            raise


def _slope(x: list[int], y: list[float]) -> float | None:
    """Least-squares slope of log y against log x (None with fewer than two points)."""
    if len(x) < 2 or min(y) <= 0:
        return None
    return round(float(np.polyfit(np.log(x), np.log(y), 1)[0]), 2)


def bench_refresh(counts: list[int], resolution: int, repeats: int, threads: int) -> dict:
    import drjit as dr

    from scratchfab.backend import array_module
    from scratchfab.model.camera import Camera
    from scratchfab.optimize.loss import neighbour_pairs
    from scratchfab.optimize.optimizer import Settings
    from scratchfab.optimize.stage import load_job_inputs
    from scratchfab.render.pairs import raster_pairs, scratch_rectangles

    m = array_module("llvm")
    dr.set_thread_count(threads if threads > 0 else 2)
    t0 = time.perf_counter()
    neighbour_pairs(np.zeros((2, 2)), np.ones((2, 2)), 1.0)  # loads numba and its scan
    first_call = time.perf_counter() - t0
    t0 = time.perf_counter()
    down = Camera(np.array([0.0, 0.0, 10.0]), -np.eye(3)[2], np.eye(3)[0], np.eye(3)[1], 1, 1, 4, 4)
    raster_pairs(down, np.zeros((1, 4, 2)), np.ones(16, bool))  # loads its compiled scans
    raster_first_call = time.perf_counter() - t0
    rows: list[dict[str, float]] = []
    for count in counts:
        with tempfile.TemporaryDirectory() as tmp:
            job = Path(tmp) / "job"
            pipeline = ROOT / "pipelines" / "full-size.toml"
            _design(job, pipeline, "--count", str(count), "--resolution", str(resolution))
            design, targets, initial = load_job_inputs(job)
        lr = OptimizeOptions().learning_rates()
        opt = LayoutOptimizer(design, targets, initial, Settings(lr=lr), m)
        ends = opt.ends.astype(np.float64)
        p0, p1, half = ends[:, 0:2], ends[:, 2:4], opt.width / 2
        # the reach and angle slack of LayoutOptimizer._refresh
        reach = opt.tool_width + 2 * (opt.margin - float(np.max(half)))
        slack = 2 * opt.settings.refresh_every * float(lr["theta"])
        best: dict[str, float] = {}
        for _ in range(repeats):
            times = {}
            for r in opt.renderers:
                t0 = time.perf_counter()
                r.find_pairs(p0, p1, half, opt.margin)
                times[f"find_pairs_{r.view.name}_s"] = time.perf_counter() - t0
            corners = scratch_rectangles(p0, p1, half, opt.margin)
            for r in opt.renderers:
                t0 = time.perf_counter()
                raster_pairs(r.camera, corners, r.pixel_ok)
                times[f"raster_pairs_{r.view.name}_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            neighbour_pairs(p0, p1, reach, slack, dtype=np.uint32)  # as the refresh calls it
            times["neighbour_pairs_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            opt._refresh(opt.ends)
            times["refresh_s"] = time.perf_counter() - t0
            # on one thread: the merge candidates after the pixel pairs, not beside them
            threads_now = dr.thread_count()
            dr.set_thread_count(1)
            t0 = time.perf_counter()
            opt._refresh(opt.ends)
            times["refresh_one_thread_s"] = time.perf_counter() - t0
            dr.set_thread_count(threads_now)
            best = {k: min(v, best.get(k, math.inf)) for k, v in times.items()}
        row: dict[str, float] = {"scratches": count}
        row.update({k: round(v, 3) for k, v in best.items()})
        # numpy's allocations (tracemalloc sees them; the compiled scan's few are O(n))
        tracemalloc.start()
        neighbour_pairs(p0, p1, reach, slack, dtype=np.uint32)
        row["neighbour_pairs_peak_mb"] = round(tracemalloc.get_traced_memory()[1] / 2**20, 1)
        tracemalloc.stop()
        for v, n in zip(opt.views, opt.pair_counts(), strict=True):
            row[f"pixel_pairs_{v.name}"] = n
        row["neighbour_pairs"] = opt._neighbour_count
        rows.append(row)
        print(f"refresh: {rows[-1]}", file=sys.stderr, flush=True)
    growth = {
        key: _slope(counts, [row[key] for row in rows]) for key in rows[0] if key != "scratches"
    }
    return {
        "board": f"pipelines/full-size.toml: 150 mm, 3 views {resolution}x{resolution} px, "
        "layouts of the design stage",
        "threads": threads,
        "pair_margin_mm": round(opt.margin, 3),
        "neighbour_pairs_first_call_s (loads numba and the compiled scan, once a process)": round(
            first_call, 3
        ),
        "raster_pairs_first_call_s (after neighbour_pairs': loads its compiled scans)": round(
            raster_first_call, 3
        ),
        "repeats (best kept)": repeats,
        "rows": rows,
        "growth_exponent (d log / d log scratches)": growth,
    }


#: Renderer pair kernels have well over a thousand IR operations (the smallest, the
#: forward kernel of the 2-term class of render_classes, about 1,700); every other kernel
#: of a step (projection, Adam, exposure sums, merge penalty, touch masks, piece codes)
#: has a few hundred at most.
PAIR_KERNEL_OPS = 1000


def _time_refreshes(opt: LayoutOptimizer) -> list[float]:
    """Make ``opt`` time each pair refresh; returns the list the seconds are appended to."""
    seconds: list[float] = []
    refresh = opt._refresh

    def timed_refresh(ends: np.ndarray) -> None:
        t0 = time.perf_counter()
        refresh(ends)
        seconds.append(time.perf_counter() - t0)

    opt._refresh = timed_refresh  # type: ignore[method-assign]
    return seconds


def bench_steps(pipeline: str, steps: int, threads: int, count: int, resolution: int) -> dict:
    import drjit as dr

    from scratchfab.backend import array_module
    from scratchfab.design.targets import job_cross_targets
    from scratchfab.optimize.optimizer import Settings
    from scratchfab.optimize.stage import load_job_inputs, log_columns

    m = array_module("llvm")
    dr.set_thread_count(threads if threads > 0 else 2)
    options = OptimizeOptions()
    with tempfile.TemporaryDirectory() as tmp:
        job = Path(tmp) / "job"
        if pipeline == "demo":
            _design(job)
        else:
            source = ROOT / "pipelines" / "full-size.toml"
            _design(job, source, "--count", str(count), "--resolution", str(resolution))
        design, targets, initial = load_job_inputs(job)
        cross = job_cross_targets(design) or {(k, k): t for k, t in targets.items()}
        settings = Settings(lr=options.learning_rates(), refresh_every=options.refresh_every)
        opt = LayoutOptimizer(design, targets, initial, settings, m)
        refresh_s = _time_refreshes(opt)
        names = [v.name for v in opt.views]
        rows: list[list[float]] = []
        rec: dict[str, list[float]] = {
            k: [] for k in ("wall", "refresh", "pair", "other", "codegen", "quality", "ckpt")
        }
        pair_counts: list[int] = []
        active_counts: list[int] = []
        kernels_per_step = 0
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            for i in range(steps + 1):
                dr.kernel_history()  # clears it
                before = len(refresh_s)
                t0 = time.perf_counter()
                result = opt.step()
                wall = time.perf_counter() - t0
                hist = [k for k in dr.kernel_history() if str(k["type"]).endswith("JIT")]
                t1 = time.perf_counter()
                quality_report(result.renders, targets, cross)
                t2 = time.perf_counter()
                rows.append([float(i), result.loss, 0.0] + [0.0] * (len(log_columns(names)) - 3))
                save_checkpoint(
                    Path(tmp) / "checkpoint.npz", opt.state(), {"bench": 1}, np.asarray(rows)
                )
                t3 = time.perf_counter()
                if i == 0:  # compiles (or loads) the kernels
                    continue
                pair = [k for k in hist if k.get("operation_count", 0) >= PAIR_KERNEL_OPS]
                rec["wall"].append(wall)
                rec["refresh"].append(refresh_s[-1] if len(refresh_s) > before else 0.0)
                rec["pair"].append(sum(k["execution_time"] for k in pair) / 1e3)
                rec["other"].append(sum(k["execution_time"] for k in hist) / 1e3 - rec["pair"][-1])
                rec["codegen"].append(sum(k.get("codegen_time", 0.0) for k in hist) / 1e3)
                rec["quality"].append(t2 - t1)
                rec["ckpt"].append(t3 - t2)
                kernels_per_step = max(kernels_per_step, len(hist))
                pair_counts.append(sum(opt.pair_counts()))
                if opt.active is not None:  # the pairs the next step renders
                    active_counts.append(sum(opt.active_counts()))
    mean = {k: float(np.mean(v)) for k, v in rec.items()}
    every = options.checkpoint_every
    # every refresh seen (the first step's too), once per refresh_every steps
    refresh_each = float(np.mean(refresh_s))
    step_s = mean["wall"] - mean["refresh"] + refresh_each / options.refresh_every
    per_step = step_s + mean["quality"] + mean["ckpt"] / every
    host = mean["wall"] - mean["refresh"] - mean["pair"] - mean["other"]
    parts = {
        "renderer pair kernels (forward + backward)": mean["pair"],
        "other Dr.Jit kernels": mean["other"],
        "pair refresh (amortised)": refresh_each / options.refresh_every,
        "host: tracing, AD, Adam, numpy copies": host,
        "quality_report for log.csv": mean["quality"],
        f"checkpoint write / {every}": mean["ckpt"] / every,
    }
    return {
        "board": (
            "demo: 60 mm, 2 views 80x80 px, 2000 scratches"
            if pipeline == "demo"
            else f"pipelines/full-size.toml: {count} scratches, 3 views {resolution}x{resolution} px"
        ),
        "threads": threads,
        "measured_steps": steps,
        "pairs_in_use (all views, mean)": round(float(np.mean(pair_counts))),
        "pairs_rendered (touching, all views, mean)": round(
            float(np.mean(active_counts or pair_counts))
        ),
        "jit_kernels_per_step (most)": kernels_per_step,
        "step_s (LayoutOptimizer.step, refresh amortised)": round(step_s, 4),
        "pair_refresh_s": round(refresh_each, 4),
        "stage_s_per_step (step + log + checkpoint)": round(per_step, 4),
        "codegen_s_per_step (inside the kernels' host time)": round(mean["codegen"], 4),
        "checkpoint_write_s": round(mean["ckpt"], 4),
        "breakdown_s": {k: round(v, 4) for k, v in parts.items()},
        "breakdown_percent": {k: round(100 * v / per_step, 1) for k, v in parts.items()},
    }


def bench_large(
    steps: int,
    threads: int,
    refresh_every: int,
    demo_iterations_to_bar: int | None,
    until_bar: int = 0,
) -> dict:
    import drjit as dr
    from test_optimize_helpers import board_functions, make_layout, warp

    from scratchfab.backend import array_module
    from scratchfab.model.design import design_from_mapping
    from scratchfab.optimize.optimizer import Settings

    m = array_module("llvm")
    dr.set_thread_count(threads if threads > 0 else 2)
    tables = {
        "board": {"width_mm": 100.0, "height_mm": 100.0, "margin_mm": 2.0},
        "light": {"position_mm": [0.0, 187.3, 463.6]},
        "scratch": {"count": 40000, "min_length_mm": 2.0, "max_length_mm": 12.0},
        "views": [
            {
                "name": n,
                "azimuth_deg": az,
                "elevation_deg": el,
                "distance_mm": 500.0,
                "fov_deg": "auto",
                "resolution": [512, 512],
            }
            for n, az, el in (("left", -22.0, 0.0), ("right", 22.0, 0.0), ("low", 0.0, -45.0))
        ],
    }
    design = design_from_mapping(tables, "<bench>", ROOT)
    funcs = board_functions(100.0)
    funcs["low"] = lambda x, y: (np.abs(y) < 25.0) * 0.9 + 0.05  # type: ignore[assignment]
    targets = {v.name: warp(design, funcs[v.name], v, n=2) for v in design.views}
    cross = {
        (k.name, j.name): warp(design, funcs[j.name], k, n=2)
        for k in design.views
        for j in design.views
        if j.name != k.name
    }
    layout = make_layout(design, 40000, seed=1)
    opts = OptimizeOptions()
    lr = opts.learning_rates()
    t0 = time.perf_counter()
    opt = LayoutOptimizer(design, targets, layout, Settings(lr=lr, refresh_every=refresh_every), m)
    setup = time.perf_counter() - t0
    times = []
    # step() refreshes by itself; timing it there keeps it out of the step times
    refresh = _time_refreshes(opt)
    bar: dict | None = None
    quality: dict | None = None
    started = time.perf_counter()
    for _ in range(max(steps, until_bar)):
        seen = len(refresh)
        t2 = time.perf_counter()
        result = opt.step()
        times.append(time.perf_counter() - t2 - sum(refresh[seen:]))
        if until_bar:
            # The step's renders are of the layout before the step (iteration - 1).
            quality = quality_report(result.renders, targets, cross)
            views = quality["views"].values()
            if all(v["rho"] >= 0.8 for v in views) and all(
                x <= 0.2 for v in views for x in v["crosstalk"].values()
            ):
                bar = {
                    "iteration": opt.iteration - 1,
                    "seconds": round(time.perf_counter() - started, 1),
                }
                break
            print(
                f"large: iteration {opt.iteration}, {time.perf_counter() - started:.0f} s, "
                f"rho {[round(v['rho'], 3) for v in views]}",
                file=sys.stderr,
                flush=True,
            )
    steady = times[1:] if len(times) > 1 else times
    per = float(np.mean(steady)) + (float(np.mean(refresh)) / refresh_every if refresh else 0.0)
    out = {
        "board": "100 mm, 3 views 512x512 px, 40000 scratches",
        "threads": threads,
        "refresh_every": refresh_every,
        "pair_margin_mm": round(opt.margin, 3),
        "pairs_per_view": opt.pair_counts(),
        "pairs_rendered_per_view (last step)": opt.active_counts(),
        "setup_s": round(setup, 1),
        "first_step_s (includes kernel compile)": round(times[0], 2),
        "measured_steps": steps,
        "seconds_per_iteration": round(per, 3),
        "pair_refresh_s": round(float(np.mean(refresh)), 2) if refresh else None,
        # the whole process's peak so far: the demo case (run first) peaks far lower
        "peak_rss_mb": peak_rss_mb(),
    }
    if until_bar:
        out["measured_to_quality_bar"] = bar or f"not reached in {until_bar} iterations"
        if quality is not None:
            out["quality_at_stop"] = _summary(quality)
    elif demo_iterations_to_bar is not None:
        out[
            "time_to_quality_bar_s (EXTRAPOLATED: demo's iterations to the bar x measured s/iter)"
        ] = round(max(demo_iterations_to_bar, 1) * per, 1)
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--demo-iterations", type=int, default=150)
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--large-steps", type=int, default=3)
    parser.add_argument("--large-refresh", type=int, default=2)
    parser.add_argument("--skip-large", action="store_true")
    # the test board from a uniform layout crosses the bar after about 40-60 steps
    parser.add_argument("--large-iterations-to-bar", type=int, default=60)
    parser.add_argument(
        "--large-until-bar",
        type=int,
        default=0,
        help="Run the large board up to N iterations until it reaches the bar (measured).",
    )
    parser.add_argument("--spaces", default="linear")
    parser.add_argument("--refresh-counts", default="5000,10000,20000,40000")
    parser.add_argument("--refresh-resolution", type=int, default=512)
    parser.add_argument("--refresh-repeats", type=int, default=3)
    parser.add_argument("--skip-refresh", action="store_true")
    parser.add_argument("--skip-demo", action="store_true")
    parser.add_argument("--steps", type=int, default=20, help="Steps of the steps case.")
    parser.add_argument("--steps-pipeline", choices=("demo", "full-size"), default="demo")
    parser.add_argument("--steps-count", type=int, default=40000)
    parser.add_argument("--steps-resolution", type=int, default=512)
    parser.add_argument("--skip-steps", action="store_true")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="Only the refresh case, at 1000 and 2000 scratches and 128 x 128 px, and the "
        "steps case on the demo, 10 steps (seconds).",
    )
    args = parser.parse_args()
    report: dict = {"machine": "2-core CPU, Dr.Jit LLVM"}
    if args.quick:
        report["refresh"] = bench_refresh([1000, 2000], 128, 1, args.threads)
        report["steps"] = bench_steps("demo", 10, args.threads, 0, 0)
        print(json.dumps(report, indent=2))
        return
    if not args.skip_demo:
        report["demo"] = [
            bench_demo(args.demo_iterations, args.threads, space)
            for space in args.spaces.split(",")
        ]
    if not args.skip_refresh:
        counts = [int(c) for c in args.refresh_counts.split(",")]
        report["refresh"] = bench_refresh(
            counts, args.refresh_resolution, args.refresh_repeats, args.threads
        )
    if not args.skip_steps:
        report["steps"] = bench_steps(
            args.steps_pipeline, args.steps, args.threads, args.steps_count, args.steps_resolution
        )
    if not args.skip_large:
        report["large"] = bench_large(
            args.large_steps,
            args.threads,
            args.large_refresh,
            args.large_iterations_to_bar,
            args.large_until_bar,
        )
    print(
        json.dumps(
            report,
            indent=2,
            default=lambda v: None if isinstance(v, float) and not math.isfinite(v) else str(v),
        )
    )


if __name__ == "__main__":
    main()
