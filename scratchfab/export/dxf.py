"""DXF (ezdxf): millimetres, layer BOARD with the outline, layer SCRATCHES with the strokes.

Every piece is a LINE entity in machine coordinates, scratches in cut order and
direction. The document passes ezdxf's audit before it is written. The same toolpath
gives the same bytes: the header's dates and GUIDs are ezdxf's fixed ones, not the
clock's and random ones, and the CLASS entries are in name order, not hash order.
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import ezdxf
from ezdxf import units

from scratchfab.errors import ScratchfabError
from scratchfab.fileio import write_bytes
from scratchfab.machine.profile import MachineProfile
from scratchfab.toolpath.plan import Toolpath

BOARD_LAYER = "BOARD"
SCRATCH_LAYER = "SCRATCHES"


@contextmanager
def _fixed_metadata() -> Iterator[None]:
    """Use ezdxf's fixed dates, GUIDs and version marker within the block."""
    before = ezdxf.options.write_fixed_meta_data_for_testing
    ezdxf.options.write_fixed_meta_data_for_testing = True
    try:
        yield
    finally:
        ezdxf.options.write_fixed_meta_data_for_testing = before


def _register_classes_sorted(doc: Any) -> None:
    """Register the document's CLASS entries now, sorted by name.

    ezdxf registers a class per entity type in use while writing, iterating a set, so the
    CLASSES section's order would follow ``PYTHONHASHSEED``; a class registered before
    keeps its place.
    """
    doc.classes.add_required_classes(doc.dxfversion)
    doc.classes.classes = dict(sorted(doc.classes.classes.items()))


def dxf_text(toolpath: Toolpath) -> str:
    """The DXF document (R2010, millimetres, machine coordinates) as text.

    Raises:
        ScratchfabError: The document fails ezdxf's audit.
    """
    with _fixed_metadata():
        doc = ezdxf.new("R2010", setup=False)
    doc.units = units.MM
    doc.header["$MEASUREMENT"] = 1
    doc.layers.add(BOARD_LAYER, color=8)
    doc.layers.add(SCRATCH_LAYER, color=7)
    msp = doc.modelspace()
    ring = toolpath.outline.tolist()
    for k in range(4):
        msp.add_line(ring[k], ring[(k + 1) % 4], dxfattribs={"layer": BOARD_LAYER})
    for (x0, y0), (x1, y1) in toolpath.strokes.tolist():
        msp.add_line((x0, y0), (x1, y1), dxfattribs={"layer": SCRATCH_LAYER})
    auditor = doc.audit()
    if auditor.has_errors:
        first = auditor.errors[0].message if auditor.errors else "unknown"
        raise ScratchfabError(f"DXF audit failed ({first}); nothing written")
    _register_classes_sorted(doc)
    buffer = io.StringIO()
    with _fixed_metadata():
        doc.write(buffer)
    return buffer.getvalue()


def write_dxf(
    toolpath: Toolpath, profile: MachineProfile | None, path: str | Path
) -> dict[str, Any]:
    """Write :func:`dxf_text` atomically; returns entity counts and the file size.

    ``profile`` is not used: the strokes already are in machine coordinates.
    """
    data = dxf_text(toolpath).encode("utf-8")
    write_bytes(path, data)
    return {
        "entities": {BOARD_LAYER: 4, SCRATCH_LAYER: len(toolpath)},
        "bytes": len(data),
        "units": "mm",
    }
