"""scratchfab: scratch-based reflection art, from target images to an engraved board.

The core library works without the command line (``scratchfab.cli`` is a thin click
layer over it). Lengths are millimetres, images (H, W) numpy arrays of linear radiance.
Every name in ``__all__`` below is also importable from ``scratchfab`` itself
(``from scratchfab import plan_toolpath``), its module loaded on first use, so that
``import scratchfab`` stays light. A notebook's path from a design to a machine, in
memory where it can be:

- design: :func:`scratchfab.design.quick.quick_design` (a list of image files, one view
  each, as ``scratchfab design IMAGE...``),
  :func:`scratchfab.model.design.design_from_mapping` (a dict, as the TOML file's
  tables) or :func:`scratchfab.model.design.load_design` (a file); what the scratches
  can show is :func:`scratchfab.design.feasibility.check_feasibility` (``design`` on a job
  also refuses a black target and warns of a too bright one);
- targets: :func:`scratchfab.design.targets.view_targets` (every view of a design whose
  targets are files), or :func:`scratchfab.design.targets.fit_to_board` (an array) or
  :func:`scratchfab.design.targets.board_image` (a file), then
  :func:`scratchfab.design.targets.warp_to_view` for each view's camera pixels;
- initial layout: :func:`scratchfab.design.layout.initial_layout` -> a
  :class:`scratchfab.model.scratches.ScratchSet`;
- optimize: :class:`scratchfab.optimize.optimizer.LayoutOptimizer` (``step()``, then
  ``scratches()``), its Dr.Jit module from :func:`scratchfab.backend.array_module`; its
  settings :class:`scratchfab.optimize.optimizer.Settings`, made with
  ``Settings.of(OptimizeOptions(...))``
  (:class:`scratchfab.optimize.options.OptimizeOptions` holds the ``[optimize]`` table's
  keys); ``drjit.set_thread_count(1)`` first for bit-identical runs;
- render: :func:`scratchfab.render.renderer.render_scratches` -> ``{view: (H, W)}``;
- toolpath: :func:`scratchfab.machine.profile.load_profile` (a bundled name or a file)
  and :func:`scratchfab.toolpath.plan_toolpath` (tuned by
  :class:`scratchfab.toolpath.OrderOptions`; its ``progress`` callback gets the
  ordering's phases) -> a :class:`scratchfab.toolpath.Toolpath` (``Toolpath.load``
  reads a ``toolpath.json``);
- export: :func:`scratchfab.export.gcode.gcode_text`, :func:`scratchfab.export.svg.svg_text`,
  :func:`scratchfab.export.dxf.dxf_text` (text in memory) or
  :func:`scratchfab.export.export` (a file; not in ``__all__``, where the name is the
  subpackage ``scratchfab.export``);
- stream: :func:`scratchfab.machine.stream_job.stream_file` (a G-code file to a serial
  port, or ``grblsim://`` for the built-in GRBL emulator), asked with a
  :class:`scratchfab.machine.stream_job.StreamRequest` and answering through
  :class:`scratchfab.machine.stream_job.StreamCallbacks`.

A whole job as ``scratchfab run`` does it: :func:`scratchfab.pipeline.config.load_pipeline`
and :func:`scratchfab.pipeline.runner.run_pipeline` -> a
:class:`scratchfab.pipeline.runner.RunResult` (the stages that ran and skipped, each
view's verify rho, PSNR and pass/fail, and the toolpath's figures). The ``run_*``
functions of each stage's ``stage`` module do one stage on a job folder (SPEC section 6).
Mistakes in files, tables, settings and targets raise
:class:`scratchfab.errors.ScratchfabError` (one line naming the file and key or row);
the building blocks made in code raise ``ValueError``: the dataclasses (``Board``,
``Light``, ``ScratchTool``, ``View``, ``OptimizeOptions``, a profile's tables) for a
value outside a file's bounds, ``tone_map`` for an exposure that is not > 0, and
``ScratchSet``, ``fit_to_board``, ``warp_to_view``, ``order_strokes`` for arrays of the
wrong shape or range. Nothing in the core prints: progress goes to the callbacks a
caller passes.
"""

# Helpers under private names: ``dir(scratchfab)`` lists ``__all__`` and no helper.
import typing as _typing

if _typing.TYPE_CHECKING:
    from scratchfab.backend import array_module
    from scratchfab.design.feasibility import check_feasibility
    from scratchfab.design.layout import initial_layout
    from scratchfab.design.quick import quick_design
    from scratchfab.design.targets import board_image, fit_to_board, view_targets, warp_to_view
    from scratchfab.errors import ScratchfabError
    from scratchfab.export.dxf import dxf_text
    from scratchfab.export.gcode import gcode_text
    from scratchfab.export.svg import svg_text
    from scratchfab.machine.profile import load_profile
    from scratchfab.machine.stream_job import StreamCallbacks, StreamRequest, stream_file
    from scratchfab.model.design import design_from_mapping, load_design
    from scratchfab.model.scratches import ScratchSet
    from scratchfab.optimize.optimizer import LayoutOptimizer, Settings
    from scratchfab.optimize.options import OptimizeOptions
    from scratchfab.pipeline.config import load_pipeline
    from scratchfab.pipeline.runner import RunResult, run_pipeline
    from scratchfab.render.renderer import render_scratches
    from scratchfab.toolpath import OrderOptions, Toolpath, plan_toolpath

__version__ = "0.1.0"

__all__ = [
    "LayoutOptimizer",
    "OptimizeOptions",
    "OrderOptions",
    "RunResult",
    "ScratchSet",
    "ScratchfabError",
    "Settings",
    "StreamCallbacks",
    "StreamRequest",
    "Toolpath",
    "array_module",
    "board_image",
    "check_feasibility",
    "design_from_mapping",
    "dxf_text",
    "fit_to_board",
    "gcode_text",
    "initial_layout",
    "load_design",
    "load_pipeline",
    "load_profile",
    "plan_toolpath",
    "quick_design",
    "render_scratches",
    "run_pipeline",
    "stream_file",
    "svg_text",
    "view_targets",
    "warp_to_view",
]

#: Each name of ``__all__`` by the module it comes from (imported on first use: Dr.Jit,
#: Mitsuba and scipy load only for the names that need them).
_HOME = {
    name: module
    for module, names in {
        "scratchfab.backend": ("array_module",),
        "scratchfab.design.feasibility": ("check_feasibility",),
        "scratchfab.design.layout": ("initial_layout",),
        "scratchfab.design.quick": ("quick_design",),
        "scratchfab.design.targets": (
            "board_image",
            "fit_to_board",
            "view_targets",
            "warp_to_view",
        ),
        "scratchfab.errors": ("ScratchfabError",),
        "scratchfab.export.dxf": ("dxf_text",),
        "scratchfab.export.gcode": ("gcode_text",),
        "scratchfab.export.svg": ("svg_text",),
        "scratchfab.machine.profile": ("load_profile",),
        "scratchfab.machine.stream_job": ("StreamCallbacks", "StreamRequest", "stream_file"),
        "scratchfab.model.design": ("design_from_mapping", "load_design"),
        "scratchfab.model.scratches": ("ScratchSet",),
        "scratchfab.optimize.optimizer": ("LayoutOptimizer", "Settings"),
        "scratchfab.optimize.options": ("OptimizeOptions",),
        "scratchfab.pipeline.config": ("load_pipeline",),
        "scratchfab.pipeline.runner": ("RunResult", "run_pipeline"),
        "scratchfab.render.renderer": ("render_scratches",),
        "scratchfab.toolpath": ("OrderOptions", "Toolpath", "plan_toolpath"),
    }.items()
    for name in names
}


if not _typing.TYPE_CHECKING:  # for mypy the names above: a misspelt one is an error, not Any

    def __getattr__(name: str) -> object:
        """A name of ``__all__``, imported from its module when first asked for."""
        from importlib import import_module

        module = _HOME.get(name)
        if module is None:
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        value = getattr(import_module(module), name)
        globals()[name] = value  # asked once
        return value


def __dir__() -> list[str]:
    """The module's own names and ``__all__`` (a notebook's completion lists them)."""
    return sorted({*globals(), *__all__})
