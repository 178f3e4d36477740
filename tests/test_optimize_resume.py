"""optimize --resume on checkpoints of an earlier scratchfab, and what a refusal names.

References: the views' order as design.toml lists it, the columns of the log.csv the
stopped run wrote, the files the design stage wrote (rewritten here by hand), the glint
rule's limit from :func:`design_glint_deg`, and the number of times the checkpoint is read.
"""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from conftest import make_design
from test_optimize_glint import glint_design
from test_optimize_helpers import make_job, stopped_at_three_of_four

import scratchfab.optimize.checkpoint as checkpoint_module
from scratchfab.cli import main
from scratchfab.design.feasibility import design_glint_deg
from scratchfab.model.job import load_job_design
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.optimize.checkpoint import load_checkpoint, save_checkpoint
from scratchfab.optimize.options import OptimizeOptions
from scratchfab.optimize.stage import ResumeRefused, run_optimize


@pytest.fixture
def job(tmp_path: Path) -> Path:
    return make_job(tmp_path / "job", make_design(resolution=24, size_mm=30.0), count=150)


@pytest.fixture
def glint_job(tmp_path: Path) -> Path:
    """A job whose left view glints (:func:`test_optimize_glint.glint_design`)."""
    return make_job(tmp_path / "glint", glint_design(resolution=24), count=100)


def _edit_checkpoint(job: Path, fingerprint: dict[str, Any], **meta: Any) -> None:
    """Set (None: remove) keys of the checkpoint's fingerprint and meta, as another
    scratchfab would have written them."""
    ckpt = job / "optimize" / "checkpoint.npz"
    state, old, rows = load_checkpoint(ckpt)
    for table, changes in ((old["fingerprint"], fingerprint), (old, meta)):
        for key, value in changes.items():
            if value is None:
                table.pop(key, None)
            else:
                table[key] = value
    save_checkpoint(ckpt, state, old, rows)


#: What a checkpoint of the scratchfab before the design record lacked.
EARLIER = {"design": None, "inputs": None, "image_error": None}


def test_a_checkpoint_without_design_record_refuses_views_given_in_another_order(
    job: Path,
) -> None:
    """The earlier fingerprint's digest takes the targets by sorted name, so swapped views
    passed it and resumed on other steps under swapped columns; the order its log's
    columns were written in tells the order its steps followed."""
    run_optimize(job, OptimizeOptions(iterations=2))
    _edit_checkpoint(job, EARLIER, iterations=None, prune_tolerance=None)
    with (job / "optimize" / "log.csv").open() as handle:
        header = next(csv.reader(handle))
    logged = [c.removeprefix("psnr_") for c in header if c.startswith("psnr_")]
    file = job / "design" / "design.toml"
    design = load_job_design(file)
    names = [v.name for v in design.views]
    assert logged == names and len(names) == 2
    replace(design, views=design.views[::-1]).save(file)
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=3, resume=True))
    first, second = names
    assert info.value.design == {"[[views]] order": f"[{first}, {second}] -> [{second}, {first}]"}
    assert info.value.changed == ["[[views]] order"]
    design.save(file)  # the order it was made in: it resumes
    assert run_optimize(job, OptimizeOptions(iterations=3, resume=True)).iterations == 3


def test_a_killed_run_whose_total_is_not_kept_needs_iterations_and_says_so(
    job: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A run of 2 steps stretched to 4 by the earlier scratchfab (no total kept, its
    schedule's 2) and killed at 3 (no summary): a bare resume says the total is not known
    and to give --iterations, before compiling anything; given, it goes on. Either reads
    the checkpoint once."""
    stopped_at_three_of_four(job)
    _edit_checkpoint(job, EARLIER, iterations=None, prune_tolerance=None)
    (job / "optimize" / "summary.json").unlink()
    reads: list[Path] = []
    load = checkpoint_module.load_checkpoint

    def counted(path: Path) -> Any:
        reads.append(path)
        return load(path)

    monkeypatch.setattr(checkpoint_module, "load_checkpoint", counted)
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["optimize", str(job), "--resume"])
    assert info.value.code != 0
    err = capsys.readouterr().err
    ckpt = job / "optimize" / "checkpoint.npz"
    assert f"{ckpt}: the run's total is not known" in err
    assert "(it had done 3 iterations)" in err and "give --iterations N with --resume" in err
    assert "compiling kernels" not in err and len(reads) == 1
    main(["optimize", str(job), "--resume", "--iterations", "4"])
    assert "4 iterations (done)" in capsys.readouterr().out
    assert reads == [ckpt, ckpt]


def test_a_finished_run_of_the_earlier_objective_on_a_glinting_design_is_refused_at_once(
    glint_job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A finished run made while the glint still counted: the bare resume refuses with the
    reason at once (it said "nothing to do", then refused once given --iterations); one of
    the first glint rule ("glint left out", the limit this one has) has nothing to do."""
    main(["optimize", str(glint_job), "--iterations", "2"])
    _edit_checkpoint(glint_job, {"image_error": None})
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["optimize", str(glint_job), "--resume"])
    said = capsys.readouterr()
    assert "nothing to do" not in said.out and "compiling kernels" not in said.err
    assert (
        "made by an earlier scratchfab, whose image error counted the bare board's glint "
        "(this one leaves it out); run without --resume to start over"
    ) in said.err
    _edit_checkpoint(glint_job, {"image_error": "glint left out"})
    main(["optimize", str(glint_job), "--resume"])
    assert capsys.readouterr().out.startswith("nothing to do: the run had done its 2 iterations")


def test_a_checkpoint_of_another_glint_limit_is_refused_where_a_view_glints(
    glint_job: Path, job: Path
) -> None:
    """The checkpoint keeps the glint rule's limit for its design: another limit (a later
    rule's) left out other pixels of a glinting design and is refused, naming both; a
    design that glints under neither counted every pixel either way and resumes."""
    run_optimize(glint_job, OptimizeOptions(iterations=2))
    limit = design_glint_deg(load_job_design(glint_job / "design" / "design.toml"))
    ckpt = glint_job / "optimize" / "checkpoint.npz"
    assert load_checkpoint(ckpt)[1]["fingerprint"]["image_error"]["glint_limit_deg"] == (
        pytest.approx(limit, abs=1e-6)
    )
    other = {"glint_limit_deg": round(limit + 1.5, 6), "glint_left_out": True}
    _edit_checkpoint(glint_job, {"image_error": other})
    with pytest.raises(ResumeRefused) as info:
        run_optimize(glint_job, OptimizeOptions(iterations=3, resume=True))
    assert info.value.changed == ["image_error"] and info.value.made_with is None
    assert info.value.reasons() == (
        "made by an earlier scratchfab, whose image error left out the bare board's glint "
        f"below {other['glint_limit_deg']:.6g} degrees of half-vector tilt (this one below "
        f"{round(limit, 6):.6g} degrees)"
    )
    run_optimize(job, OptimizeOptions(iterations=2))
    summary = json.loads((job / "optimize" / "summary.json").read_text())
    assert summary["glint_left_out"] == {}  # no view of it glints
    _edit_checkpoint(job, {"image_error": {"glint_limit_deg": 0.5, "glint_left_out": False}})
    assert run_optimize(job, OptimizeOptions(iterations=3, resume=True)).iterations == 3
    _edit_checkpoint(job, {"image_error": None})  # the earlier scratchfab's: every pixel
    assert run_optimize(job, OptimizeOptions(iterations=4, resume=True)).iterations == 4


def test_a_refusal_names_the_design_stage_output_that_changed(job: Path) -> None:
    """A changed initial layout is named by its file, not as "settings or inputs"; a
    checkpoint that keeps only the digest of them all says which two kinds it covers."""
    run_optimize(job, OptimizeOptions(iterations=2))
    file = job / "design" / "scratches.csv"
    design = load_job_design(job / "design" / "design.toml")
    layout = load_scratches(file, design.scratch, design.board)
    moved = layout.p0.copy()
    moved[0] += 0.1
    ScratchSet(moved, layout.p1, layout.width, layout.depth).save(file, design.scratch)
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=3, resume=True))
    assert info.value.changed == ["inputs_sha256"]
    assert (
        info.value.reasons() == "design/scratches.csv changed since it was made: design was rerun"
    )
    _edit_checkpoint(job, {"inputs": None})
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=3, resume=True))
    assert info.value.reasons() == (
        "the design's initial scratches or targets changed since it was made: design was rerun"
    )
    assert "settings or inputs" not in str(info.value)
