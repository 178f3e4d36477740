"""The analytic renderer of SPEC section 4, in Dr.Jit (differentiable).

- :mod:`.renderer`: :func:`~scratchfab.render.renderer.render_scratches` (every view of a
  design to ``{name: float32 (H, W)}`` linear radiance) and
  :class:`~scratchfab.render.renderer.ViewRenderer` (one view, for the optimizer);
- :mod:`.ndf`: the closed-form footprint NDF of one scratch (supplement eqs. 1-9);
- :mod:`.profile`: the scratch's cross-section (eqs. 2 and 6);
- :mod:`.pairs`: which pixels each scratch can touch;
- :mod:`.tonemap` and :mod:`.layout`: the 8-bit previews and the ``<view>.npy``/``.png``
  files; :mod:`.stage`: :func:`~scratchfab.render.stage.run_render` on files.
"""
