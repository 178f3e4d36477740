"""``scratchfab export``: write a toolpath as G-code, DXF or SVG."""

from __future__ import annotations

from pathlib import Path

import click

from scratchfab.errors import ScratchfabError
from scratchfab.export import FORMATS, WRITERS, format_for
from scratchfab.model.job import JobLayout


@click.command("export")
@click.argument("job", required=False, type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--format",
    "-f",
    "fmt",
    type=click.Choice(sorted(WRITERS)),
    show_default="from -o's extension",
    help=f"One of {', '.join(FORMATS)}; nc is G-code named .nc.",
)
@click.option(
    "--output",
    "-o",
    type=click.Path(dir_okay=False, path_type=Path),
    show_default="JOB/export/board.<format>",
    help="Output file.",
)
@click.option(
    "--toolpath",
    "toolpath_file",
    type=click.Path(dir_okay=False, path_type=Path),
    show_default="JOB/toolpath/toolpath.json",
    help="The toolpath.",
)
@click.option(
    "--machine",
    "-m",
    default=None,
    help=(
        "Check and write for this profile instead of the toolpath's own: other feeds, Z "
        "heights or tool control; the board placement and tool must be the toolpath's."
    ),
)
@click.option(
    "--force",
    is_flag=True,
    help=(
        "Export a toolpath planned from another layout, design or machine profile than "
        "there is now (warned)."
    ),
)
def export(
    job: Path | None,
    fmt: str | None,
    output: Path | None,
    toolpath_file: Path | None,
    machine: str | None,
    force: bool,
) -> None:
    """Write JOB/export/board.gcode, .dxf or .svg from JOB/toolpath/toolpath.json.

    Says the machine profile it writes for, and where the toolpath was planned from the
    design's initial layout (optimize had not run), that too. A toolpath planned from other inputs than
    there are now (optimize or design ran again, the scratch CSV or the machine profile
    was edited) is refused, naming what changed and the toolpath command to rerun;
    --force exports it as it was planned.
    G-code is checked before anything is written: every coordinate inside the machine's
    envelope, every line within its length limit.
    """
    # Imported here, not for --help: the toolpath package and the profiles.
    from scratchfab.export import export as export_toolpath
    from scratchfab.machine.profile import load_profile, machine_named
    from scratchfab.machine.sender_program import strip_block
    from scratchfab.toolpath import Toolpath
    from scratchfab.toolpath.inputs import initial_layout, planned_for
    from scratchfab.toolpath.plan import partial_text

    if toolpath_file is None:
        if job is None:
            raise ScratchfabError("give a JOB folder or --toolpath FILE")
        toolpath_file = JobLayout(job).toolpath_json
    if output is None:
        if fmt is None:
            raise ScratchfabError(f"give --format ({', '.join(FORMATS)}) or -o FILE")
        if job is None:
            raise ScratchfabError("give -o FILE (no JOB folder to write into)")
        output = JobLayout(job).export_file(fmt)
    name = format_for(output, fmt)
    tp = Toolpath.load(toolpath_file)
    profile = load_profile(machine) if machine else None
    stats = export_toolpath(tp, profile, output, name, "--force", force)
    if "lines" in stats:
        box = stats["bbox"]
        extent = ", ".join(f"{k[0].upper()} {v[0]:g}..{v[1]:g}" for k, v in box.items() if v)
        # the count stream gives: it sends no comment or blank line
        text = Path(output).read_text(encoding="utf-8").splitlines()
        sent = sum(1 for line in text if strip_block(line))
        detail = (
            f"{stats['lines']} lines ({sent} sent to the machine), {stats['bytes']} bytes, "
            f"longest line {stats['max_line_length']}; {extent}"
        )
    else:
        detail = f"{len(tp)} scratches, {stats['bytes']} bytes"
    target = planned_for(tp)
    if profile is not None:
        target = f"{machine_named(profile.name, machine)}, planned for {target}"
    if initial_layout(tp) is not None:
        target += ", from the design's initial layout (not optimized)"
    click.echo(f"wrote {output} for {target}: {detail}")
    for note in stats["notes"]:
        click.echo(f"note: {note}", err=True)
    if stats["stale"] is not None:
        click.echo(f"warning: exported as planned (--force): {stats['stale']}", err=True)
    lost = partial_text(tp.stats)
    if lost is not None:
        click.echo(
            f"warning: {toolpath_file} holds a partial board: {lost} (see its preview.png)",
            err=True,
        )
