"""The toolpath stage: scratches on the board -> ordered strokes on the machine."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from scratchfab.toolpath.order import OrderOptions, OrderProgress, OrderResult, order_strokes

if TYPE_CHECKING:
    from scratchfab.toolpath.plan import Toolpath, estimate_time, plan_toolpath, write_preview

# The planning names come from scratchfab.toolpath.plan (shapely, Pillow, the figures) on
# first use: the CLI's help needs only OrderOptions.
_FROM_PLAN = ("Toolpath", "estimate_time", "plan_toolpath", "write_preview")

__all__ = [
    "OrderOptions",
    "OrderProgress",
    "OrderResult",
    "Toolpath",
    "estimate_time",
    "order_strokes",
    "plan_toolpath",
    "write_preview",
]


def __getattr__(name: str) -> Any:
    """The planning names, imported from :mod:`scratchfab.toolpath.plan` when asked for."""
    if name in _FROM_PLAN:
        return getattr(importlib.import_module("scratchfab.toolpath.plan"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
