"""``scratchfab render``: the analytic renderer on a design and a scratch file, or a job."""

from __future__ import annotations

import time
from pathlib import Path

import click

from scratchfab.cli.options import backend_option, job_or_files, job_or_files_options
from scratchfab.model.job import JobLayout, job_inputs, stale_layout_warning


@click.command("render")
@job_or_files_options("render")
@backend_option
def render(
    job: Path | None,
    design_file: Path | None,
    scratch_file: Path | None,
    out_dir: Path | None,
    backend: str,
) -> None:
    """Render every view of a board: <view>.npy (linear radiance) and <view>.png.

    Either JOB (reads JOB/design/design.toml and JOB/optimize/scratches.csv, else
    JOB/design/scratches.csv; writes JOB/render/) or --design FILE --scratches CSV --out DIR.

    The .npy files are float32 (H, W) linear radiance (docs/files.md). The .png preview
    is 8-bit grey: radiance divided by the image's 99.5th percentile of positive values,
    clipped to [0, 1], sRGB-encoded; that exposure is stored in the PNG's text chunk
    "scratchfab.exposure".
    """
    # Imported here, not for --help: the renderer loads Dr.Jit.
    from scratchfab.render.stage import run_render

    inputs = job_or_files(job, design_file, scratch_file, out_dir)
    if isinstance(inputs, tuple):
        design_file, scratch_file, out_dir = inputs
    else:
        design_file, scratch_file = job_inputs(inputs)
        stale = stale_layout_warning(inputs)
        if stale is not None:
            click.echo(stale, err=True)
        out_dir = out_dir if out_dir is not None else JobLayout(inputs).render_dir
    start = time.perf_counter()
    run_render(
        design_file, scratch_file, out_dir, "cuda" if backend == "cuda" else "llvm", click.echo
    )
    click.echo(f"wrote {out_dir} in {time.perf_counter() - start:.1f} s")
