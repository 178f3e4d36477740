"""The optimization variables of a scratch layout and the constraints on them.

Each scratch is held as its centre (cx, cy), its angle theta (radians, from +x toward
+y) and its length L, not as its two endpoints. Why:

- What a view sees of a scratch depends mostly on its *direction*: the profile's
  normals only reach the half-vectors whose horizontal part lies across the scratch
  (SPEC section 3). With endpoints, turning a scratch takes a coordinated move of four
  coordinates that Adam's per-coordinate scaling distorts; with an angle it is one
  variable with its own step size.
- The length bounds ``[min_length_mm, max_length_mm]`` become a clamp of one variable,
  and keeping the scratch on the board a clamp of the centre into a box that shrinks
  with the scratch's half extent; both are cheap masks (no branches).

The raw variables that Adam moves may leave the feasible set; the scratch that is
rendered is always their projection :func:`project` (idempotent), and a small quadratic
penalty on the distance to the projection pulls stray raw values back, because the clamp
passes no gradient outside. Every output is the projected layout.

Bound on the motion (used to re-find pixel pairs only every K steps, see
:func:`pair_margin`): :class:`BoundedAdam` clips every coordinate's step to its learning
rate, so per step |d cx|, |d cy| <= lr_c, |d L| <= lr_L and |d theta| <= lr_theta. The
length clamp is non-expansive; the centre clamp moves by at most the change of the box,
which is at most the change of the half extent (L/2)(cos, sin). Hence each endpoint
c +- (L/2) u(theta) moves per step by at most

    sqrt(2) lr_c + 2 (lr_L / 2 + (L_max / 2) lr_theta) = sqrt(2) lr_c + lr_L + L_max lr_theta.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import drjit as dr
import drjit.opt
import numpy as np

from scratchfab.backend import jit_array
from scratchfab.model.design import Design
from scratchfab.model.scratches import ScratchSet

KEYS = ("cx", "cy", "theta", "length")


@dataclass(frozen=True)
class Bounds:
    """The feasible set of one scratch.

    Attributes:
        half_x: Endpoints keep |x| <= half_x (board half width minus margin), mm.
        half_y: Endpoints keep |y| <= half_y, mm.
        min_length: Shortest allowed scratch, mm.
        max_length: Longest allowed scratch, mm.
    """

    half_x: float
    half_y: float
    min_length: float
    max_length: float

    @classmethod
    def from_design(cls, design: Design) -> Bounds:
        """The bounds that ``design`` asks for."""
        hw, hh = design.board.half_extent
        m = design.board.margin_mm
        max_len = min(design.scratch.max_length_mm, 2 * min(hw - m, hh - m))
        return cls(hw - m, hh - m, min(design.scratch.min_length_mm, max_len), max_len)


def from_scratches(scratches: ScratchSet) -> dict[str, np.ndarray]:
    """Centre, angle and length (float64) of a scratch set."""
    d = scratches.p1 - scratches.p0
    c = 0.5 * (scratches.p0 + scratches.p1)
    return {
        "cx": c[:, 0].copy(),
        "cy": c[:, 1].copy(),
        "theta": np.arctan2(d[:, 1], d[:, 0]),
        "length": np.linalg.norm(d, axis=1),
    }


def project(cx: Any, cy: Any, theta: Any, length: Any, bounds: Bounds) -> tuple[Any, ...]:
    """Projection onto the feasible set (Dr.Jit arrays): (cx, cy, theta, length).

    The length is clamped to its bounds, then the centre to the box in which both
    endpoints stay within the board's margin. Idempotent, and 1-Lipschitz in each raw
    variable (see the module docstring).
    """
    length = dr.clip(length, bounds.min_length, bounds.max_length)
    s, c = dr.sincos(theta)
    ex = dr.abs(c) * length * 0.5
    ey = dr.abs(s) * length * 0.5
    lim_x = dr.maximum(bounds.half_x - ex, 0.0)
    lim_y = dr.maximum(bounds.half_y - ey, 0.0)
    return dr.clip(cx, -lim_x, lim_x), dr.clip(cy, -lim_y, lim_y), theta, length


def endpoints(cx: Any, cy: Any, theta: Any, length: Any) -> tuple[Any, Any, Any, Any]:
    """(p0x, p0y, p1x, p1y) of scratches given by centre, angle and length (Dr.Jit)."""
    s, c = dr.sincos(theta)
    hx = c * length * 0.5
    hy = s * length * 0.5
    return cx - hx, cy - hy, cx + hx, cy + hy


def project_np(params: dict[str, np.ndarray], bounds: Bounds) -> dict[str, np.ndarray]:
    """:func:`project` on numpy float64 arrays (for layouts read from files)."""
    length = np.clip(params["length"], bounds.min_length, bounds.max_length)
    ex = np.abs(np.cos(params["theta"])) * length * 0.5
    ey = np.abs(np.sin(params["theta"])) * length * 0.5
    lim_x = np.maximum(bounds.half_x - ex, 0.0)
    lim_y = np.maximum(bounds.half_y - ey, 0.0)
    return {
        "cx": np.clip(params["cx"], -lim_x, lim_x),
        "cy": np.clip(params["cy"], -lim_y, lim_y),
        "theta": params["theta"].copy(),
        "length": length,
    }


def to_arrays(Float: type, params: dict[str, np.ndarray]) -> dict[str, Any]:
    """Numpy parameters as Dr.Jit arrays of type ``Float``."""
    return {k: jit_array(Float, params[k]) for k in KEYS}


def max_step_mm(lr: dict[str, float], max_length: float) -> float:
    """Largest distance any endpoint can move in one clipped Adam step (module docstring)."""
    return math.sqrt(2.0) * max(lr["cx"], lr["cy"]) + lr["length"] + max_length * lr["theta"]


def pair_margin(lr: dict[str, float], max_length: float, steps: int, half_width: float) -> float:
    """Margin for pairs that must stay complete while scratches move for ``steps`` steps.

    Every point of a moved scratch rectangle lies within D + w of the old segment, where
    D bounds the endpoint motion (a point (1 - s) p0' + s p1' is within D of
    (1 - s) p0 + s p1, and the rectangle adds at most w across). The old rectangle grown
    by D + w on every side contains all such points. That holds in exact arithmetic; a
    relative 1e-4 and 1e-4 mm of slack absorb the float64 rounding of the computed steps,
    endpoints (Dr.Jit's sin and cos) and rectangle corners.
    """
    reach = steps * max_step_mm(lr, max_length) + half_width
    return reach * (1 + 1e-4) + 1e-4


class BoundedAdam(drjit.opt.Adam):  # type: ignore[misc]
    """Dr.Jit's Adam with every coordinate's step clipped to its learning rate.

    Kingma and Ba's rule of thumb |step| <= lr is not a bound: for the default betas a
    burst of gradient after a quiet spell gives up to about 7.3 lr. Clipping makes it one,
    which is what the pair margin relies on; in steady state the clip is rarely active.

    ``scale`` (a step-size schedule's multiple for the coming step) multiplies the clipped
    step: a Dr.Jit Float64 of width 1, opaque so that a frozen step replays it with each
    step's value, or None for 1. A coordinate then moves by at most ``scale`` times its
    learning rate.
    """

    scale: Any = None

    def _step(self, cache: Any, value: Any, grad: Any, lr: Any, extra: Any, /) -> Any:
        new_value, new_extra = super()._step(cache, value, grad, lr, extra)
        step = dr.clip(new_value - value, -lr, lr)
        if self.scale is not None:
            step = step * self.scale
        return value + step, new_extra
