"""Exporters: G-code (GRBL 1.1), DXF and SVG, chosen by file extension."""

from __future__ import annotations

from scratchfab.export.registry import FORMATS, WRITERS, export, format_for, writer

__all__ = ["FORMATS", "WRITERS", "export", "format_for", "writer"]
