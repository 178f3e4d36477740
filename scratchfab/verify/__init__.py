"""Verification by an independent renderer (Mitsuba 3) and the figures that compare.

- :mod:`.verify`: :class:`~scratchfab.verify.verify.BoardRenderer` (one board, any view,
  to an array) and :func:`~scratchfab.verify.verify.run_verify` (every view, metrics and
  difference maps into a folder);
- :mod:`.bsdf`, :mod:`.scene`, :mod:`.index`, :mod:`.dent`: the Mitsuba plugin and scene;
- :mod:`.diffmap`, :mod:`.sweep`, :mod:`.jitter`: difference maps, a walking viewer's GIF
  and machine tolerances applied to a layout.
"""
