"""The job's design digest (what optimize records and the stale-layout note compares).

It covers the pictures optimize reads (``targets/<view>.npy``, ``board/<view>.png``), and
a rerun of design that changes nothing optimize depends on leaves the layout current, also
over a job whose record an earlier scratchfab made of ``design.toml``'s bytes.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from scratchfab.cli import main
from scratchfab.fileio import file_sha256
from scratchfab.model.design import load_design
from scratchfab.model.job import JobLayout, design_digest, stale_layout

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "scratchfab" / "data" / "demo"
QUICK = [str(DEMO / "sun.png"), "--board", "30x30", "--resolution", "16x16", "--count", "40"]


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    main(args)
    return capsys.readouterr().out


def _as_optimized(job: Path, record: dict[str, str]) -> JobLayout:
    """The job as optimize leaves it: its layout and ``record`` of the design it was made from."""
    layout = JobLayout(job)
    layout.optimize_dir.mkdir(exist_ok=True)
    shutil.copy(layout.design.initial_scratches, layout.optimized_scratches)
    layout.optimize_summary.write_text(json.dumps({"design_sha256": record}))
    return layout


@pytest.fixture
def job(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    """A quick-form job of one view, designed and marked optimized from this design."""
    folder = tmp_path / "job"
    _run(["design", *QUICK, "--out", str(folder)], capsys)
    _as_optimized(folder, design_digest(folder))
    return folder


def test_a_board_picture_swapped_by_hand_notes_the_layout_stale(job: Path) -> None:
    layout = JobLayout(job)
    (view,) = load_design(layout.design.design_toml).views
    assert stale_layout(job) is None
    picture = layout.design.board_png(view.name)
    kept = picture.read_bytes()
    shutil.copy(DEMO / "house.png", picture)
    said = stale_layout(job)
    assert said is not None and f"design/board/{view.name}.png" in said
    picture.write_bytes(kept)
    assert stale_layout(job) is None


def test_a_target_swapped_by_hand_notes_the_layout_stale(job: Path) -> None:
    layout = JobLayout(job)
    (view,) = load_design(layout.design.design_toml).views
    target = layout.design.target_npy(view.name)
    np.save(target, np.flipud(np.load(target)))
    said = stale_layout(job)
    assert said is not None and f"design/targets/{view.name}.npy" in said


def test_a_record_without_the_pictures_compares_the_files_it_has(job: Path) -> None:
    """An earlier scratchfab recorded design.toml and scratches.csv only: still current."""
    layout = JobLayout(job)
    old = {p.name: file_sha256(p) for p in layout.design.digested}
    _as_optimized(job, old)
    assert stale_layout(job) is None


def _as_the_version_before(job: Path) -> str:
    """The job as the scratchfab before "auto" was kept left it; its design.toml's fov.

    That version wrote each view's fov_deg as auto's number, and optimize recorded the
    bytes' SHA-256 of design.toml and scratches.csv.
    """
    file = JobLayout(job).design.design_toml
    numbers = re.subn(
        r'(?m)^fov_deg = "auto"  # (\S+) degrees on this .*$', r"fov_deg = \1", file.read_text()
    )
    text, n = numbers
    assert n == 1
    file.write_text(text)
    layout = JobLayout(job)
    _as_optimized(job, {p.name: file_sha256(p) for p in layout.design.digested})
    assert stale_layout(job) is None
    return re.search(r"(?m)^fov_deg = (\S+)$", text).group(1)


def test_the_first_rerun_over_a_job_of_the_version_before_keeps_its_layout_current(
    job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The rerun writes fov_deg = "auto" where the file had the number: the same design."""
    number = _as_the_version_before(job)
    out = _run(["design", *QUICK, "--out", str(job)], capsys)
    file = JobLayout(job).design.design_toml
    assert f'fov_deg = "auto"  # {number} degrees' in file.read_text()
    assert "note:" not in out and stale_layout(job) is None
    # and from the job's own design.toml, as README's edit loop reruns it
    _as_the_version_before(job)
    out = _run(["design", str(file), "--out", str(job)], capsys)
    assert "note:" not in out and stale_layout(job) is None


def test_a_rerun_over_a_job_of_the_version_before_that_changes_the_design_notes_it(
    job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _as_the_version_before(job)
    file = JobLayout(job).design.design_toml
    file.write_text(file.read_text().replace("roughness = 0.05\n", "roughness = 0.08\n"))
    out = _run(["design", str(file), "--out", str(job)], capsys)
    assert "note:" in out and stale_layout(job) is not None
