"""scratchfab: scratch-based reflection art, from target images to an engraved board.

The core library works without the command line (``scratchfab.cli`` is a thin click
layer over it). Lengths are millimetres, images (H, W) numpy arrays of linear radiance.
A notebook's path from a design to a machine, in memory where it can be:

- design: :func:`scratchfab.design.quick.quick_design` (a list of image files, one view
  each, as ``scratchfab design IMAGE...``),
  :func:`scratchfab.model.design.design_from_mapping` (a dict, as the TOML file's
  tables) or :func:`~scratchfab.model.design.load_design` (a file); what the scratches
  can show is :func:`scratchfab.design.feasibility.check_feasibility` (``design`` on a job
  also refuses a black target and warns of a too bright one);
- targets: :func:`scratchfab.design.targets.view_targets` (every view of a design whose
  targets are files), or :func:`scratchfab.design.targets.fit_to_board` (an array) or
  :func:`~scratchfab.design.targets.board_image` (a file), then
  :func:`~scratchfab.design.targets.warp_to_view` for each view's camera pixels;
- initial layout: :func:`scratchfab.design.layout.initial_layout` -> a
  :class:`scratchfab.model.scratches.ScratchSet`;
- optimize: :class:`scratchfab.optimize.optimizer.LayoutOptimizer` (``step()``, then
  ``scratches()``), its Dr.Jit module from :func:`scratchfab.backend.array_module`; its
  ``Settings.of(OptimizeOptions(...))`` (:class:`~scratchfab.optimize.options.OptimizeOptions`
  holds the ``[optimize]`` table's keys); ``drjit.set_thread_count(1)``
  first for bit-identical runs;
- render: :func:`scratchfab.render.renderer.render_scratches` -> ``{view: (H, W)}``;
- toolpath: :func:`scratchfab.machine.profile.load_profile` (a bundled name or a file)
  and :func:`scratchfab.toolpath.plan_toolpath`;
- export: :func:`scratchfab.export.gcode.gcode_text`, :func:`scratchfab.export.svg.svg_text`,
  :func:`scratchfab.export.dxf.dxf_text` (text in memory) or
  :func:`scratchfab.export.export` (a file);
- stream: :func:`scratchfab.machine.stream_job.stream_file` (a G-code file to a serial
  port, or ``grblsim://`` for the built-in GRBL emulator).

The ``run_*`` functions of each stage's ``stage`` module do the same on a job folder
(SPEC section 6). Mistakes in files, tables, settings and targets raise
:class:`scratchfab.errors.ScratchfabError` (one line naming the file and key or row);
the building blocks made in code raise ``ValueError``: the dataclasses (``Board``,
``Light``, ``ScratchTool``, ``View``, ``OptimizeOptions``, a profile's tables) for a value
outside a file's bounds, ``tone_map`` for an exposure that is not > 0, and ``ScratchSet``,
``fit_to_board``, ``warp_to_view``, ``order_strokes`` for arrays of the wrong shape or range.
Nothing in the core prints: progress goes to the callbacks a caller passes.
"""

__version__ = "0.1.0"
