"""``scratchfab optimize JOB``: the click layer over :func:`scratchfab.optimize.stage.run_optimize`."""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import click

from scratchfab.backend import backend_available
from scratchfab.cli.options import FiniteFloat, RedrawnLine, backend_option
from scratchfab.console import command_line
from scratchfab.errors import ConfigError, Interrupted
from scratchfab.metrics import CROSSTALK_MEANING
from scratchfab.model.job import JobLayout
from scratchfab.optimize.checkpoint import Checkpoint, read_checkpoint
from scratchfab.optimize.progress import clock, progress_printer
from scratchfab.optimize.stage import (
    NOTHING_TO_DO,
    OptimizeOptions,
    Progress,
    ResumeRefused,
    checkpoint_request,
    checkpoint_settings,
    run_optimize,
)

_DEFAULTS = OptimizeOptions()
#: The options whose parameters the command's share names with :class:`OptimizeOptions`.
_FIELDS = frozenset(f.name for f in fields(OptimizeOptions))


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
    help="Total Adam steps (a resumed run continues up to this count; with --resume "
    "alone, the run's own total).",
)
@click.option(
    "--time-budget",
    "time_budget_s",
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
@click.option(
    "--lr-schedule",
    type=click.Choice(["constant", "linear", "cosine"]),
    default=_DEFAULTS.lr_schedule,
    show_default=True,
    help="How the step sizes change over --iterations: from --lr-start-scale times the "
    "base steps at the first step to --lr-end-scale times at the last, along a cosine or "
    "a line; constant: the base steps throughout (scales 1).",
)
@click.option(
    "--lr-start-scale",
    type=FiniteFloat(min=0, min_open=True),
    default=_DEFAULTS.lr_start_scale,
    show_default=True,
    help="Step sizes of the first step, as a multiple of the base steps.",
)
@click.option(
    "--lr-end-scale",
    type=FiniteFloat(min=0, min_open=True),
    default=_DEFAULTS.lr_end_scale,
    show_default=True,
    help="Step sizes of the last step, as a multiple of the base steps.",
)
@click.option(
    "--resume",
    is_flag=True,
    help="Continue from JOB/optimize/checkpoint.npz with the run's own options where not "
    "given (its total, step sizes, schedule, seed and --prune), as `scratchfab run` "
    "started it too; its backend too, but llvm where a cuda run finds no GPU (--backend "
    "and --threads may differ: noted).",
)
@click.option(
    "--prune",
    "prune_tolerance",
    type=FiniteFloat(min=0),
    default=None,
    is_flag=False,
    flag_value=0.01,
    metavar="[FRACTION]",
    help="After optimizing, drop scratches while the loss rises by at most this fraction "
    "(--prune alone: 0.01; put it after JOB; --resume without it: the run's own).",
)
@click.option(
    "--no-prune",
    is_flag=True,
    help="Keep every scratch: with --resume, drop the run's own --prune (it runs after "
    "the steps, so they are the same).",
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
    time_budget_s: float,
    seed: int,
    backend: str,
    space: str,
    threads: int,
    lr_schedule: str,
    lr_start_scale: float,
    lr_end_scale: float,
    resume: bool,
    prune_tolerance: float | None,
    no_prune: bool,
    checkpoint_every: int,
) -> None:
    """Optimize the scratch layout of JOB (reads JOB/design, writes JOB/optimize).

    Ctrl-C stops after the current step, writes everything and exits with 130;
    --resume continues.
    """
    ctx = click.get_current_context()
    scaled = [name for name in ("lr_start_scale", "lr_end_scale") if _given(ctx, name)]
    asked_constant = lr_schedule == "constant"
    if asked_constant and scaled:
        raise click.BadParameter(
            "a constant schedule keeps the base steps: give --lr-schedule linear or "
            "cosine with a scale (equal start and end scales: constant steps of that "
            "multiple)",
            param_hint=f"--{scaled[0].replace('_', '-')}",
        )
    if no_prune and prune_tolerance is not None:
        raise click.BadParameter("give --prune or --no-prune, not both", param_hint="--no-prune")
    asked = {k: v for k, v in ctx.params.items() if k in _FIELDS}
    given = {k for k in asked if _given(ctx, k)} | ({"prune_tolerance"} if no_prune else set())
    checkpoint: Checkpoint | None = None
    if resume:  # what the command does not give, the run's own (its steps', total, prune)
        checkpoint = read_checkpoint(JobLayout(job).optimize_checkpoint)
        own = {**checkpoint_settings(checkpoint), **checkpoint_request(job, checkpoint)}
        if "iterations" not in own and "iterations" not in given:
            raise ConfigError(_no_total(checkpoint))
        asked.update((k, v) for k, v in own.items() if k not in given)
        # a run made on a GPU goes on where there is none (--backend given: the user's)
        if (
            "backend" not in given
            and own.get("backend") == "cuda"
            and not backend_available("cuda")
        ):
            click.echo(
                f"note: {checkpoint.path} was made on the cuda backend, which cannot run "
                "here (no NVIDIA GPU and driver): resuming on llvm (the CPU)"
            )
            asked["backend"] = "llvm"
        if no_prune and own.get("prune_tolerance") is not None:
            click.echo(
                f"--no-prune: the run's own --prune {own['prune_tolerance']:g} is dropped; "
                "its outputs are written without pruning"
            )
    options = OptimizeOptions(**asked)
    try:
        result = run_optimize(job, options, progress=_bar(), checkpoint=checkpoint)
    except ResumeRefused as exc:
        raise ConfigError(
            exc.message(lambda made: _as_flags(made, options, asked_constant, bool(scaled)))
        ) from None
    if result.stopped == NOTHING_TO_DO:
        click.echo(
            f"nothing to do: the run had done its {result.iterations} iterations and "
            f"{result.out_dir} holds its outputs; give --iterations N (more than "
            f"{result.iterations}) with --resume to go on"
        )
        return
    views = result.quality["views"]
    for name, v in views.items():
        cross = ", ".join(f"crosstalk from {j} {x:.3f}" for j, x in v["crosstalk"].items())
        glint = (
            f" (over every pixel, its glint on {100 * result.glint[name]:.1f}% of the board too, "
            "which optimize left out)"
            if name in result.glint
            else ""
        )
        click.echo(
            f"{name}: PSNR {v['psnr']:.2f} dB, rho {v['rho']:.3f}"
            + (f", {cross}" if cross else "")
            + glint
        )
    if any(v["crosstalk"] for v in views.values()):
        click.echo(f"crosstalk from j: j's picture showing in the view, {CROSSTALK_MEANING}")
    if result.prune is not None:
        p = result.prune
        click.echo(
            f"pruned {p.removed} scratches: {p.length_saved_mm:.0f} mm of cutting, about "
            f"{clock(p.time_saved_s)} of machining saved (at {p.feed_mm_min:g} mm/min + "
            f"{p.stroke_overhead_s:g} s per stroke); loss {p.loss_before:.5f} -> "
            f"{p.loss_after:.5f}"
        )
    # A step gives the loss of the layout it started from; the layout after the last step
    # (and pruning) is evaluated afresh, so this loss is not the last progress line's.
    after = "after the last step" + (" and pruning" if result.prune is not None else "")
    click.echo(
        f"{result.iterations} iterations ({result.stopped}), loss {result.loss:.5f} {after} "
        f"(a progress line shows the loss its step started from); wrote {result.out_dir}"
    )
    _note_stale_toolpath(job)
    if result.stopped == "time budget":  # a resume given the same budget would take no step
        go_on = command_line(["scratchfab", "optimize", job, "--resume"])
        click.echo(
            f"stopped by --time-budget {options.time_budget_s:g}, which counts the run's "
            f"optimizing in all, its earlier sessions' too; `{go_on}` goes on to its "
            f"{options.iterations} iterations (with --time-budget S, S more than the time "
            "spent, it stops before that)"
        )
    if result.stopped == "interrupted":  # exit 130: `optimize && toolpath` stops here
        again: list[str | Path] = ["scratchfab", "optimize", job, *_given_flags(ctx), "--resume"]
        raise Interrupted(
            f"interrupted after {result.iterations} of {options.iterations} iterations; "
            f"`{command_line(again)}` continues it"
        )


def _note_stale_toolpath(job: Path) -> None:
    """Name a toolpath the new layout left behind, in export's own words (and commands).

    ``toolpath`` and ``export`` refuse it and ``stream`` asks about it, later; a person who
    re-optimizes is told at once what to plan and export again.
    """
    from scratchfab.toolpath import Toolpath
    from scratchfab.toolpath.inputs import check_current

    file = JobLayout(job).toolpath_json
    if not file.is_file():
        return
    try:
        stale, _ = check_current(Toolpath.load(file))
    except ConfigError:  # a damaged toolpath: toolpath and export say so themselves
        return
    if stale is not None:
        click.echo(f"note: {stale}")


def _no_total(checkpoint: Checkpoint) -> str:
    """Why ``--resume`` needs ``--iterations`` for a checkpoint that keeps no total."""
    done = checkpoint.done
    return (
        f"{checkpoint.path}: the run's total is not known: its checkpoint, made by an earlier "
        "scratchfab, does not keep it"
        + (f" (it had done {done} iterations)" if done is not None else "")
        + ", and no summary.json written from it tells it (a run killed before writing its "
        "outputs leaves none); give --iterations N with --resume, N the total the run was "
        "last given"
    )


def _given_flags(ctx: click.Context) -> list[str]:
    """The options this command was given, as flags, less --resume.

    A resume takes the options its checkpoint keeps where it is not given them, but not
    ``--time-budget``, so the advice repeats what was given.
    """
    return [
        word
        for p in optimize.params
        if isinstance(p, click.Option) and p.name != "resume" and _given(ctx, p.name or "")
        for word in ([p.opts[0]] if p.is_flag else [p.opts[0], str(ctx.params[p.name or ""])])
    ]


def _given(ctx: click.Context, name: str) -> bool:
    """Whether this command was given the option of parameter ``name``."""
    return ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT


def _as_flags(
    made_with: dict[str, Any], options: OptimizeOptions, asked_constant: bool, scaled: bool
) -> str | None:
    """A checkpoint's option values as flags that, added to this command, resume it.

    None when one has no flag. A schedule of scales 1 is written ``--lr-schedule constant``
    unless the command gave a scale (which constant refuses: then the scales); a command
    that asked for constant steps gets the checkpoint's schedule whole, as the scales it
    leaves out would take their defaults once another shape replaces constant.

    Args:
        made_with: :attr:`ResumeRefused.made_with`, compared with ``options``.
        options: The options this command ran with.
        asked_constant: The command gave ``--lr-schedule constant``.
        scaled: The command gave ``--lr-start-scale`` or ``--lr-end-scale``.
    """
    flags = {p.name: p.opts[0] for p in optimize.params if p.name}
    wanted = dict(made_with)
    schedule: dict[str, Any] = {}
    keys = ("lr_schedule", "lr_start_scale", "lr_end_scale")
    if wanted.keys() & set(keys):
        whole = {k: wanted.pop(k, getattr(options, k)) for k in keys}
        try:  # a checkpoint edited by hand may hold values out of bounds
            constant = replace(options, **whole).schedule() is None
        except (TypeError, ValueError):
            return None
        if constant and not scaled:
            schedule = {"lr_schedule": "constant"}
        else:
            schedule = {k: v for k, v in whole.items() if asked_constant or k in made_with}
    if not set(wanted) <= set(flags):
        return None
    return " ".join(f"{flags[k]} {v}" for k, v in {**schedule, **wanted}.items())
