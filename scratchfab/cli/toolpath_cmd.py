"""``scratchfab toolpath``: order a board's scratches for a machine."""

from __future__ import annotations

from pathlib import Path

import click

from scratchfab.errors import ScratchfabError
from scratchfab.machine.profile import bundled_profiles, load_profile
from scratchfab.model.design import load_design
from scratchfab.model.scratches import load_scratches
from scratchfab.toolpath import OrderOptions, plan_toolpath, write_preview


def _inputs(
    job: Path | None, scratches: Path | None, design: Path | None, out: Path | None
) -> tuple[Path, Path, Path]:
    if job is None:
        if scratches is None or design is None or out is None:
            raise ScratchfabError(
                "give a JOB folder, or all of --scratches CSV --design FILE --out DIR"
            )
        return scratches, design, out
    if not job.is_dir():
        raise ScratchfabError(f"{job}: job folder not found")
    if scratches is None:
        scratches = job / "optimize" / "scratches.csv"
        if not scratches.is_file():
            fallback = job / "design" / "scratches.csv"
            click.echo(
                f"note: {scratches} not found (optimize has not run); using {fallback}", err=True
            )
            scratches = fallback
    return scratches, design or job / "design" / "design.toml", out or job / "toolpath"


@click.command("toolpath")
@click.argument("job", required=False, type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--machine",
    "-m",
    required=True,
    help=f"Bundled profile ({', '.join(bundled_profiles())}) or a profile TOML file.",
)
@click.option(
    "--scratches",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Scratch CSV (default: JOB/optimize/scratches.csv).",
)
@click.option(
    "--design",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Design TOML (default: JOB/design/design.toml).",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    help="Output folder (default: JOB/toolpath).",
)
@click.option(
    "--passes",
    default=OrderOptions.passes,
    show_default=True,
    help="Cap on 2-opt/Or-opt work, in visits per stroke (0: greedy only).",
)
@click.option("--seed", default=0, show_default=True, help="Seed of the ordering's perturbations.")
def toolpath(
    job: Path | None,
    machine: str,
    scratches: Path | None,
    design: Path | None,
    out: Path | None,
    passes: int,
    seed: int,
) -> None:
    """Order the strokes for a machine: JOB/toolpath/toolpath.json and preview.png.

    Clips the scratches to the board and the machine's envelope, drops those shorter
    than the tool's minimum, merges collinear duplicates, orders them to minimise pen-up
    travel from the start position and estimates the machining time.
    """
    if passes < 0:
        raise ScratchfabError(f"--passes must be >= 0, got {passes}")
    csv_path, design_path, out_dir = _inputs(job, scratches, design, out)
    profile = load_profile(machine)
    loaded = load_design(design_path, require_views=False)
    board_scratches = load_scratches(csv_path, loaded.scratch, loaded.board)
    click.echo(f"ordering {len(board_scratches)} scratches for {profile.name} ...", err=True)
    result = plan_toolpath(
        board_scratches,
        loaded.board,
        profile,
        loaded.scratch,
        OrderOptions(passes=passes, seed=seed),
    )
    result.save(out_dir / "toolpath.json")
    write_preview(result, out_dir / "preview.png")
    s = result.stats
    dropped = s["outside_count"] + s["short_count"] + s["merged_count"]
    click.echo(
        f"{s['count']} strokes ({dropped} dropped: {s['outside_count']} outside, "
        f"{s['short_count']} too short, {s['merged_count']} duplicates); "
        f"cut {s['cut_length_mm']:.1f} mm, travel {s['travel_length_mm']:.1f} mm "
        f"(input order {s['travel_input_order_mm']:.1f} mm); "
        f"about {s['estimated_time_s'] / 60:.1f} min"
    )
    click.echo(f"wrote {out_dir / 'toolpath.json'} and {out_dir / 'preview.png'}")
