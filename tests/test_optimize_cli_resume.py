"""``optimize JOB --resume`` of a run that ``scratchfab run`` started and Ctrl-C stopped.

The pipeline's ``[optimize]`` table holds options the command has no flags for (the
``lr_*`` step sizes, ``refresh_every``, ``merge_weight``, ...): the resume takes them, and
every option the command does not give, from the checkpoint. References: the same
pipeline run without a stop (the project's resume is bit-identical with one thread), the
values written in the pipeline file, and the design as ``design.toml`` holds it.
"""

from __future__ import annotations

import contextlib
import json
import shutil
from collections.abc import Iterator
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import pytest
from conftest import cli_said, write_pipeline

from scratchfab.model.job import load_job_design
from scratchfab.optimize import stage as optimize_stage
from scratchfab.optimize.checkpoint import load_checkpoint, read_checkpoint, save_checkpoint
from scratchfab.optimize.options import OptimizeOptions
from scratchfab.optimize.stage import checkpoint_request, checkpoint_settings
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline

#: Every option of the run that the command has no flag for or leaves at another default.
OPTIMIZE = """[optimize]
iterations = 9
checkpoint_every = 2
seed = 5
space = "perceptual"
lr_position_mm = 0.05
lr_angle_deg = 0.4
lr_length_mm = 0.02
lr_schedule = "linear"
lr_start_scale = 3.0
lr_end_scale = 0.5
refresh_every = 3
merge_weight = 0.03
jitter_deg = 1.0
prune_tolerance = 0.01
feed_mm_min = 250.0
stroke_overhead_s = 1.5
"""


@pytest.fixture(scope="module")
def stopped(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """The pipeline file, a job whose ``scratchfab run`` Ctrl-C stopped after 5 of its 9
    optimize steps, and the job of the same pipeline run without a stop."""
    folder = tmp_path_factory.mktemp("resume")
    path = write_pipeline(folder, edits={"[optimize]\niterations = 4\n": OPTIMIZE})
    reference = folder / "reference"
    run_pipeline(load_pipeline(path), reference, until="optimize")

    @contextlib.contextmanager
    def ctrl_c_after_five_steps() -> Iterator[Any]:
        polls = iter(range(10**6))
        yield lambda: next(polls) >= 4

    job = folder / "job"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(optimize_stage, "interrupt_flag", ctrl_c_after_five_steps)
        with pytest.raises(SystemExit) as exc:
            from scratchfab.cli import main

            main(["run", str(path), "--out", str(job), "--until", "optimize"])
    assert exc.value.code == 130
    assert int(load_checkpoint(job / "optimize" / "checkpoint.npz")[0]["iteration"]) == 5
    return path, job, reference


@pytest.fixture
def job(stopped: tuple[Path, Path, Path], tmp_path: Path) -> Path:
    """A copy of the stopped job, for a test to resume or change."""
    copy = tmp_path / "job"
    shutil.copytree(stopped[1], copy)
    return copy


def test_the_checkpoint_tells_the_options_the_pipeline_file_gave(
    stopped: tuple[Path, Path, Path],
) -> None:
    """What a resume takes from the checkpoint is what the pipeline's table says."""
    path, job, _ = stopped
    table = load_pipeline(path).optimize
    checkpoint = read_checkpoint(job / "optimize" / "checkpoint.npz")
    own = {**checkpoint_settings(checkpoint), **checkpoint_request(job, checkpoint)}
    assert replace(table, **own) == table
    # all but the time budget, each command's own (it counts the run's time in all), and
    # the resume itself
    assert set(own) == {f.name for f in fields(OptimizeOptions)} - {"time_budget_s", "resume"}


def test_resume_alone_ends_as_the_run_without_a_stop(
    stopped: tuple[Path, Path, Path], job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`optimize JOB --resume` goes on with the run's step sizes, schedule, seed, total and
    prune: the same layout, byte for byte, and the same log as the run never stopped."""
    reference = stopped[2]
    code, said = cli_said(["optimize", str(job), "--resume"], capsys)
    assert code == 0, said
    assert "9 iterations (done)" in said and "(at 250 mm/min + 1.5 s per stroke)" in said
    summaries = [
        json.loads((j / "optimize" / "summary.json").read_text()) for j in (job, reference)
    ]
    assert {**summaries[0]["options"], "resume": False} == summaries[1]["options"]
    assert summaries[0]["prune"] == summaries[1]["prune"]
    for name in ("scratches.csv", "scratches_unpruned.csv"):
        made = (job / "optimize" / name).read_bytes()
        assert made == (reference / "optimize" / name).read_bytes(), name
    logs = [(j / "optimize" / "log.csv").read_text().splitlines() for j in (job, reference)]
    drop_seconds = [[row.split(",")[:2] + row.split(",")[3:] for row in log] for log in logs]
    assert drop_seconds[0] == drop_seconds[1]
    # `run` afterwards finds the run finished and says so (not "interrupted")
    said_by_run: list[str] = []
    run_pipeline(load_pipeline(stopped[0]), job, until="optimize", say=said_by_run.append)
    assert any("it had finished: its outputs are kept" in line for line in said_by_run)
    assert (job / "optimize" / "scratches.csv").read_bytes() == made


@pytest.mark.parametrize(
    ("flags", "named", "advice"),
    [
        (["--seed", "6"], "(seed)", "--seed 5"),
        (["--lr-start-scale", "2"], "(lr_start_scale)", "--lr-start-scale 3.0"),
        (["--lr-schedule", "cosine"], "(lr_schedule)", "--lr-schedule linear"),
        (["--space", "linear"], "(space)", "--space perceptual"),
    ],
)
def test_an_option_given_otherwise_than_the_run_is_still_refused(
    job: Path, capsys: pytest.CaptureFixture[str], flags: list[str], named: str, advice: str
) -> None:
    """An option the command gives is the user's: one the run did not have is refused,
    naming it and the run's value, and nothing is written."""
    before = (job / "optimize" / "checkpoint.npz").read_bytes()
    code, said = cli_said(["optimize", str(job), *flags, "--resume"], capsys)
    assert code == 2 and "Traceback" not in said
    assert f"made with different settings {named}" in said
    assert f"it was made with {advice}: give that to resume it" in said
    assert (job / "optimize" / "checkpoint.npz").read_bytes() == before


def test_a_design_changed_since_the_stop_is_still_refused(
    job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The run's options taken from its checkpoint do not take its design: a changed board
    finish is named as before."""
    toml = job / "design" / "design.toml"
    design = load_job_design(toml)
    was = design.board.roughness
    replace(design, board=replace(design.board, roughness=was * 1.5)).save(toml)
    code, said = cli_said(["optimize", str(job), "--resume"], capsys)
    assert code == 2
    assert f"{toml} changed since it was made ([board] roughness {was:.6g} -> " in said
    assert "different settings" not in said


def test_a_value_the_checkpoint_holds_out_of_bounds_is_named_not_taken(
    job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A step size edited out of its bounds in the checkpoint is not taken (no option can
    be built from it): the refusal names it in one line, with no advice of flags."""
    ckpt = job / "optimize" / "checkpoint.npz"
    state, meta, rows = load_checkpoint(ckpt)
    meta["fingerprint"]["lr_position_mm"] = -1.0
    save_checkpoint(ckpt, state, meta, rows)
    assert "lr_position_mm" not in checkpoint_settings(read_checkpoint(ckpt))
    code, said = cli_said(["optimize", str(job), "--resume"], capsys)
    assert code == 2 and "Traceback" not in said
    assert "made with different settings (lr_position_mm)" in said
    assert said.rstrip().endswith("; run without --resume to start over")
    assert "give that" not in said


def _made_on_cuda(job: Path) -> None:
    """Mark the job's checkpoint as made on the CUDA backend (as a GPU machine writes it)."""
    ckpt = job / "optimize" / "checkpoint.npz"
    state, meta, rows = load_checkpoint(ckpt)
    assert meta["fingerprint"]["backend"] == "llvm"
    meta["fingerprint"]["backend"] = "cuda"
    save_checkpoint(ckpt, state, meta, rows)


@pytest.mark.parametrize(
    ("how", "falls_back"),
    [
        ("optimize --resume", True),  # the run's own backend cannot run here: the CPU
        ("optimize --resume --backend llvm", False),  # the user's flag wins
        ("run", False),  # the pipeline's [optimize] backend, as its file gives it
    ],
)
def test_a_run_made_on_cuda_resumes_on_the_cpu_with_a_note(
    stopped: tuple[Path, Path, Path],
    job: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    how: str,
    falls_back: bool,
) -> None:
    """A checkpoint recording ``cuda`` is resumed on llvm (no GPU here, or asked), not
    refused: a note says the backend changed. The steps ran on llvm throughout, so the
    layout is byte for byte the one the run never stopped made."""
    from scratchfab.cli import optimize_cmd

    monkeypatch.setattr(optimize_cmd, "backend_available", lambda name: name != "cuda")
    _made_on_cuda(job)
    if how == "run":
        lines: list[str] = []
        run_pipeline(load_pipeline(stopped[0]), job, until="optimize", say=lines.append)
        said = "\n".join(lines)
        assert "cannot continue it" not in said and "continuing the run from" in said
    else:
        code, said = cli_said(["optimize", str(job), *how.split()[1:]], capsys)
        assert code == 0, said
    ckpt = job / "optimize" / "checkpoint.npz"
    fallback = f"note: {ckpt} was made on the cuda backend, which cannot run here"
    assert (fallback in said) is falls_back
    assert (
        f"note: {ckpt} was made on the cuda backend; its steps go on on llvm, which rounds "
        "differently" in said
    )
    reference = stopped[2] / "optimize" / "scratches.csv"
    assert (job / "optimize" / "scratches.csv").read_bytes() == reference.read_bytes()
    assert load_checkpoint(ckpt)[1]["fingerprint"]["backend"] == "llvm"  # as it went on


def test_an_unavailable_backend_given_on_resume_is_refused_with_the_fix(
    job: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--backend cuda`` given where it cannot run is the user's: it fails (no fallback)
    with the fix, and the checkpoint is left as it was."""
    import drjit as dr

    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("this machine runs CUDA")
    ckpt = job / "optimize" / "checkpoint.npz"
    before = ckpt.read_bytes()
    code, said = cli_said(["optimize", str(job), "--resume", "--backend", "cuda"], capsys)
    assert code != 0 and "Traceback" not in said
    assert "the CUDA backend needs an NVIDIA GPU and driver; use --backend llvm" in said
    assert "which cannot run here" not in said
    assert ckpt.read_bytes() == before


def test_a_resume_on_more_threads_goes_on_with_a_note(
    stopped: tuple[Path, Path, Path], job: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--threads`` changes only the rounding (Dr.Jit's atomics add in another order): a
    resume on every core is not refused but noted, and ends where the run never stopped
    ends, to rounding; the checkpoint then records the threads it went on with."""
    from scratchfab.model.scratches import load_scratches

    code, said = cli_said(["optimize", str(job), "--resume", "--threads", "2"], capsys)
    assert code == 0, said
    ckpt = job / "optimize" / "checkpoint.npz"
    assert (
        f"note: {ckpt} was made with threads = 1; its steps go on with threads = 2, which "
        "rounds differently" in said
    )
    assert "made with different settings" not in said
    tool = load_job_design(job / "design" / "design.toml").scratch
    got, want = (load_scratches(j / "optimize" / "scratches.csv", tool) for j in (job, stopped[2]))
    assert len(got) == len(want)
    for a, b in ((got.p0, want.p0), (got.p1, want.p1)):
        assert abs(a - b).max() < 1e-6
    assert load_checkpoint(ckpt)[1]["fingerprint"]["threads"] == 2
