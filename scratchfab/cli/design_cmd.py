"""``scratchfab design``: the click layer over :mod:`scratchfab.design.stage`."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import click

from scratchfab.bundled import bundled_dir, bundled_names, is_file, names_a_file
from scratchfab.cli.options import FiniteFloat, SizePair
from scratchfab.errors import ConfigError

if TYPE_CHECKING:
    from scratchfab.model.design import Design


@click.command("design")
@click.argument("inputs", nargs=-1, required=True, metavar="DESIGN.toml | IMAGE...")
@click.option(
    "--out", "-o", "out", required=True, type=click.Path(file_okay=False), help="Job folder."
)
@click.option(
    "--board",
    type=SizePair(),
    metavar="WxH",
    default=None,
    show_default="100x100",
    help="Quick form: board size WxH in mm.",
)
@click.option(
    "--fit",
    type=click.Choice(["contain", "cover"]),
    default=None,
    show_default="the file's pipeline.fit, else contain",
    help="Fit images to the board: whole picture (contain) or fill the board (cover).",
)
@click.option(
    "--gamma",
    type=FiniteFloat(min=0, min_open=True),
    default=1.0,
    show_default=True,
    help="Exponent on linear values (1: unchanged).",
)
@click.option(
    "--contrast",
    type=FiniteFloat(min=0),
    default=1.0,
    show_default=True,
    help="Contrast about the mean (1: unchanged).",
)
@click.option(
    "--invert",
    is_flag=True,
    default=False,
    help="Invert every target (black becomes white) before fitting: bright = cut, so a "
    "dark-on-white image shows best inverted; a design file's view can say invert = true.",
)
@click.option(
    "--count",
    type=click.IntRange(min=1),
    default=None,
    show_default="the file's scratch.count; quick form: 0.5 per mm^2, at most 200000",
    help="Number of scratches.",
)
@click.option(
    "--resolution",
    type=SizePair(whole=True),
    default=None,
    show_default="the file's; quick form: 128 on the long side",
    help="Camera pixels per view: N (NxN) or WxH.",
)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=None,
    show_default="the file's pipeline.seed, else 0",
    help="Seed of the initial layout.",
)
@click.option(
    "--force",
    is_flag=True,
    default=None,
    help="Go on despite feasibility errors or a black target.",
)
@click.option(
    "--machine",
    "-m",
    default=None,
    show_default="the file's toolpath.machine, else grbl-3018-diamond",
    help=f"Machine whose time to cut the layout design tells (and warns where it cannot "
    f"reach the layout): bundled profile "
    f"({', '.join(bundled_names('machine_profiles'))}) or a profile TOML file.",
)
def design(
    inputs: tuple[str, ...],
    out: str,
    board: tuple[float, float] | None,
    fit: str | None,
    gamma: float,
    contrast: float,
    invert: bool,
    count: int | None,
    resolution: tuple[int, int] | None,
    seed: int | None,
    force: bool | None,
    machine: str | None,
) -> None:
    """Turn target images and a scene into a job's design folder.

    Give a design or pipeline file, or (quick form) one image per view:

        scratchfab design cat.png dog.png --board 100x100 --out JOB

    Writes JOB/design/: design.toml, targets/, board/, scratches.csv and the
    feasibility report; the quick form's design.toml can start the next run.
    """
    # Imported here, not for --help: the design stage loads scipy (~0.2 s).
    from scratchfab.design.quick import count_note, quick_design
    from scratchfab.design.stage import run_design
    from scratchfab.design.stand import stand_lines
    from scratchfab.machine.profile import load_profile
    from scratchfab.model.job import redesigned_note

    res = resolution
    # A typo in --machine is refused before the design's work, not told after it.
    profile = load_profile(machine) if machine is not None else None
    inputs = _bundled_pipeline(inputs)
    toml = [p for p in inputs if p.lower().endswith(".toml")]
    if toml:
        if len(inputs) != 1:
            raise ConfigError("give either one design/pipeline .toml file or image files, not both")
        if board is not None:
            raise ConfigError(
                "--board only applies to the quick form (images); set [board] in the file"
            )
        source: str | Design = inputs[0]
    else:
        board = board or (100.0, 100.0)
        source = quick_design([Path(p) for p in inputs], board, count, res)
        res = None
        note = count_note(board) if count is None else None
        if note:
            click.echo(note)
    try:
        result = run_design(
            source,
            out,
            force=force or None,
            fit=fit,
            gamma=gamma,
            contrast=contrast,
            count=count,
            resolution=res,
            seed=seed,
            progress=click.echo,
            invert=invert,
            machine=profile,
        )
    except ConfigError as exc:
        if isinstance(source, str):
            raise
        raise _as_typed(exc, source, inputs) from None
    for line in stand_lines(result.design):
        click.echo(line)
    click.echo(f"design file: {result.design_file}")
    note = redesigned_note(result.folder.parent)
    if note:
        click.echo(note)


def _bundled_pipeline(inputs: tuple[str, ...]) -> tuple[str, ...]:
    """A lone bundled pipeline's name (``demo``, as ``run demo`` takes it) as its file."""
    if len(inputs) != 1 or names_a_file(inputs[0]) or is_file(Path(inputs[0])):
        return inputs
    bundled = bundled_dir("pipelines") / f"{inputs[0]}.toml"
    return (str(bundled),) if is_file(bundled) else inputs


def _as_typed(exc: ConfigError, design: Design, images: Sequence[str]) -> ConfigError:
    """A quick-form error about one view, naming the image as typed instead of ``views[i]``.

    The user of the quick form wrote no design file, so ``quick form: views[0].target:
    /abs/sun.png: ...`` names a key they never saw; ``sun.png: ...`` names what they typed.
    """
    message = str(exc)
    for i, (view, typed) in enumerate(zip(design.views, images, strict=True)):
        key = f"{design.source}: views[{i}]"
        target = f"{key}.target ('{view.name}'): {design.target_path(view)}: "
        for prefix in (target, f"{key} ('{view.name}'): "):
            if message.startswith(prefix):
                return ConfigError(f"{typed}: {message[len(prefix) :]}")
    return exc
