"""``scratchfab render``: the analytic renderer on a design and a scratch file, or a job."""

from __future__ import annotations

import time
from pathlib import Path

import click

from scratchfab.cli.options import backend_option
from scratchfab.errors import ScratchfabError
from scratchfab.model.design import load_design
from scratchfab.model.job import job_inputs
from scratchfab.model.scratches import load_scratches
from scratchfab.render.layout import write_render_layout
from scratchfab.render.renderer import render_scratches


@click.command("render")
@click.argument("job", required=False, type=click.Path(path_type=Path))
@click.option("--design", "design_file", type=click.Path(path_type=Path), help="Design TOML.")
@click.option(
    "--scratches", "scratch_file", type=click.Path(path_type=Path), help="Scratch CSV (mm)."
)
@click.option(
    "--out", "out_dir", type=click.Path(path_type=Path), help="Output folder (default JOB/render)."
)
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

    The .npy files are float32 (H, W) linear radiance (SPEC section 4). The .png preview
    is 8-bit grey: radiance divided by the image's 99.5th percentile of positive values,
    clipped to [0, 1], sRGB-encoded; that exposure is stored in the PNG's text chunk
    "scratchfab.exposure".
    """
    if job is not None:
        if design_file is not None or scratch_file is not None:
            raise ScratchfabError("give either JOB or --design/--scratches, not both")
        design_file, scratch_file = job_inputs(job)
        out_dir = out_dir if out_dir is not None else job / "render"
    elif design_file is None or scratch_file is None or out_dir is None:
        raise ScratchfabError("give JOB, or all of --design FILE --scratches CSV --out DIR")
    start = time.perf_counter()
    design = load_design(design_file)
    scratches = load_scratches(scratch_file, design.scratch, design.board)
    click.echo(f"rendering {len(scratches)} scratches, {len(design.views)} views ({backend})")
    images = render_scratches(
        design,
        scratches,
        backend="cuda" if backend == "cuda" else "llvm",
        progress=lambda line: click.echo(f"  {line}"),
    )
    write_render_layout(out_dir, images)
    click.echo(f"wrote {out_dir} in {time.perf_counter() - start:.1f} s")
