"""``scratchfab run``: a whole pipeline into one job folder."""

from __future__ import annotations

from pathlib import Path

import click

from scratchfab.cli.options import confirm
from scratchfab.errors import ScratchfabError
from scratchfab.model.job import JobLayout
from scratchfab.pipeline.config import STAGES, load_pipeline
from scratchfab.pipeline.runner import run_pipeline


@click.command("run")
@click.argument("pipeline", metavar="PIPELINE")
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    show_default="the pipeline's [pipeline] out (relative to the pipeline file), "
    "else job-<file name>",
    help="Job folder.",
)
@click.option(
    "--from",
    "start",
    type=click.Choice(STAGES),
    help="Rerun from this stage on (stream: only with --from stream or a changed G-code).",
)
@click.option("--until", type=click.Choice(STAGES), help="Stop after this stage.")
@click.option("--force", is_flag=True, help="Rerun every stage (streaming included).")
@click.option(
    "--yes",
    is_flag=True,
    help="Do not ask for confirmation before streaming to a machine (a board the envelope "
    "cuts short, or a resume after an alarm that may have lost the position without "
    "--homed, is then refused).",
)
@click.option(
    "--homed",
    is_flag=True,
    help="The stream being resumed ended in a way that may have lost the position (an "
    "alarm, a lost link, a stop after which the controller was found reset), and the "
    "machine was homed ($H), or unlocked ($X) and its work zero set again, since (else "
    "asked; refused under --yes).",
)
@click.option(
    "--zero-here",
    is_flag=True,
    help="When the stream stage runs: the tool stands at the board's origin point; set the "
    "work zero there once connected (as stream --zero-here), and on a resume it stands "
    "for --homed.",
)
def run(
    pipeline: str,
    out: Path | None,
    start: str | None,
    until: str | None,
    force: bool,
    yes: bool,
    homed: bool,
    zero_here: bool,
) -> None:
    """Run design -> optimize -> verify-render -> toolpath -> export (-> stream) into a job.

    PIPELINE is a pipeline TOML, or a bundled pipeline's name: `scratchfab run demo` runs
    the bundled demo into ./job-demo.

    Stages whose inputs did not change since the last run are skipped (JOB/manifest.json);
    a failed stage leaves earlier outputs intact and the next run resumes there. The G-code
    is streamed again only when it or the [stream] options changed, or with --from stream
    or --force; a real port (not grblsim://) asks first unless --yes.
    JOB/report.html shows the result.
    """
    pipe = load_pipeline(pipeline)
    job = pipe.job_dir(out)
    report = JobLayout(job).report_html
    try:
        result = run_pipeline(
            pipe,
            job,
            start=start,
            until=until,
            force=force,
            say=click.echo,
            confirm=None if yes else confirm,
            homed=homed,
            zero_here=zero_here,
        )
    except ScratchfabError as exc:
        # the error first, then where the report is: the CLI prints the error's text
        if report.is_file() and len(exc.args) == 1:
            exc.args = (f"{exc.args[0]}\nreport: {report}",)
        raise
    except BaseException:
        if report.is_file():
            click.echo(f"report: {report}")
        raise
    if report.is_file():
        click.echo(f"report: {report}")
    ran = ", ".join(result.ran) or "nothing"
    click.echo(f"job {job}: ran {ran}; skipped {len(result.skipped)} in {result.seconds:.1f} s")
