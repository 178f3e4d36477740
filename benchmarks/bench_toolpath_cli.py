"""Wall time of ``scratchfab toolpath`` on a quick-form job, as a user runs it.

Makes two images, designs a 100 x 100 mm board of ``--count`` scratches with the quick
form (``scratchfab design a.png b.png --board 100x100 --count N``), then runs
``scratchfab toolpath JOB --machine M`` ``--repeat`` times, each a fresh process, and
reports the median wall and CPU time, with what a run is made of:

- ``imports_s``: a process that only imports what the stage needs (numpy, scipy's k-d
  tree, shapely, Pillow, numba and the compiled local search) and exits;
- in this process, after one warm-up: ``order_strokes_s`` (the ordering alone, what
  ``bench_toolpath.py`` times) and ``plan_toolpath_s`` (clipping, merging, ordering and
  the time estimate), ``save_json_s`` and ``preview_s``.

The rest of a CLI run is Python's start, loading the numba kernels from their cache,
reading the inputs and the messages. With ``--cold`` one more run compiles the kernels
into an empty numba cache (what the first run after an install or an upgrade pays).
The outputs' MD5s are reported, and whether every run wrote the same files. The
machine's load average is recorded: other work on the cores inflates the wall times.

Prints one JSON object. Usage:
``python benchmarks/bench_toolpath_cli.py [--count 3000] [--machine grbl-3018-diamond]
[--repeat 3] [--cold]``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import TypeVar

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
#: What the toolpath stage imports, for the fixed cost of a run.
STAGE_IMPORTS = (
    "import scipy.spatial, shapely, PIL.Image, scratchfab.toolpath.stage, "
    "scratchfab.toolpath.local_search"
)
T = TypeVar("T")


def make_images(folder: Path, size: int = 256) -> list[Path]:
    """Two grey images, a wave pattern and a disc (deterministic)."""
    y, x = np.mgrid[0:size, 0:size]
    wave = 128 + 100 * np.sin(x / 20.0) * np.cos(y / 30.0)
    disc = np.where((x - size / 2) ** 2 + (y - size / 2) ** 2 < (0.31 * size) ** 2, 230, 30)
    files = []
    for name, pixels in (("a.png", wave), ("b.png", disc)):
        Image.fromarray(np.clip(pixels, 0, 255).astype(np.uint8)).save(folder / name)
        files.append(folder / name)
    return files


def cli(*args: str | Path, env: dict[str, str] | None = None) -> tuple[float, float]:
    """Run ``python -m scratchfab ARGS``: (wall s, CPU s of the child); raises if it fails."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "scratchfab", *map(str, args)],
        capture_output=True,
        text=True,
        check=False,
        cwd=ROOT,
        env=env,
    )
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"scratchfab {' '.join(map(str, args))} failed:\n{proc.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def md5s(folder: Path) -> dict[str, str]:
    """MD5 of toolpath.json and preview.png in ``folder``."""
    return {
        name: hashlib.md5((folder / name).read_bytes()).hexdigest()
        for name in ("toolpath.json", "preview.png")
    }


def median(values: list[float]) -> float:
    return round(statistics.median(values), 3)


def in_process(job: Path, machine: str, repeat: int) -> dict[str, float]:
    """Median seconds of the stage's parts, run here after one warm-up."""
    from scratchfab.machine.profile import load_profile
    from scratchfab.model.design import load_design
    from scratchfab.model.job import job_inputs
    from scratchfab.model.scratches import load_scratches
    from scratchfab.toolpath.order import order_strokes
    from scratchfab.toolpath.plan import plan_toolpath, write_preview

    design_file, scratch_file = job_inputs(job)
    profile = load_profile(machine)
    design = load_design(design_file, require_views=False)
    scratches = load_scratches(scratch_file, design.scratch, design.board)
    plan = plan_toolpath(scratches, design.board, profile, design.scratch)  # warm-up
    times: dict[str, list[float]] = {}

    def timed(key: str, run: Callable[[], T]) -> T:
        t = time.perf_counter()
        out = run()
        times.setdefault(key, []).append(time.perf_counter() - t)
        return out

    strokes, start = plan.strokes, plan.start
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeat):
            timed("order_strokes_s", partial(order_strokes, strokes[:, 0], strokes[:, 1], start))
            planned = timed(
                "plan_toolpath_s",
                partial(plan_toolpath, scratches, design.board, profile, design.scratch),
            )
            timed("save_json_s", partial(planned.save, Path(tmp) / "toolpath.json"))
            timed("preview_s", partial(write_preview, planned, Path(tmp) / "preview.png"))
    return {key: median(values) for key, values in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=3000, help="scratches on the board")
    parser.add_argument("--machine", default="grbl-3018-diamond", help="machine profile")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each timing")
    parser.add_argument("--cold", action="store_true", help="also a run with no numba cache")
    args = parser.parse_args()
    if args.count < 1 or args.repeat < 1:
        parser.error("--count and --repeat must be at least 1")
    report: dict = {
        "benchmark": "scratchfab toolpath CLI wall time",
        "machine": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "load_average_at_start": [round(v, 2) for v in os.getloadavg()],
        "count": args.count,
        "profile": args.machine,
        "repeat": args.repeat,
    }
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        job = folder / "job"
        images = make_images(folder)
        cli("design", *images, "--board", "100x100", "--count", args.count, "--out", job)
        out = job / "toolpath"
        cli("toolpath", job, "--machine", args.machine)  # fills the numba cache if empty
        first = md5s(out)
        walls, cpus, same = [], [], True
        for _ in range(args.repeat):
            wall, cpu = cli("toolpath", job, "--machine", args.machine)
            walls.append(wall)
            cpus.append(cpu)
            same &= md5s(out) == first
        report["cli_wall_s"] = median(walls)
        report["cli_cpu_s"] = median(cpus)
        report["cli_wall_runs_s"] = [round(w, 3) for w in walls]
        imports = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-c", STAGE_IMPORTS], check=True, cwd=ROOT)
            imports.append(time.perf_counter() - t)
        report["imports_s"] = median(imports)
        report |= in_process(job, args.machine, args.repeat)
        if args.cold:
            with tempfile.TemporaryDirectory() as cache:
                env = dict(os.environ, NUMBA_CACHE_DIR=cache)
                wall, cpu = cli("toolpath", job, "--machine", args.machine, env=env)
            report["cold_cache_cli_wall_s"] = round(wall, 3)
            report["cold_cache_cli_cpu_s"] = round(cpu, 3)
            same &= md5s(out) == first
        report["outputs_md5"] = first
        report["outputs_identical_across_runs"] = same
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
