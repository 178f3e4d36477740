"""The ``scratchfab`` command line: a thin click layer over the core library.

Subcommands live in their own modules and are imported only when used, so ``--help``
stays fast and a missing optional dependency affects only its own command.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from typing import Any

import click

from scratchfab import __version__
from scratchfab.errors import Interrupted, ScratchfabError

#: name -> (module, attribute, one-line help), in pipeline order.
COMMANDS: dict[str, tuple[str, str, str]] = {
    "design": ("scratchfab.cli.design_cmd", "design", "Turn target images and a scene into a job."),
    "optimize": (
        "scratchfab.cli.optimize_cmd",
        "optimize",
        "Optimize the scratch layout of a job.",
    ),
    "render": ("scratchfab.cli.render_cmd", "render", "Render a board with the analytic renderer."),
    "verify-render": (
        "scratchfab.cli.verify_cmd",
        "verify_render",
        "Verify a board with the independent Mitsuba 3 renderer.",
    ),
    "toolpath": ("scratchfab.cli.toolpath_cmd", "toolpath", "Order the strokes for a machine."),
    "export": ("scratchfab.cli.export_cmd", "export", "Write G-code, DXF or SVG."),
    "stream": ("scratchfab.cli.stream_cmd", "stream", "Stream G-code to a GRBL controller."),
    "grbl-sim": ("scratchfab.cli.stream_cmd", "grbl_sim", "Run the built-in GRBL 1.1 emulator."),
    "run": ("scratchfab.cli.run_cmd", "run", "Run a whole pipeline into a job folder."),
}


class LazyGroup(click.Group):
    """A click group that imports each subcommand's module on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        """Commands whose module is present, in pipeline order."""
        return [
            name for name in COMMANDS if importlib.util.find_spec(COMMANDS[name][0]) is not None
        ]

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        """Import and return the named command."""
        if cmd_name not in COMMANDS:
            return None
        module_name, attr, _ = COMMANDS[cmd_name]
        if importlib.util.find_spec(module_name) is None:
            return None
        command: click.Command = getattr(importlib.import_module(module_name), attr)
        return command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """List the commands with their one-line help without importing them."""
        rows = [(name, COMMANDS[name][2]) for name in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


@click.group(cls=LazyGroup)
@click.version_option(__version__, prog_name="scratchfab")
def cli() -> None:
    """Scratch-based reflection art: design -> optimize -> verify-render -> toolpath -> export -> stream."""


def main(argv: list[str] | None = None) -> Any:
    """Entry point: run the CLI, turning user errors into one line and a non-zero exit."""
    for stream in (sys.stdout, sys.stderr):
        # A path the console's code page cannot show (Windows' cp1252, a redirect) is
        # escaped, not a traceback.
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            reconfigure(errors="backslashreplace")
    try:
        return cli.main(args=argv, prog_name="scratchfab", standalone_mode=False)
    except Interrupted as exc:
        click.echo(str(exc), err=True)
        sys.exit(exc.exit_code)
    except ScratchfabError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
