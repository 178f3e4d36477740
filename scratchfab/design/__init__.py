"""The design stage: target images and a scene in, an initial scratch layout out.

- :mod:`.targets`: pictures on the board (:func:`~scratchfab.design.targets.fit_to_board`,
  :func:`~scratchfab.design.targets.board_image`) and as each camera sees them
  (:func:`~scratchfab.design.targets.warp_to_view`, :func:`~scratchfab.design.targets.view_targets`);
- :mod:`.images`: image files to linear luminance (:func:`~scratchfab.design.images.load_image`);
- :mod:`.layout`: the initial layout, :func:`~scratchfab.design.layout.initial_layout`;
- :mod:`.feasibility`: can the tool show each view and tell them apart;
- :mod:`.quick`: a scene for images without a design file;
- :mod:`.stage`: :func:`~scratchfab.design.stage.run_design`, all of it into ``JOB/design``.
"""
