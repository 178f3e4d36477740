"""The exporters, by file extension: the one place that lists them."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from scratchfab.errors import ScratchfabError

if TYPE_CHECKING:
    from scratchfab.machine.profile import MachineProfile
    from scratchfab.toolpath.plan import Toolpath

Writer = Callable[["Toolpath", "MachineProfile | None", "str | Path"], dict[str, Any]]

#: extension (no dot) -> (module, function) of its writer; "nc" is another name for
#: G-code. A writer's module is imported when it is used: ezdxf alone costs ~0.2 s.
WRITERS: dict[str, tuple[str, str]] = {
    "gcode": ("scratchfab.export.gcode", "write_gcode"),
    "nc": ("scratchfab.export.gcode", "write_gcode"),
    "dxf": ("scratchfab.export.dxf", "write_dxf"),
    "svg": ("scratchfab.export.svg", "write_svg"),
}

#: The formats ``scratchfab export --format`` offers.
FORMATS = ("gcode", "dxf", "svg")


def format_for(path: str | Path, format: str | None = None) -> str:
    """The format named, or the one the file's extension implies.

    Raises:
        ScratchfabError: Unknown format or extension, or a format named for a file whose
            extension belongs to another one (DXF written to ``board.gcode``, say).
    """
    extension = Path(path).suffix.lstrip(".").lower()
    name = (format or extension).lower()
    if name not in WRITERS:
        known = ", ".join(sorted(WRITERS))
        what = f"format '{format}'" if format else f"file extension of {path}"
        raise ScratchfabError(f"unknown {what}; known: {known}")
    if extension in WRITERS and WRITERS[extension] != WRITERS[name]:
        raise ScratchfabError(
            f"{path}: the extension says {extension} but the format asked for is {name}; "
            f"name the file .{name} or leave the format out"
        )
    return name


def writer(name: str) -> Writer:
    """The writer of format ``name`` (a key of :data:`WRITERS`), its module imported."""
    module, function = WRITERS[name]
    found: Writer = getattr(importlib.import_module(module), function)
    return found


def check_same_plan(toolpath: Toolpath, profile: MachineProfile) -> None:
    """Refuse a profile that would have planned other strokes than the toolpath holds.

    The strokes are already in the planning profile's machine coordinates: another board
    placement puts the board elsewhere on the bed, another tool cuts other scratches.
    Feeds, Z heights, tool control, start and G-code settings may differ: they are
    what exporting for another profile is for.

    Raises:
        ScratchfabError: Naming what differs and the command that plans for the profile.
    """
    from scratchfab.machine.profile import machine_named
    from scratchfab.toolpath.inputs import profile_changes

    planned = toolpath.profile
    differ = profile_changes(planned, profile, ("board", "tool"))
    if differ:
        raise ScratchfabError(
            f"{machine_named(profile.name, profile.source)} places or cuts the board otherwise "
            f"than the toolpath was planned for ('{planned.name}'): {'; '.join(differ)}; "
            "rerun `scratchfab toolpath JOB --machine` with this profile, then export; "
            "nothing written"
        )


def export(
    toolpath: Toolpath,
    profile: MachineProfile | None,
    path: str | Path,
    format: str | None = None,
    refuse_stale: str | None = None,
    force: bool = False,
) -> dict[str, Any]:
    """Write ``toolpath`` to ``path`` in ``format`` (default: from the extension).

    Args:
        toolpath: The ordered strokes.
        profile: The machine (default: the toolpath's own profile); it must place the
            board and cut with the tool as the toolpath's own does.
        path: The output file (written atomically; nothing is written on error).
        format: ``gcode``, ``nc``, ``dxf`` or ``svg``.
        refuse_stale: The override (``--force``) that exports a toolpath planned from
            other inputs than there are now
            (:func:`~scratchfab.toolpath.inputs.check_current`), named when such a
            toolpath is refused; None: not checked (the runner's manifest sees to it).
        force: The override was given: a stale toolpath is written, and ``stale`` says
            what changed.

    Returns:
        Figures for the report (G-code: lines, bytes, max_line_length, bbox); ``stale``:
        what changed since the toolpath was planned, or None; ``notes``: what could not
        be checked.

    Raises:
        ScratchfabError: An unknown format or extension, a path that holds a NUL byte,
            a profile that would have planned other strokes (:func:`check_same_plan`),
            a stale toolpath under ``refuse_stale``, or what the writer refuses (G-code:
            a stroke outside the envelope, a line too long).
    """
    from scratchfab.toolpath.inputs import check_current

    name = format_for(path, format)
    if profile is not None:
        check_same_plan(toolpath, profile)
    stale, notes = check_current(toolpath, profile) if refuse_stale else (None, [])
    if stale is not None and not force:
        raise ScratchfabError(
            f"{stale} (or give {refuse_stale} to export it as it was planned); nothing written"
        )
    stats = writer(name)(toolpath, profile, path)
    return {"format": name, "path": str(path), **stats, "stale": stale, "notes": notes}
