"""The toolpath stage: scratches on the board -> ordered strokes on the machine."""

# Helpers under private names: ``dir(scratchfab.toolpath)`` lists no helper.
import typing as _typing

from scratchfab.toolpath.order import OrderOptions, OrderProgress, OrderResult, order_strokes

if _typing.TYPE_CHECKING:
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


if not _typing.TYPE_CHECKING:  # for mypy the names above: a misspelt one is an error, not Any

    def __getattr__(name: str) -> object:
        """The planning names, imported from :mod:`scratchfab.toolpath.plan` when asked for."""
        from importlib import import_module

        if name in _FROM_PLAN:
            return getattr(import_module("scratchfab.toolpath.plan"), name)
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
