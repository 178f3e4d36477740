"""The job folder's layout (SPEC section 6): where each stage finds its inputs."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from scratchfab.errors import ConfigError
from scratchfab.fileio import file_sha256
from scratchfab.model.design import Design, load_design


def job_inputs(job: str | Path) -> tuple[Path, Path]:
    """The design and scratch files a stage working on a job uses.

    The design is ``JOB/design/design.toml``; the scratches are the optimized layout
    ``JOB/optimize/scratches.csv`` when present, else the initial ``JOB/design/scratches.csv``.

    Raises:
        ConfigError: Naming the missing file.
    """
    folder = Path(job)
    if not folder.is_dir():
        raise ConfigError(f"{folder}: job folder not found")
    design = folder / "design" / "design.toml"
    if not design.is_file():
        raise ConfigError(f"{design}: file not found (is {folder} a job folder?)")
    for scratches in (folder / "optimize" / "scratches.csv", folder / "design" / "scratches.csv"):
        if scratches.is_file():
            return design, scratches
    raise ConfigError(
        f"{folder}: no scratch layout (expected optimize/scratches.csv or design/scratches.csv)"
    )


#: The design stage's files an optimized layout is made from (recorded by optimize).
DESIGN_FILES = ("design.toml", "scratches.csv")


def design_digest(job: str | Path) -> dict[str, str]:
    """SHA-256 of each of the job's :data:`DESIGN_FILES`, by name."""
    return {name: file_sha256(Path(job) / "design" / name) for name in DESIGN_FILES}


def stale_layout_warning(job: str | Path) -> str | None:
    """A warning when ``JOB/optimize/scratches.csv`` was made from another design.

    Optimize records :func:`design_digest` in ``optimize/summary.json``; rerunning
    design afterwards (README step 1's edit loop) leaves an optimized layout of the old
    design behind, which toolpath, verify and render would otherwise use without a word.
    None when the layout is current, or when there is no record to tell by.
    """
    folder = Path(job)
    if not (folder / "optimize" / "scratches.csv").is_file():
        return None
    try:
        summary = json.loads((folder / "optimize" / "summary.json").read_text(encoding="utf-8"))
        recorded = summary["design_sha256"]
    except (OSError, ValueError, TypeError, KeyError):
        return None
    if not isinstance(recorded, dict):
        return None
    changed = [f"design/{k}" for k, v in design_digest(folder).items() if recorded.get(k) != v]
    if not changed:
        return None
    return (
        f"warning: {folder / 'optimize' / 'scratches.csv'} was optimized from an earlier "
        f"design ({', '.join(changed)} changed since): it is used as it is; rerun "
        f"`scratchfab optimize {folder}` for the current design"
    )


def load_job_design(design_file: str | Path) -> Design:
    """A job's ``design/design.toml``, each view's target read from the job's own copy.

    The design stage writes every view's board picture to ``design/board/<view>.png``
    and records its absolute path (SPEC section 6). A job that was moved or copied since
    would read the pictures at the old place, or none; this reads the ones beside the file.

    Raises:
        ConfigError: Naming the file and the key on any mistake.
    """
    file = Path(design_file)
    design = load_design(file)
    views = []
    for view in design.views:
        own = (file.parent / "board" / f"{view.name}.png").resolve()
        views.append(replace(view, target=str(own)) if own.is_file() else view)
    return design.with_views(tuple(views))
