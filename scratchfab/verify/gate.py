"""The verify gate's one rule: which ``min_rho`` stops a board.

A module of its own, without Dr.Jit, so that the report and the pipeline's result read
the gate as :func:`~scratchfab.verify.verify.run_verify` applies it.
"""

from __future__ import annotations

from typing import TypeGuard


def gate_applies(min_rho: float | None) -> TypeGuard[float]:
    """Whether ``min_rho`` gates the views: not None (no gate) nor -1 (every rho reaches it).

    A view's rho lies in [-1, 1], so ``min_rho = -1`` passes every view: it is the way to
    say "never stop" (a view whose rho cannot be measured included), and no view "passes"
    it any more than without a gate.
    """
    return min_rho is not None and min_rho > -1.0
