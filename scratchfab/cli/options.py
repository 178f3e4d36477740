"""Click options shared by several commands."""

from __future__ import annotations

import click

#: ``--backend llvm|cuda`` of the commands that run Dr.Jit kernels.
backend_option = click.option(
    "--backend",
    type=click.Choice(["llvm", "cuda"]),
    default="llvm",
    show_default=True,
    help="Dr.Jit backend: llvm (CPU) or cuda (NVIDIA GPU).",
)
