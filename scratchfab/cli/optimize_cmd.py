"""``scratchfab optimize JOB``: the click layer over :func:`scratchfab.optimize.stage.run_optimize`."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import click

from scratchfab.cli.options import backend_option
from scratchfab.optimize.stage import OptimizeOptions, Progress, run_optimize


def _clock(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--:--"
    s = int(round(seconds))
    return (
        f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
        if s >= 3600
        else f"{s // 60:02d}:{s % 60:02d}"
    )


class _Bar:
    """A one-line progress bar with loss and ETA, redrawn in place on a terminal."""

    def __init__(self, width: int = 30) -> None:
        self.width = width
        self.last_len = 0
        self.tty = sys.stderr.isatty()
        self.last_decile = -1
        self.last_time = 0.0

    def __call__(self, p: Progress) -> None:
        if p.message:
            if self.tty:
                self._line(f"{p.message}...", newline=True)
            else:
                click.echo(f"{p.message}...", err=True)
            return
        frac = p.iteration / p.total if p.total else 1.0
        filled = int(round(frac * self.width))
        text = (
            f"[{'#' * filled}{'.' * (self.width - filled)}] {p.iteration}/{p.total} "
            f"loss {p.loss:.5f}  elapsed {_clock(p.elapsed_s)}  eta {_clock(p.eta_s)}"
        )
        if self.tty:
            self._line(text, newline=p.iteration >= p.total)
        elif int(10 * frac) != self.last_decile or time.monotonic() - self.last_time > 5:
            # Not a terminal (a log): a line per 10 % and at least every 5 s.
            self.last_decile = int(10 * frac)
            self.last_time = time.monotonic()
            click.echo(text, err=True)

    def _line(self, text: str, newline: bool) -> None:
        pad = " " * max(0, self.last_len - len(text))
        click.echo(f"\r{text}{pad}", nl=newline, err=True)
        self.last_len = 0 if newline else len(text)


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
    type=click.FloatRange(min=0),
    default=0.0,
    show_default=True,
    help="Stop after this many seconds of optimizing (0: no limit).",
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
    type=click.FloatRange(min=0),
    default=None,
    is_flag=False,
    flag_value=0.01,
    help="Drop scratches while the loss rises by at most this fraction [0.01].",
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

    Ctrl-C stops after the current step and writes everything; --resume continues.
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
    result = run_optimize(job, options, progress=_Bar())
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
            f"{_clock(p.time_saved_s)} of machining saved (at {p.feed_mm_min:g} mm/min + "
            f"{p.stroke_overhead_s:g} s per stroke)"
        )
    click.echo(
        f"{result.iterations} iterations ({result.stopped}), loss {result.loss:.5f}; "
        f"wrote {result.out_dir}"
    )
