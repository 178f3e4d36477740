"""The optimize stage: multi-view Adam on a scratch layout (the supplement's section 3).

- :mod:`.optimizer`: :class:`~scratchfab.optimize.optimizer.LayoutOptimizer` (``step()``,
  ``scratches()``, ``evaluate()``) and its numerical
  :class:`~scratchfab.optimize.optimizer.Settings`;
- :mod:`.options`: :class:`~scratchfab.optimize.options.OptimizeOptions`, the
  ``[optimize]`` table (``learning_rates()`` gives ``Settings.lr`` in mm and rad);
- :mod:`.loss` and :mod:`.params`: the objective and the variables it moves;
- :mod:`.prune`: dropping scratches that add nothing;
- :mod:`.stage`: :func:`~scratchfab.optimize.stage.run_optimize` on a job folder.
"""
