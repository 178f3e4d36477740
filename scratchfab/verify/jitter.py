"""Machine tolerances applied to a layout: where would the real cut differ from the plan?"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scratchfab.model.scratches import ScratchSet

if TYPE_CHECKING:
    from scratchfab.machine.profile import MachineProfile


@dataclass(frozen=True)
class Tolerance:
    """One-sigma errors of the cut, applied independently per scratch.

    Attributes:
        position_mm: Shift of a scratch (both ends together) along x and y.
        angle_deg: Rotation of a scratch about its midpoint.
        depth_fraction: Relative error of the cut depth.
        source: Where the values came from (for the report).
    """

    position_mm: float = 0.01
    angle_deg: float = 0.1
    depth_fraction: float = 0.1
    source: str = "defaults"

    @classmethod
    def from_profile(cls, ref: str, profile: MachineProfile | None = None) -> Tolerance:
        """Position tolerance from a machine profile's ``[tool] tolerance_mm``.

        Profiles carry no angle or depth tolerance, so those keep their defaults.

        Args:
            ref: The profile as the user named it (a bundled name or a path); recorded
                as ``source``.
            profile: The same profile, already loaded (else ``ref`` is loaded).

        Raises:
            ConfigError: When the profile cannot be loaded.
        """
        if profile is None:
            from scratchfab.machine.profile import load_profile

            profile = load_profile(ref)
        return cls(position_mm=float(profile.tool.tolerance_mm), source=ref)

    def as_dict(self) -> dict[str, float | str]:
        """JSON-ready fields."""
        return {
            "position_mm": self.position_mm,
            "angle_deg": self.angle_deg,
            "depth_fraction": self.depth_fraction,
            "source": self.source,
        }


def jitter_scratches(
    scratches: ScratchSet,
    tolerance: Tolerance,
    rng: np.random.Generator,
    extent: tuple[float, float] | None = None,
) -> ScratchSet:
    """A perturbed copy: each scratch shifted, turned about its midpoint and cut deeper or shallower.

    Args:
        scratches: The planned layout.
        tolerance: One-sigma errors (normal distributions; depth factors kept >= 0.1).
        rng: The seeded generator.
        extent: Board half width and half height; endpoints are clipped onto the board.
    """
    n = len(scratches)
    mid = 0.5 * (scratches.p0 + scratches.p1)
    half = 0.5 * (scratches.p1 - scratches.p0)
    shift = rng.normal(0.0, tolerance.position_mm, (n, 2))
    turn = rng.normal(0.0, math.radians(tolerance.angle_deg), n)
    c, s = np.cos(turn), np.sin(turn)
    rotated = np.stack([c * half[:, 0] - s * half[:, 1], s * half[:, 0] + c * half[:, 1]], axis=1)
    p0 = mid + shift - rotated
    p1 = mid + shift + rotated
    if extent is not None:
        limit = np.asarray(extent)
        p0 = np.clip(p0, -limit, limit)
        p1 = np.clip(p1, -limit, limit)
    factor = np.maximum(1.0 + rng.normal(0.0, tolerance.depth_fraction, n), 0.1)
    return ScratchSet(p0, p1, scratches.width.copy(), scratches.depth * factor)
