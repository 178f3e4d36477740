"""Stroke-ordering benchmark: travel against input order and vpype's linesort, and speed.

Prints one JSON object. Travel is the pen-up distance between consecutive strokes
(vpype's own measure, without the legs from and back to the start position; ours with
them is given too). vpype (``linesort --two-opt``, its default 250-pass cap) runs on the
same strokes when it is installed (``pip install vpype``; benchmark only). The goal:
travel <= 0.9x vpype's, 100k strokes ordered in under 10 s.

Usage: ``python benchmarks/bench_toolpath.py [--quick]``.
"""

from __future__ import annotations

import json
import platform
import sys
import time

import numpy as np
from scipy.spatial import cKDTree

from scratchfab.toolpath.order import OrderOptions, order_strokes

START = (-60.0, -60.0)


def uniform(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Strokes 1-12 mm long, uniform over a 100 mm board (a dense optimized board)."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-44, 44, (n, 2))
    length = rng.uniform(1, 12, n)
    th = rng.uniform(0, np.pi, n)
    u = np.stack([np.cos(th), np.sin(th)], 1) * (length / 2)[:, None]
    return c - u, c + u


def clustered(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Strokes in 40 Gaussian clusters with shared local directions (image features)."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-40, 40, (40, 2))
    angle = rng.uniform(0, np.pi, 40)
    k = rng.integers(0, 40, n)
    c = np.clip(centres[k] + rng.normal(0, 5, (n, 2)), -44, 44)
    th = angle[k] + rng.normal(0, 0.3, n)
    length = rng.uniform(1, 8, n)
    u = np.stack([np.cos(th), np.sin(th)], 1) * (length / 2)[:, None]
    return c - u, c + u


def pen_up(first: np.ndarray, last: np.ndarray) -> float:
    """Travel between consecutive strokes cut first[k] -> last[k]."""
    return float(np.hypot(*(first[1:] - last[:-1]).T).sum())


def ours(p0: np.ndarray, p1: np.ndarray) -> dict:
    t = time.perf_counter()
    res = order_strokes(p0, p1, START)
    seconds = time.perf_counter() - t
    first = np.where(res.reverse[:, None], p1[res.order], p0[res.order])
    last = np.where(res.reverse[:, None], p0[res.order], p1[res.order])
    return {
        "seconds": round(seconds, 3),
        "pen_up_mm": round(pen_up(first, last), 2),
        "travel_with_start_mm": round(res.travel_mm, 2),
        "greedy_travel_with_start_mm": round(res.travel_greedy_mm, 2),
        "input_travel_with_start_mm": round(res.travel_input_mm, 2),
    }


def vpype_linesort(p0: np.ndarray, p1: np.ndarray) -> dict | None:
    try:
        import vpype
        import vpype_cli
    except ImportError:
        return None
    lines = vpype.LineCollection(
        [np.array([complex(*a), complex(*b)]) for a, b in zip(p0, p1, strict=True)]
    )
    t = time.perf_counter()
    out = vpype_cli.execute("linesort --two-opt", vpype.Document(lines))
    seconds = time.perf_counter() - t
    layer = out.layers[1]
    return {
        "version": vpype.__version__,
        "seconds": round(seconds, 3),
        "pen_up_mm": round(float(layer.pen_up_length()[0]), 2),
    }


def lower_bound(p0: np.ndarray, p1: np.ndarray) -> float:
    """Half the sum over endpoints of the distance to the nearest other stroke's endpoint."""
    n = len(p0)
    pts = np.empty((2 * n, 2))
    pts[0::2], pts[1::2] = p0, p1
    d, i = cKDTree(pts).query(pts, k=3)
    own = (i[:, 1] >> 1) == (np.arange(2 * n) >> 1)
    return float(0.5 * np.where(own, d[:, 2], d[:, 1]).sum())


def main() -> None:
    quick = "--quick" in sys.argv
    t = time.perf_counter()
    order_strokes(*uniform(50, 0), START)  # compiles (or loads) the numba kernels
    report: dict = {
        "benchmark": "toolpath ordering",
        "machine": platform.processor() or platform.machine(),
        "warmup_compile_s": round(time.perf_counter() - t, 3),
        "options": OrderOptions().__dict__,
        "versus_vpype": [],
        "speed": [],
    }
    sizes = [1000] if quick else [1000, 3000]
    for name, make in (("uniform", uniform), ("clustered", clustered)):
        for n in sizes:
            p0, p1 = make(n, 1)
            row: dict = {"strokes": n, "layout": name, "input_pen_up_mm": round(pen_up(p0, p1), 2)}
            row["lower_bound_mm"] = round(lower_bound(p0, p1), 2)
            row["scratchfab"] = ours(p0, p1)
            vp = vpype_linesort(p0, p1)
            row["vpype"] = vp if vp is not None else "not installed"
            if vp is not None:
                row["ratio_to_vpype"] = round(row["scratchfab"]["pen_up_mm"] / vp["pen_up_mm"], 4)
            row["ratio_to_input"] = round(
                row["scratchfab"]["pen_up_mm"] / row["input_pen_up_mm"], 5
            )
            report["versus_vpype"].append(row)
    for n in [10_000] if quick else [10_000, 100_000]:
        p0, p1 = uniform(n, 2)
        row = {"strokes": n, "layout": "uniform", "input_pen_up_mm": round(pen_up(p0, p1), 2)}
        row["scratchfab"] = ours(p0, p1)
        row["under_10_s"] = row["scratchfab"]["seconds"] < 10.0
        report["speed"].append(row)
    ratios = [r["ratio_to_vpype"] for r in report["versus_vpype"] if "ratio_to_vpype" in r]
    report["goal_travel_le_0.9x_vpype"] = bool(ratios) and max(ratios) <= 0.9
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
