"""Exporters: G-code (GRBL 1.1), DXF and SVG, chosen by file extension.

:func:`export` writes a file atomically. As text in memory:
:func:`scratchfab.export.gcode.gcode_text` (or ``gcode_lines``),
:func:`scratchfab.export.svg.svg_text` and :func:`scratchfab.export.dxf.dxf_text`
(ezdxf is imported only with that module).
"""

from __future__ import annotations

from scratchfab.export.registry import FORMATS, WRITERS, export, format_for, writer

__all__ = ["FORMATS", "WRITERS", "export", "format_for", "writer"]
