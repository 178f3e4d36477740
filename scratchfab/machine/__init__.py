"""Machines: profiles, the G-code sender and a GRBL 1.1 emulator.

- :mod:`.profile`: :func:`~scratchfab.machine.profile.load_profile` (a bundled name or a
  TOML file) and the profile's dataclasses;
- :mod:`.stream_job`: :func:`~scratchfab.machine.stream_job.stream_file` (a G-code file
  to a port, with the journal that resume reads);
- :mod:`.sender`: :class:`~scratchfab.machine.sender.Streamer` and
  :func:`~scratchfab.machine.sender.open_port`;
- :mod:`.grblsim`: :class:`~scratchfab.machine.grblsim.GrblSim`, also opened as the
  pyserial URL ``grblsim://?key=value``.
"""
