"""SVG in millimetres: one user unit is 1 mm, groups ``board`` and ``scratches`` as layers.

The drawing is the machine's XY plane seen from above with +y up: a point (x, y) is
written at SVG (x, -y), and the ``viewBox`` spans the board's outline plus a margin of
:data:`MARGIN_MM`: readers that crop to the view box (vpype does) keep the lines on its
edge, and the outline's stroke is drawn whole. Groups carry Inkscape layer attributes so
that vpype and Inkscape read them as layers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from scratchfab.fileio import write_bytes
from scratchfab.machine.profile import MachineProfile
from scratchfab.toolpath.plan import Toolpath

LAYERS = ("board", "scratches")
MARGIN_MM = 1.0


def _num(v: float) -> str:
    text = f"{v:.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _line(a: list[float], b: list[float]) -> str:
    return f'<line x1="{_num(a[0])}" y1="{_num(-a[1])}" x2="{_num(b[0])}" y2="{_num(-b[1])}"/>'


def _layer(index: int, name: str, style: str, body: list[str]) -> list[str]:
    head = (
        f'<g id={quoteattr(name)} inkscape:groupmode="layer" '
        f"inkscape:label={quoteattr(f'{index} {name}')} {style}>"
    )
    return [head, *body, "</g>"]


def svg_text(toolpath: Toolpath, profile: MachineProfile | None = None) -> str:
    """The SVG document as text (machine mm, the module docstring's frame).

    Args:
        toolpath: The ordered strokes.
        profile: The machine (its name and tool width); default the toolpath's own.
    """
    prof = profile or toolpath.profile
    pts = np.vstack([toolpath.outline, toolpath.strokes.reshape(-1, 2)])
    lo, hi = pts.min(axis=0) - MARGIN_MM, pts.max(axis=0) + MARGIN_MM
    width, height = hi - lo
    ring = toolpath.outline.tolist()
    board = [_line(ring[k], ring[(k + 1) % 4]) for k in range(4)]
    cuts = [_line(a, b) for a, b in toolpath.strokes.tolist()]
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<svg xmlns="http://www.w3.org/2000/svg" '
        'xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" '
        f'width="{_num(width)}mm" height="{_num(height)}mm" '
        f'viewBox="{_num(lo[0])} {_num(-hi[1])} {_num(width)} {_num(height)}">',
        f"<title>scratchfab board for {_escape(prof.name)}</title>",
        *_layer(1, LAYERS[0], 'fill="none" stroke="#808080" stroke-width="0.2"', board),
        *_layer(
            2,
            LAYERS[1],
            f'fill="none" stroke="#000000" stroke-width="{_num(prof.tool.width_mm)}" '
            'stroke-linecap="round"',
            cuts,
        ),
        "</svg>",
    ]
    return "\n".join(lines) + "\n"


def write_svg(
    toolpath: Toolpath, profile: MachineProfile | None, path: str | Path
) -> dict[str, Any]:
    """Write :func:`svg_text` atomically; returns element counts and the file size."""
    data = svg_text(toolpath, profile).encode("utf-8")
    write_bytes(path, data)
    return {
        "elements": {"board": 4, "scratches": len(toolpath)},
        "bytes": len(data),
        "units": "mm",
    }


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
