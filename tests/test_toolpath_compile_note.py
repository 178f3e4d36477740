"""``toolpath`` says when numba compiles the ordering code first (about 10 s once after installing).

The probe reads numba's cache index: a cache folder with nothing in it is cold, and after
a run that compiled (and cached) the steps it ran the next run says nothing. Run in
subprocesses with ``NUMBA_CACHE_DIR`` pointing at an empty folder; ``--passes 0`` runs
only the greedy step, which compiles in about a second.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np

from scratchfab.model.design import design_from_mapping
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath.local_search import compile_state

ONCE = "compiling the ordering code once (about 10 s) ..."


def write_job(folder: Path) -> tuple[Path, Path]:
    """A 40 mm design and 30 seeded scratches on it."""
    tables = {
        "board": {"width_mm": 40.0, "height_mm": 40.0, "roughness": 0.05, "margin_mm": 1.0},
        "light": {"position_mm": [0.0, 150.0, 300.0]},
        "scratch": {"width_mm": 0.1, "depth_mm": 0.01, "count": 30},
        "views": [{"name": "front", "position_mm": [0.0, 0.0, 400.0], "fov_deg": "auto"}],
    }
    design = design_from_mapping(tables, "<design>", folder)
    design_file = folder / "design.toml"
    design.save(design_file)
    p0 = np.random.default_rng(5).uniform(-15.0, 15.0, (30, 2))
    scratch_file = folder / "scratches.csv"
    ScratchSet.from_arrays(p0, p0 + [2.0, 1.0], 0.1, 0.01).save(scratch_file, design.scratch)
    return design_file, scratch_file


def test_a_cold_cache_is_announced_once(tmp_path):
    design_file, scratch_file = write_job(tmp_path)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}

    def toolpath(out: str) -> str:
        argv = [sys.executable, "-m", "scratchfab", "toolpath", "--machine", "grbl-3018-diamond"]
        argv += ["--scratches", str(scratch_file), "--design", str(design_file)]
        argv += ["--out", str(tmp_path / out), "--passes", "0"]
        run = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stdout + run.stderr
        return run.stdout

    first = toolpath("a").splitlines()
    assert first.count(ONCE) == 1 and first[0].startswith("ordering 30 scratches"), first
    assert ONCE not in toolpath("b")
    # the local search, not run with --passes 0, is still to compile
    code = (
        "from scratchfab.toolpath.order import OrderOptions, compile_note\n"
        "print(compile_note(OrderOptions(passes=0)), compile_note(OrderOptions()), sep='|')"
    )
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert run.stdout.strip() == f"None|{ONCE}", run.stdout + run.stderr


def test_compiled_in_process_is_ready_uncached_compiles_each_run_plain_is_unknown():
    def twice(x: int) -> int:
        return 2 * x

    uncached = numba.njit(cache=False)(twice)
    assert compile_state([uncached]) == "each run"
    assert uncached(3) == 6
    assert compile_state([uncached]) == "ready"
    assert compile_state([]) == "ready"
    # not numba's (NUMBA_DISABLE_JIT leaves plain functions): nothing to announce
    assert compile_state([twice]) == "unknown"
