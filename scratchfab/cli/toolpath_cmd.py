"""``scratchfab toolpath``: order a board's scratches for a machine."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import click

from scratchfab.bundled import bundled_names
from scratchfab.errors import ScratchfabError
from scratchfab.model.job import JobLayout
from scratchfab.toolpath import OrderOptions


def run_toolpath(
    scratch_file: Path,
    design_file: Path,
    out_dir: Path,
    machine: str,
    options: OrderOptions,
    say: Callable[[str], None],
    refuse_partial: str | None = None,
    job: Path | None = None,
) -> None:
    """:func:`scratchfab.toolpath.stage.run_toolpath`, the stage imported when it runs."""
    # Not imported for --help: the stage plans with shapely and draws with Pillow.
    from scratchfab.toolpath.stage import run_toolpath as run

    run(scratch_file, design_file, out_dir, machine, options, say, refuse_partial, job)


def _inputs(
    job: Path | None,
    scratches: Path | None,
    design: Path | None,
    out: Path | None,
    refuse: str | None,
) -> tuple[Path, Path, Path, Path | None]:
    """(scratches, design, output folder, the job when its layout picked both files).

    ``refuse`` names the override of a refusal (a stale layout), None to warn instead.
    """
    from scratchfab.toolpath.stage import job_toolpath_inputs

    if job is None:
        if scratches is None or design is None or out is None:
            raise ScratchfabError(
                "give a JOB folder, or all of --scratches CSV --design FILE --out DIR"
            )
        return scratches, design, out, None
    scratch_file, design_file, note = job_toolpath_inputs(job, scratches, design, refuse)
    if note:
        click.echo(note, err=True)
    picked = job if scratches is None and design is None else None
    return scratch_file, design_file, out or JobLayout(job).toolpath_dir, picked


@click.command("toolpath")
@click.argument("job", required=False, type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--machine",
    "-m",
    required=True,
    help=f"Bundled profile ({', '.join(bundled_names('machine_profiles'))}) or a profile TOML file.",
)
@click.option(
    "--scratches",
    type=click.Path(dir_okay=False, path_type=Path),
    show_default="JOB/optimize/scratches.csv",
    help="Scratch CSV.",
)
@click.option(
    "--design",
    type=click.Path(dir_okay=False, path_type=Path),
    show_default="JOB/design/design.toml",
    help="Design TOML.",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    show_default="JOB/toolpath",
    help="Output folder.",
)
@click.option(
    "--passes",
    type=click.IntRange(0),
    default=OrderOptions.passes,
    show_default=True,
    help="Cap on local-search work (flip chains, Or-opt), in visits per stroke (0: greedy only).",
)
@click.option(
    "--seed",
    type=click.IntRange(0, 2**32 - 1),
    default=0,
    show_default=True,
    help="Seed of the ordering's perturbations.",
)
@click.option(
    "--kicks",
    type=click.IntRange(0),
    default=None,
    show_default=f"{OrderOptions.kicks_per_stroke:g} per stroke, at most {OrderOptions.max_kicks}",
    help="Perturbation trials in all. More trials: shorter travel, longer run.",
)
@click.option(
    "--force",
    is_flag=True,
    help="Plan anyway (warned): the part the machine reaches of a board its envelope cuts "
    "short, or a layout optimized from an earlier design.",
)
def toolpath(
    job: Path | None,
    machine: str,
    scratches: Path | None,
    design: Path | None,
    out: Path | None,
    passes: int,
    seed: int,
    kicks: int | None,
    force: bool,
) -> None:
    """Order the strokes for a machine: JOB/toolpath/toolpath.json and preview.png.

    Either JOB (reads JOB/optimize/scratches.csv, else JOB/design/scratches.csv, and
    JOB/design/design.toml) or all of --scratches, --design and --out. A plan of the
    design's initial layout (optimize has not run) is warned of, naming the optimize to
    run first; export and the G-code header then say it is not optimized.

    Clips the scratches to the board, drops those shorter than the tool's minimum,
    merges collinear duplicates, orders them to minimise pen-up travel from the start
    position and estimates the machining time. A board that the machine's envelope cuts
    short is refused, with the offset_mm that fits it or the largest board that fits (an
    earlier plan in the output folder stays; one for other machine settings is named,
    with its profile); --force
    plans the part within reach, and export repeats the warning. So is a layout
    optimized from an earlier design (rerun optimize; --force plans it as it is).
    """
    refuse = None if force else "--force"
    csv_path, design_path, out_dir, picked = _inputs(job, scratches, design, out, refuse)
    options = OrderOptions(passes=passes, seed=seed, kicks=kicks)
    run_toolpath(csv_path, design_path, out_dir, machine, options, click.echo, refuse, picked)
    click.echo(f"wrote {out_dir / 'toolpath.json'} and {out_dir / 'preview.png'}")
