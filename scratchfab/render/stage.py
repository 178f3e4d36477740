"""The ``render`` stage: the analytic renderer on a design file and a scratch file."""

from __future__ import annotations

from pathlib import Path

from scratchfab.backend import BackendName
from scratchfab.console import Say
from scratchfab.model.design import load_design
from scratchfab.model.scratches import load_scratches
from scratchfab.render.layout import write_render_layout
from scratchfab.render.renderer import render_scratches


def run_render(
    design_file: Path,
    scratch_file: Path,
    out_dir: Path,
    backend: BackendName = "llvm",
    say: Say = lambda _: None,
) -> list[Path]:
    """Render every view of the board into ``out_dir`` (``<view>.npy`` and ``<view>.png``).

    Returns:
        The files written.

    Raises:
        ConfigError: Naming the file when the design or the scratches cannot be read.
    """
    design = load_design(design_file)
    scratches = load_scratches(scratch_file, design.scratch, design.board)
    say(f"rendering {len(scratches)} scratches, {len(design.views)} views ({backend})")
    images = render_scratches(design, scratches, backend, progress=lambda line: say(f"  {line}"))
    return write_render_layout(out_dir, images)
