"""The data model: designs, scratch layouts, cameras and the job folder, in millimetres.

- :mod:`.design`: :class:`~scratchfab.model.design.Design` (board, light, tool, views),
  :func:`~scratchfab.model.design.load_design` and
  :func:`~scratchfab.model.design.design_from_mapping` (SPEC sections 2 and 5);
- :mod:`.scratches`: :class:`~scratchfab.model.scratches.ScratchSet` ((N, 2) end points)
  and the CSV file, :func:`~scratchfab.model.scratches.load_scratches`;
- :mod:`.camera`: pinhole cameras and pixel footprints on the board (SPEC section 2);
- :mod:`.job`: where each stage reads and writes in a job folder (SPEC section 6);
- :mod:`.schema`: strict TOML tables into frozen dataclasses.

A file's mistakes raise :class:`~scratchfab.errors.ConfigError` naming the file and key;
a ``Board``, ``Light``, ``ScratchTool``, ``View`` or ``ScratchSet`` built in code with a
value out of the same bounds, or arrays of the wrong shape, raises ``ValueError``.
"""
