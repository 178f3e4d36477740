"""The toolpath stage: scratches on the board -> ordered strokes on the machine."""

from __future__ import annotations

from scratchfab.toolpath.order import OrderOptions, OrderResult, order_strokes
from scratchfab.toolpath.plan import Toolpath, estimate_time, plan_toolpath, write_preview

__all__ = [
    "OrderOptions",
    "OrderResult",
    "Toolpath",
    "estimate_time",
    "order_strokes",
    "plan_toolpath",
    "write_preview",
]
