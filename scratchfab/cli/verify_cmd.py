"""``scratchfab verify-render``: the independent Mitsuba 3 check before metal is cut."""

from __future__ import annotations

import time
from pathlib import Path

import click

from scratchfab.cli.options import FiniteFloat, job_or_files, job_or_files_options
from scratchfab.errors import ScratchfabError
from scratchfab.model.job import JobLayout
from scratchfab.verify.verify import DEFAULT_SPP, bad_sweep_frames


@click.command("verify-render")
@job_or_files_options("verify")
@click.option(
    "--spp",
    type=click.IntRange(min=2),
    default=DEFAULT_SPP,
    show_default=True,
    help="Samples per pixel, at least 16 taken (two independent halves; their difference "
    "gives the noise).",
)
@click.option(
    "--max-noise",
    type=FiniteFloat(min=0, min_open=True),
    default=None,
    help="Add sample batches until the estimated relative noise is at most this (two at a "
    "time, of the size the noise so far says reaches it; up to 8x --spp in all).",
)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Sampler and jitter seed.",
)
@click.option("--sky", is_flag=True, help="Also render under sun and sky (writes OUT/sky/).")
@click.option(
    "--sky-strength",
    type=FiniteFloat(min=0, min_open=True),
    default=1.0,
    show_default=True,
    help="Sun-and-sky irradiance on the board relative to the design light's.",
)
@click.option(
    "--sun",
    "sun_direction",
    type=(FiniteFloat(), FiniteFloat(), FiniteFloat()),
    default=(0.35, 0.8, 0.5),
    show_default=True,
    help="Direction toward the sun (x right, y up, z out of the board).",
)
@click.option(
    "--sweep",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Render N >= 2 cameras along a path through the views; writes OUT/sweep.gif.",
)
@click.option(
    "--jitter",
    is_flag=True,
    help="Re-render with scratches perturbed by the machine's tolerances; report metric drops.",
)
@click.option(
    "--machine",
    help="Machine profile (bundled name or TOML) giving the jitter's position tolerance.",
)
@click.option(
    "--min-rho",
    type=FiniteFloat(-1, 1),
    default=None,
    help="Exit non-zero (3) when any view's rho_kk is below this.",
)
@click.option(
    "--backend",
    "--variant",
    "backend",
    type=click.Choice(["llvm", "cuda"]),
    default="llvm",
    show_default=True,
    help="Mitsuba variant family: llvm (CPU) or cuda (NVIDIA GPU).",
)
def verify_render(
    job: Path | None,
    design_file: Path | None,
    scratch_file: Path | None,
    out_dir: Path | None,
    spp: int,
    max_noise: float | None,
    seed: int,
    sky: bool,
    sky_strength: float,
    sun_direction: tuple[float, float, float],
    sweep: int,
    jitter: bool,
    machine: str | None,
    min_rho: float | None,
    backend: str,
) -> None:
    """Render a board in Mitsuba 3 and compare with the analytic render.

    Either JOB (reads JOB/design/design.toml and JOB/optimize/scratches.csv, else
    JOB/design/scratches.csv; writes JOB/verify/) or --design FILE --scratches CSV --out
    DIR. Writes <view>.npy and <view>.png like `render`, and metrics.json: per view
    the relative L2 error against the analytic render, the noise estimate, PSNR,
    rho_kk and the rho_kk a noise-free render would reach, crosstalk, spp and time.
    Where the sampling noise lowers rho, the output says by how much and which --spp
    ends it. For each view with a target, diff/<view>.png shows where the board comes
    out brighter or darker than it.
    """
    from scratchfab.verify.jitter import Tolerance
    from scratchfab.verify.scene import Sky, bad_sun_direction
    from scratchfab.verify.verify import (
        VerifySettings,
        run_verify_files,
        run_verify_job,
    )

    if machine is not None and not jitter:
        raise ScratchfabError("--machine only sets the --jitter tolerances; add --jitter")
    if (why := bad_sweep_frames(sweep)) is not None:
        raise ScratchfabError(f"--sweep: {why}")
    if sky and (why := bad_sun_direction(sun_direction)) is not None:
        raise ScratchfabError(f"--sun: {why}")
    tolerance = None
    if jitter:
        tolerance = Tolerance.from_profile(machine) if machine else Tolerance()
    settings = VerifySettings(
        spp=spp,
        seed=seed,
        backend="cuda" if backend == "cuda" else "llvm",
        sky=Sky(sun_direction=sun_direction, strength=sky_strength) if sky else None,
        sweep=sweep,
        jitter=tolerance,
        min_rho=min_rho,
        max_noise=max_noise,
    )
    start = time.perf_counter()

    inputs = job_or_files(job, design_file, scratch_file, out_dir)
    if isinstance(inputs, tuple):
        design_file, scratch_file, out = inputs
        run_verify_files(design_file, scratch_file, out, settings, progress=click.echo)
    else:
        out = out_dir if out_dir is not None else JobLayout(inputs).verify_dir
        run_verify_job(inputs, settings, progress=click.echo, out_dir=out)
    click.echo(f"wrote {out} in {time.perf_counter() - start:.1f} s")
