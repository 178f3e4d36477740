"""``scratchfab run``: every stage of a pipeline file in order.

:mod:`.config` parses the stage tables (:func:`~scratchfab.pipeline.config.load_pipeline`),
:mod:`.runner` runs the stages (:func:`~scratchfab.pipeline.runner.run_pipeline`), skipping
those whose inputs did not change (:mod:`.manifest`), and :mod:`.report` writes the HTML
report.
"""
