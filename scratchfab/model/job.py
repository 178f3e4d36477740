"""The job folder's layout (SPEC section 6): where each stage finds its inputs."""

from __future__ import annotations

from pathlib import Path

from scratchfab.errors import ConfigError


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
