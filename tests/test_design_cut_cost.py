"""Design says what the layout will cost to cut: its length and a time on a named machine.

The reference is the toolpath stage's own estimate for the same scratches, planned in
full (ordering with local search) on the same profile.
"""

from __future__ import annotations

import re
import shutil
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
from conftest import cli_run, design_sun_and_moon
from cut_said import cut_sentence

from scratchfab.bundled import bundled_dir
from scratchfab.design.stage import run_design
from scratchfab.machine.profile import load_profile
from scratchfab.model.design import load_design
from scratchfab.model.scratches import load_scratches
from scratchfab.pipeline.config import load_pipeline
from scratchfab.toolpath.plan import plan_toolpath

DEMO = bundled_dir("demo")
PROFILES = bundled_dir("machine_profiles")


def _seconds(said: str) -> float:
    """Seconds from ``duration_text``'s words (``1 h 2 min``, ``23 min``, ``45 s``)."""
    found = re.fullmatch(r"(?:(\d+) h )?(\d+) (min|s)", said)
    assert found, said
    hours, value, unit = found.groups()
    return int(hours or 0) * 3600 + int(value) * (60 if unit == "min" else 1)


def _cut_line(out: str) -> str:
    return cut_sentence(out.splitlines())


def _toolpath_seconds(job: Path, machine: str | Path) -> float:
    design = load_design(job / "design" / "design.toml", require_views=False)
    scratches = load_scratches(job / "design" / "scratches.csv", design.scratch)
    return float(
        plan_toolpath(scratches, design.board, load_profile(machine)).stats["estimated_time_s"]
    )


def test_design_tells_the_cut_length_and_time_at_the_bundled_profiles_feeds(tmp_path, capsys):
    job = tmp_path / "job"
    out = design_sun_and_moon(job, "60x50", 400, capsys)
    line = _cut_line(out)
    # after the layout is made
    lines = out.splitlines()
    assert (
        next(i for i, s in enumerate(lines) if s.startswith("  cut: "))
        == next(i for i, s in enumerate(lines) if s.startswith("  initial layout:")) + 1
    )
    design = load_design(job / "design" / "design.toml", require_views=False)
    scratches = load_scratches(job / "design" / "scratches.csv", design.scratch)
    length_m = float(np.hypot(*(scratches.p1 - scratches.p0).T).sum()) / 1000
    assert line.startswith(f"  cut: 400 scratches, {length_m:.1f} m of cut;")
    # the feeds named are the bundled profile's, read here from its file
    profile = tomllib.loads((PROFILES / "grbl-3018-diamond.toml").read_text(encoding="utf-8"))
    feeds = profile["feeds"]
    assert (
        f"machine '{profile['name']}' (grbl-3018-diamond; engrave {feeds['engrave_mm_min']:g} "
        "mm/min" in line
    )
    assert f"plunge {feeds['plunge_mm_min']:g} mm/min" in line
    assert "--count" in line
    said = _seconds(re.search(r"about (.+?) \(", line).group(1))
    reference = _toolpath_seconds(job, "grbl-3018-diamond")
    assert abs(said - reference) <= 0.3 * reference, (said, reference)


def test_a_pipeline_files_own_machine_is_the_one_timed(tmp_path, capsys):
    """A pipeline file's [toolpath] machine (relative to the file) sets the feeds."""
    slow = (PROFILES / "grbl-3018-diamond.toml").read_text(encoding="utf-8")
    slow = slow.replace("engrave_mm_min = 600.0", "engrave_mm_min = 150.0")
    assert "engrave_mm_min = 150.0" in slow
    (tmp_path / "machines").mkdir()
    (tmp_path / "machines" / "slow.toml").write_text(slow, encoding="utf-8")
    pipeline = (bundled_dir("pipelines") / "demo.toml").read_text(encoding="utf-8")
    for name in ("sun", "house"):
        shutil.copy(DEMO / f"{name}.png", tmp_path / f"{name}.png")
        pipeline = pipeline.replace(f"../demo/{name}.png", f"{name}.png")
    pipeline = pipeline.replace('machine = "grbl-3018-diamond"', 'machine = "machines/slow.toml"')
    assert 'machine = "machines/slow.toml"' in pipeline
    (tmp_path / "mine.toml").write_text(pipeline, encoding="utf-8")
    job = tmp_path / "job"
    code, out, _ = cli_run(
        ["design", str(tmp_path / "mine.toml"), "--count", "300", "--resolution", "24",
         "--out", str(job)],
        capsys,
    )  # fmt: skip
    assert code == 0
    line = _cut_line(out)
    assert f"({tmp_path / 'machines' / 'slow.toml'}; engrave 150 mm/min" in line, line
    assert "[scratch] count" in line
    said = _seconds(re.search(r"about (.+?) \(", line).group(1))
    reference = _toolpath_seconds(job, tmp_path / "machines" / "slow.toml")
    assert abs(said - reference) <= 0.3 * reference, (said, reference)
    # as `run` designs: the pipeline's Design, the machine it names passed along
    pipe = load_pipeline(tmp_path / "mine.toml")
    said_lines: list[str] = []
    run_design(
        replace(pipe.design, source=str(pipe.path)),
        tmp_path / "run-job",
        progress=said_lines.append,
        machine=pipe.machine_ref(),
    )
    line = _cut_line("\n".join(said_lines))
    assert f"({tmp_path / 'machines' / 'slow.toml'}; engrave 150 mm/min" in line, line
    assert "; [scratch] count in " in line
