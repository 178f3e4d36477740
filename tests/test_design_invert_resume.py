"""optimize --resume after a rerun of design that inverted a view (``--invert``).

``invert`` is no key of the design record a checkpoint keeps (``design_fields``): the
picture's inversion is in the targets, whose digest the checkpoint keeps by view. The
references: a plain rerun of the same file, which changes no target and resumes, and the
target file itself, whose values the inversion changes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scratchfab.cli import main
from scratchfab.model.design import design_fields
from scratchfab.model.job import JobLayout, load_job_design, stale_layout
from scratchfab.optimize.options import OptimizeOptions
from scratchfab.optimize.stage import ResumeRefused, run_optimize


def _design(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    main(["design", *args])
    capsys.readouterr()


def test_a_resume_after_a_rerun_that_inverted_a_view_is_refused_naming_its_target(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    picture = tmp_path / "sun.png"
    image = Image.new("L", (20, 20), 40)
    image.paste(200, (4, 4, 16, 16))
    image.save(picture)
    job = tmp_path / "job"
    layout = JobLayout(job)
    toml = layout.design.design_toml
    quick = [str(picture), "--board", "30x30", "--count", "40", "--resolution", "16"]
    _design([*quick, "--out", str(job)], capsys)
    run_optimize(job, OptimizeOptions(iterations=2))
    target = layout.design.target_npy("sun")
    before = np.load(target)
    fields = design_fields(load_job_design(toml))

    # a plain rerun from the job's file changes no target: the run resumes
    _design([str(toml), "--out", str(job)], capsys)
    np.testing.assert_array_equal(np.load(target), before)
    assert stale_layout(job) is None
    assert run_optimize(job, OptimizeOptions(iterations=3, resume=True)).iterations == 3

    _design([str(toml), "--invert", "--out", str(job)], capsys)
    inverted = np.load(target)
    seen = ~np.isnan(before)
    assert np.abs(inverted[seen] - before[seen]).max() > 0.5  # the target did change
    # ... while the design's record did not: invert is not in it, and need not be
    assert design_fields(load_job_design(toml)) == fields
    said = stale_layout(job)
    assert said is not None and "design/targets/sun.npy" in said
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=4, resume=True))
    assert info.value.changed == ["inputs_sha256"]
    assert info.value.design == {}
    # the layout is laid on the targets, so it changed with them
    assert info.value.reasons() == (
        "design/scratches.csv, design/targets/sun.npy changed since it was made: design was rerun"
    )
    # without --resume it starts over on the inverted target
    assert run_optimize(job, OptimizeOptions(iterations=2)).iterations == 2
