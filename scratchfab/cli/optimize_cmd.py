"""``scratchfab optimize JOB``: the click layer over :func:`scratchfab.optimize.stage.run_optimize`."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import click

from scratchfab.cli.options import FiniteFloat, RedrawnLine, backend_option
from scratchfab.console import command_line
from scratchfab.errors import Interrupted
from scratchfab.optimize.progress import clock, progress_printer
from scratchfab.optimize.stage import OptimizeOptions, Progress, run_optimize


def _bar() -> Callable[[Progress], None]:
    """Progress on stderr: a bar redrawn in place on a terminal, else throttled lines."""
    return progress_printer(
        lambda text: click.echo(text, err=True), RedrawnLine() if sys.stderr.isatty() else None
    )


@click.command("optimize")
@click.argument("job", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--iterations",
    type=click.IntRange(min=0),
    default=300,
    show_default=True,
    help="Total Adam steps (a resumed run continues up to this count).",
)
@click.option(
    "--time-budget",
    type=FiniteFloat(min=0),
    default=0.0,
    show_default=True,
    help="Stop after this many seconds of optimizing (0: no limit). The step sizes shrink "
    "over --iterations, not over the budget: give the steps that fit in it.",
)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Seed of the run's random generator.",
)
@backend_option
@click.option(
    "--space",
    type=click.Choice(["linear", "perceptual"]),
    default="linear",
    show_default=True,
    help="Space of the image error.",
)
@click.option(
    "--threads",
    type=click.IntRange(min=0),
    default=1,
    show_default=True,
    help="CPU threads; 1 is bit-reproducible, 0 uses every core.",
)
@click.option("--resume", is_flag=True, help="Continue from JOB/optimize/checkpoint.npz.")
@click.option(
    "--prune",
    "prune_tolerance",
    type=FiniteFloat(min=0),
    default=None,
    is_flag=False,
    flag_value=0.01,
    metavar="[FRACTION]",
    help="After optimizing, drop scratches while the loss rises by at most this fraction "
    "(--prune alone: 0.01; put it after JOB).",
)
@click.option(
    "--checkpoint-every",
    type=click.IntRange(min=1),
    default=25,
    show_default=True,
    help="Steps between checkpoints.",
)
def optimize(
    job: Path,
    iterations: int,
    time_budget: float,
    seed: int,
    backend: str,
    space: str,
    threads: int,
    resume: bool,
    prune_tolerance: float | None,
    checkpoint_every: int,
) -> None:
    """Optimize the scratch layout of JOB (reads JOB/design, writes JOB/optimize).

    Ctrl-C stops after the current step, writes everything and exits with 130;
    --resume continues.
    """
    options = OptimizeOptions(
        iterations=iterations,
        time_budget_s=time_budget,
        seed=seed,
        backend=backend,  # type: ignore[arg-type]
        space=space,  # type: ignore[arg-type]
        threads=threads,
        resume=resume,
        prune_tolerance=prune_tolerance,
        checkpoint_every=checkpoint_every,
    )
    result = run_optimize(job, options, progress=_bar())
    views = result.quality["views"]
    for name, v in views.items():
        cross = ", ".join(f"x_{name},{j} = {x:.3f}" for j, x in v["crosstalk"].items())
        click.echo(
            f"{name}: PSNR {v['psnr']:.2f} dB, rho {v['rho']:.3f}" + (f", {cross}" if cross else "")
        )
    if result.prune is not None:
        p = result.prune
        click.echo(
            f"pruned {p.removed} scratches: {p.length_saved_mm:.0f} mm of cutting, about "
            f"{clock(p.time_saved_s)} of machining saved (at {p.feed_mm_min:g} mm/min + "
            f"{p.stroke_overhead_s:g} s per stroke)"
        )
    click.echo(
        f"{result.iterations} iterations ({result.stopped}), loss {result.loss:.5f}; "
        f"wrote {result.out_dir}"
    )
    if result.stopped == "interrupted":  # exit 130: `optimize && toolpath` stops here
        raise Interrupted(
            f"interrupted after {result.iterations} of {iterations} iterations; "
            f"`{command_line(['scratchfab', 'optimize', job, '--resume'])}` continues it"
        )
