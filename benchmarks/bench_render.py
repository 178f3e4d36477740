"""Benchmark of the analytic renderer: forward, forward+backward, pairs/s, peak memory.

Usage: python benchmarks/bench_render.py [--scratches 1000 10000 100000]
       [--resolutions 128 256 512] [--backend llvm] [--budget-s 240] [--out FILE]

Every (scratches, resolution) case renders two views (cameras 20 degrees left and right
of a 100 mm board, light above) in its own subprocess, so ``peak_rss_mib`` is that case's
peak resident memory (Dr.Jit's LLVM arrays live in host memory) and ``rss_growth_mib``
what the case added over the imports. Times are the best of ``--repeat`` runs after one
warm-up (kernel compilation excluded; Python tracing included). A case whose estimated
forward+backward time exceeds ``--budget-s`` is not run: its figures are extrapolated
from the measured pair count (pair finding is cheap and always run) and the throughput of
the largest case that did run, and marked ``"extrapolated": true``.

The JSON also holds the arithmetic per pair, counted from the LLVM IR Dr.Jit generates
(floating-point instructions per SIMD lane; an FMA counts 2), the measured float64 FMA
throughput of this machine through Dr.Jit, and the resulting fraction of that limit.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FLOP_RE = re.compile(
    r"= (?:reassoc |nnan |ninf |nsz |arcp |contract |afn |fast )*"
    r"(fadd|fsub|fmul|fdiv|fneg|call [^@]*@llvm\.(?:fma|sqrt|maximum|minimum|fabs|minnum|maxnum))"
    r"[ .]"
)


def count_flops(ir: str) -> int:
    """Floating-point operations per SIMD lane in an LLVM kernel (FMA counts 2)."""
    total = 0
    for match in FLOP_RE.finditer(ir):
        total += 2 if "llvm.fma" in match.group(1) else 1
    return total


class RssSampler:
    """Peak resident memory (MiB) of this process while active, sampled from /proc."""

    def __init__(self, period_s: float = 0.002) -> None:
        self.period_s = period_s
        self.peak = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @staticmethod
    def current() -> float:
        with open("/proc/self/statm") as handle:
            pages = int(handle.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self.current())
            time.sleep(self.period_s)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def make_case(n: int, res: int, seed: int = 0):
    from scratchfab.model.design import design_from_mapping
    from scratchfab.model.scratches import ScratchSet

    tables = {
        "board": {"width_mm": 100.0, "height_mm": 100.0, "roughness": 0.05, "margin_mm": 2.0},
        "light": {"position_mm": [0.0, 180.0, 480.0]},
        "scratch": {"width_mm": 0.1, "depth_mm": 0.01},
        "views": [
            {
                "name": name,
                "position_mm": [x, 0.0, 480.0],
                "fov_deg": "auto",
                "resolution": [res, res],
            }
            for name, x in (("left", -175.0), ("right", 175.0))
        ],
    }
    design = design_from_mapping(tables, "<bench>", Path("."))
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-40, 40, (n, 2))
    angle = rng.uniform(0, np.pi, n)
    length = rng.uniform(2.0, 12.0, n)
    d = 0.5 * length[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
    return design, ScratchSet.from_arrays(centre - d, centre + d, 0.1, 0.01)


def run_case(n: int, res: int, backend: str, repeat: int, mode: str) -> dict:
    """One case, in this process. mode: "pairs" (pair finding only) or "full"."""
    import drjit as dr

    from scratchfab.backend import array_module
    from scratchfab.render.renderer import ViewRenderer

    m = array_module(backend)  # type: ignore[arg-type]
    whole = RssSampler()
    whole.__enter__()
    design, scratches = make_case(n, res)
    t = time.perf_counter()
    views = [ViewRenderer(design, v, m) for v in design.views]
    setup_s = time.perf_counter() - t
    t = time.perf_counter()
    pairs = [vr.find_pairs(scratches.p0, scratches.p1, scratches.width / 2) for vr in views]
    pairs_s = time.perf_counter() - t
    n_pairs = sum(len(p) for p in pairs)
    out: dict = {
        "scratches": n,
        "resolution": res,
        "views": 2,
        "pairs": n_pairs,
        "setup_s": setup_s,
        "find_pairs_s": pairs_s,
        "find_pairs_ns_per_pair": 1e9 * pairs_s / max(n_pairs, 1),
    }
    if mode == "pairs":
        whole.__exit__()
        out["peak_rss_mib"] = whole.peak
        return out
    arrays = [vr.scratch_arrays(scratches) for vr in views]
    weights = [
        m.Float64(np.random.default_rng(1).uniform(0.5, 1.5, vr.pixel_count)) for vr in views
    ]

    def forward() -> None:
        images = [vr.render(*a, p) for vr, a, p in zip(views, arrays, pairs, strict=True)]
        dr.eval(images)
        dr.sync_thread()

    def forward_backward() -> None:
        params = [[m.Float64(x) for x in a[:4]] for a in arrays]
        for ps in params:
            dr.enable_grad(ps)
        loss: Any = 0
        for vr, a, p, ps, w in zip(views, arrays, pairs, params, weights, strict=True):
            loss = loss + dr.sum(vr.render(ps[0], ps[1], ps[2], ps[3], a[4], a[5], p) * w)
        dr.backward(loss)
        grads = [dr.grad(x) for ps in params for x in ps]
        dr.eval(grads)
        dr.sync_thread()

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    t = time.perf_counter()
    forward()
    out["forward_first_s"] = time.perf_counter() - t
    history = [h for h in dr.kernel_history() if h.get("type") == dr.KernelType.JIT]
    big = max(history, key=lambda h: h.get("operation_count", 0))
    out["flops_per_pair_forward"] = count_flops(big["ir"].getvalue())
    t = time.perf_counter()
    forward_backward()
    out["forward_backward_first_s"] = time.perf_counter() - t
    history = [h for h in dr.kernel_history() if h.get("type") == dr.KernelType.JIT]
    big_kernels = [h for h in history if h.get("size", 0) >= min(len(p) for p in pairs)]
    out["flops_per_pair_forward_backward"] = (
        sum(count_flops(h["ir"].getvalue()) for h in big_kernels) // 2
    )  # two views
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    dr.kernel_history_clear()
    fwd, both = [], []
    jit_backend = dr.JitBackend.LLVM if backend == "llvm" else dr.JitBackend.CUDA
    dr.flush_malloc_cache()
    dr.detail.malloc_clear_statistics()
    out["rss_before_timed_mib"] = RssSampler.current()
    with RssSampler() as sampler:
        for _ in range(repeat):
            t = time.perf_counter()
            forward()
            fwd.append(time.perf_counter() - t)
            t = time.perf_counter()
            forward_backward()
            both.append(time.perf_counter() - t)
    out["drjit_peak_mib"] = dr.detail.malloc_watermark(jit_backend) / 2**20
    out["timed_peak_rss_mib"] = sampler.peak
    out["forward_s"] = min(fwd)
    out["forward_backward_s"] = min(both)
    out["pairs_per_s_forward"] = n_pairs / out["forward_s"]
    out["pairs_per_s_forward_backward"] = n_pairs / out["forward_backward_s"]
    whole.__exit__()
    out["peak_rss_mib"] = whole.peak
    return out


def fma_peak(backend: str) -> float:
    """Measured float64 FLOP/s of a pure-FMA Dr.Jit kernel (8 independent chains per lane)."""
    import drjit as dr

    from scratchfab.backend import array_module

    m = array_module(backend)  # type: ignore[arg-type]
    n = 1 << 22
    steps = 64
    best = float("inf")
    for _ in range(3):
        xs = [m.Float64(np.full(n, 1.0 + 1e-3 * k)) for k in range(8)]
        dr.eval(xs)
        dr.sync_thread()
        a, b = 0.999999, 1e-7
        for _ in range(steps):
            xs = [dr.fma(x, a, b) for x in xs]
        t = time.perf_counter()
        dr.eval(xs)
        dr.sync_thread()
        best = min(best, time.perf_counter() - t)
    return 2.0 * 8 * steps * n / best


def child(args: argparse.Namespace) -> None:
    result = run_case(args.child[0], args.child[1], args.backend, args.repeat, args.mode)
    print(json.dumps(result))


def spawn(n: int, res: int, backend: str, repeat: int, mode: str, timeout: float) -> dict | None:
    cmd = [sys.executable, __file__, "--child", str(n), str(res), "--backend", backend]
    cmd += ["--repeat", str(repeat), "--mode", mode]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return None
    if proc.returncode != 0:
        print(proc.stderr[-2000:], file=sys.stderr)
        return None
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scratches", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--resolutions", type=int, nargs="+", default=[128, 256, 512])
    parser.add_argument("--backend", default="llvm", choices=["llvm", "cuda"])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--budget-s", type=float, default=240.0)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--mode", default="full", choices=["full", "pairs"])
    parser.add_argument("--child", type=int, nargs=2, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        child(args)
        return

    peak = fma_peak(args.backend)
    print(f"measured float64 FMA throughput: {peak / 1e9:.1f} GFLOP/s", file=sys.stderr)
    cases = []
    rate = None  # forward+backward pairs/s of the largest case run so far
    rate_fwd = None
    for n in args.scratches:
        for res in args.resolutions:
            quick = spawn(n, res, args.backend, 1, "pairs", 600)
            if quick is None:
                cases.append({"scratches": n, "resolution": res, "error": "pair finding failed"})
                continue
            estimate: float | None = (
                None if rate is None else quick["pairs"] / rate * (2 + 2 * args.repeat)
            )
            if estimate is not None and estimate > args.budget_s:
                assert rate_fwd is not None and rate is not None
                quick.update(
                    extrapolated=True,
                    forward_s=quick["pairs"] / rate_fwd,
                    forward_backward_s=quick["pairs"] / rate,
                    pairs_per_s_forward=rate_fwd,
                    pairs_per_s_forward_backward=rate,
                )
                cases.append(quick)
                print(f"{n} x {res}^2: extrapolated ({quick['pairs']} pairs)", file=sys.stderr)
                continue
            full = spawn(n, res, args.backend, args.repeat, "full", 4 * args.budget_s)
            if full is None:
                quick["error"] = "timed out or failed"
                cases.append(quick)
                continue
            full["extrapolated"] = False
            rate = full["pairs_per_s_forward_backward"]
            rate_fwd = full["pairs_per_s_forward"]
            cases.append(full)
            print(
                f"{n} x {res}^2: {full['pairs']} pairs, fwd {full['forward_s']:.3f} s, "
                f"fwd+bwd {full['forward_backward_s']:.3f} s, drjit {full['drjit_peak_mib']:.0f} MiB",
                file=sys.stderr,
            )
    measured = [c for c in cases if c.get("extrapolated") is False]
    flops = max((c["flops_per_pair_forward"] for c in measured), default=0)
    flops_fb = max((c["flops_per_pair_forward_backward"] for c in measured), default=0)
    best_fwd = max((c["pairs_per_s_forward"] for c in measured), default=0.0)
    best_fb = max((c["pairs_per_s_forward_backward"] for c in measured), default=0.0)
    report = {
        "benchmark": "render",
        "backend": args.backend,
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count(),
            "measured_fp64_fma_gflops": peak / 1e9,
        },
        "flops_per_pair_forward": flops,
        "flops_per_pair_forward_backward": flops_fb,
        "best_forward_gflops": flops * best_fwd / 1e9,
        "best_forward_backward_gflops": flops_fb * best_fb / 1e9,
        "fraction_of_measured_peak_forward": flops * best_fwd / peak,
        "fraction_of_measured_peak_forward_backward": flops_fb * best_fb / peak,
        "cases": cases,
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
