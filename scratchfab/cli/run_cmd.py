"""``scratchfab run``: a whole pipeline into one job folder."""

from __future__ import annotations

from pathlib import Path

import click

from scratchfab.pipeline.config import STAGES, load_pipeline
from scratchfab.pipeline.runner import run_pipeline


@click.command("run")
@click.argument("pipeline", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Job folder [the pipeline's [pipeline] out, else job-<file name>].",
)
@click.option("--from", "start", type=click.Choice(STAGES), help="Rerun from this stage on.")
@click.option("--until", type=click.Choice(STAGES), help="Stop after this stage.")
@click.option("--force", is_flag=True, help="Rerun every stage.")
def run(
    pipeline: Path, out: Path | None, start: str | None, until: str | None, force: bool
) -> None:
    """Run design -> optimize -> verify-render -> toolpath -> export (-> stream) into a job.

    Stages whose inputs did not change since the last run are skipped (JOB/manifest.json);
    a failed stage leaves earlier outputs intact and the next run resumes there.
    JOB/report.html shows the result.
    """
    pipe = load_pipeline(pipeline)
    job = out or Path(pipe.pipeline.out or f"job-{pipeline.stem}")
    try:
        result = run_pipeline(pipe, job, start=start, until=until, force=force, say=click.echo)
    finally:
        report = job / "report.html"
        if report.is_file():
            click.echo(f"report: {report}")
    ran = ", ".join(result.ran) or "nothing"
    click.echo(f"job {job}: ran {ran}; skipped {len(result.skipped)} in {result.seconds:.1f} s")
