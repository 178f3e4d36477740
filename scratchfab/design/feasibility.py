"""Can the tool's profile show each view, and can it tell the views apart?

A scratch lights view k at board point p when one of its profile normals equals the
half-vector h_k(p) within the GGX lobe (SPEC section 4). The profile's normals lie in
the plane spanned by the scratch's across-direction and z, tilted at most by the
steepest wall 2 atan(2w / wbar) (SPEC section 3). Hence:

- view k is reachable at p when tilt(h_k) = atan(|h_xy| / h_z) <= steepest wall + lobe;
- a scratch turned to light view k at p (across-direction along h_k's horizontal
  part) carries the arc of normals {cos(t) z + sin(t) a_k : |t| <= steepest}; it also
  lights view j by the angle between h_j and that arc compared with the lobe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any

import numpy as np
from PIL import Image

from scratchfab.errors import ConfigError
from scratchfab.model.design import Board, Design, View
from scratchfab.render.profile import steepest_wall_deg

#: A view must be able to light at least this share of the board.
MIN_REACHABLE_FRACTION = 0.5
#: Pairs closer than this many lobe widths (median over the board) get a warning.
WARN_SEPARATION_LOBES = 3.0


def lobe_deg(roughness: float) -> float:
    """Angular width of the GGX lobe, atan(alpha): where D falls to about a quarter of its peak."""
    return math.degrees(math.atan(roughness))


def ggx_ratio(angle_deg: np.ndarray, roughness: float) -> np.ndarray:
    """D(cos angle) / D(1) for GGX (SPEC section 4): the relative response off the lobe's peak."""
    c = np.cos(np.radians(angle_deg))
    a2 = roughness * roughness
    return a2 * a2 / (1.0 + (a2 - 1.0) * c * c) ** 2


def board_points(board: Board, long_side: int = 96) -> np.ndarray:
    """Centres of a board grid (rows, cols, 2); row 0 along the top edge (+y)."""
    if board.width_mm >= board.height_mm:
        cols = long_side
        rows = max(1, round(long_side * board.height_mm / board.width_mm))
    else:
        rows = long_side
        cols = max(1, round(long_side * board.width_mm / board.height_mm))
    hw, hh = board.half_extent
    x = -hw + (np.arange(cols) + 0.5) * board.width_mm / cols
    y = hh - (np.arange(rows) + 0.5) * board.height_mm / rows
    xx, yy = np.meshgrid(x, y)
    return np.stack([xx, yy], axis=-1)


def half_vectors(design: Design, view: View, points: np.ndarray) -> np.ndarray:
    """Unit half-vectors h(p) = normalize(wi + wo) at board points (..., 2) -> (..., 3)."""
    p = np.concatenate([points, np.zeros(points.shape[:-1] + (1,))], axis=-1)
    wi = design.light_for(view) - p
    wo = view.camera_position - p
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    h = wi + wo
    return h / np.linalg.norm(h, axis=-1, keepdims=True)


def tilt_deg(h: np.ndarray) -> np.ndarray:
    """Angle of h from the board normal, degrees."""
    return np.degrees(np.arctan2(np.hypot(h[..., 0], h[..., 1]), h[..., 2]))


def across_directions(h: np.ndarray) -> np.ndarray:
    """Unit across-direction (..., 2) that tilts the profile toward h (x-axis where h is vertical)."""
    hxy = h[..., :2]
    norm = np.linalg.norm(hxy, axis=-1, keepdims=True)
    fallback = np.zeros_like(hxy)
    fallback[..., 0] = 1.0
    return np.where(norm > 1e-12, hxy / np.maximum(norm, 1e-300), fallback)


def arc_distance_deg(h: np.ndarray, across: np.ndarray, max_tilt_deg: float) -> np.ndarray:
    """Angle between unit vectors h (..., 3) and the arc of profile normals of a scratch.

    The arc is {cos(t) z + sin(t) a : |t| <= max_tilt} with a = (across, 0).
    """
    a = np.concatenate([across, np.zeros(across.shape[:-1] + (1,))], axis=-1)
    ha = np.sum(h * a, axis=-1)
    hz = h[..., 2]
    along = 1.0 - ha * ha - hz * hz  # squared component along the scratch
    in_plane = np.arctan2(ha, hz)
    tmax = math.radians(max_tilt_deg)
    inside = np.abs(in_plane) <= tmax
    off_plane = np.arcsin(np.sqrt(np.clip(along, 0.0, 1.0)))
    t_end = np.sign(in_plane) * tmax
    cos_end = np.clip(np.cos(t_end) * hz + np.sin(t_end) * ha, -1.0, 1.0)
    return np.degrees(np.where(inside, off_plane, np.arccos(cos_end)))


@dataclass
class ViewFeasibility:
    """Per-view result: tilt of the half-vector against what the profile reaches."""

    name: str
    tilt_min_deg: float
    tilt_median_deg: float
    tilt_max_deg: float
    reachable_fraction: float
    tilt_map: np.ndarray = field(repr=False)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready summary (the map is written as a PNG)."""
        return {
            "tilt_min_deg": round(self.tilt_min_deg, 4),
            "tilt_median_deg": round(self.tilt_median_deg, 4),
            "tilt_max_deg": round(self.tilt_max_deg, 4),
            "reachable_fraction": round(self.reachable_fraction, 6),
        }


@dataclass
class PairFeasibility:
    """How a scratch turned for view ``lit`` affects view ``other``."""

    lit: str
    other: str
    separation_min_deg: float
    separation_median_deg: float
    expected_crosstalk: float
    crosstalk_map: np.ndarray = field(repr=False)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "scratch_for": self.lit,
            "seen_by": self.other,
            "separation_min_deg": round(self.separation_min_deg, 4),
            "separation_median_deg": round(self.separation_median_deg, 4),
            "expected_crosstalk": round(self.expected_crosstalk, 6),
        }


@dataclass
class FeasibilityReport:
    """Everything the check found; ``errors`` stop ``design`` unless forced."""

    steepest_wall_deg: float
    lobe_deg: float
    views: dict[str, ViewFeasibility]
    pairs: list[PairFeasibility]
    errors: list[str]
    warnings: list[str]

    @property
    def ok(self) -> bool:
        """True when there is no error."""
        return not self.errors

    def to_json(self) -> dict[str, Any]:
        """The report as JSON-ready data (``feasibility.json``)."""
        return {
            "steepest_wall_deg": round(self.steepest_wall_deg, 4),
            "lobe_deg": round(self.lobe_deg, 4),
            "reach_limit_deg": round(self.steepest_wall_deg + self.lobe_deg, 4),
            "views": {name: v.to_json() for name, v in self.views.items()},
            "pairs": [p.to_json() for p in self.pairs],
            "errors": list(self.errors),
            "warnings": list(self.warnings),
            "maps": (
                "feasibility_<view>.png: board seen from the front (top = +y); green: the "
                "profile reaches the half-vector, yellow: only through the roughness lobe, "
                "red: unreachable; magenta tint: expected crosstalk with another view"
            ),
        }

    def summary_lines(self, errors: bool = True) -> list[str]:
        """Short human-readable lines for the terminal.

        Args:
            errors: False leaves the errors out, for a caller that raises them with
                :meth:`raise_if_errors`.
        """
        lines = [
            f"tool reaches half-vectors tilted up to {self.steepest_wall_deg:.1f} deg "
            f"(+{self.lobe_deg:.1f} deg roughness lobe)"
        ]
        for name, v in self.views.items():
            lines.append(
                f"view '{name}': half-vector tilt {v.tilt_min_deg:.1f}-{v.tilt_max_deg:.1f} deg, "
                f"{100 * v.reachable_fraction:.0f}% of the board reachable"
            )
        for p in self.pairs:
            lines.append(
                f"scratches for '{p.lit}' seen by '{p.other}': {p.separation_median_deg:.1f} deg "
                f"off their normals (median), expected crosstalk {p.expected_crosstalk:.3f}"
            )
        lines += [f"warning: {w}" for w in self.warnings]
        lines += [f"error: {e}" for e in self.errors] if errors else []
        return lines

    def raise_if_errors(self, source: str) -> None:
        """Raise one ConfigError naming the source and every problem (with the --force hint)."""
        if self.errors:
            raise ConfigError(
                f"{source}: " + "; ".join(self.errors) + " (use --force to design anyway)"
            )

    def map_image(self, name: str) -> Image.Image:
        """The feasibility map of one view as an RGB image (board seen from the front)."""
        v = self.views[name]
        reach = self.steepest_wall_deg
        limit = reach + self.lobe_deg
        rgb = np.empty(v.tilt_map.shape + (3,))
        shade = 0.45 + 0.55 * (1.0 - np.clip(v.tilt_map / max(limit, 1e-9), 0.0, 1.0))
        rgb[...] = (0.85, 0.1, 0.1)
        rgb[v.tilt_map <= limit] = (0.95, 0.8, 0.1)
        ok = v.tilt_map <= reach
        rgb[ok] = np.array([0.1, 0.75, 0.2])
        rgb[ok] *= shade[ok][:, None]
        cross = np.zeros(v.tilt_map.shape)
        for p in self.pairs:
            if p.lit == name or p.other == name:
                cross = np.maximum(cross, p.crosstalk_map)
        tint = np.clip(cross, 0.0, 1.0)[..., None]
        rgb = rgb * (1 - tint) + np.array([0.9, 0.1, 0.9]) * tint
        return Image.fromarray(np.round(rgb * 255).astype(np.uint8))


def check_feasibility(design: Design, grid: int = 96) -> FeasibilityReport:
    """Check every view and every pair of views on a board grid.

    Args:
        design: The resolved design.
        grid: Points along the board's long side.

    Returns:
        The report; ``errors`` name views no scratch can light on most of the board
        (reachable share below :data:`MIN_REACHABLE_FRACTION`) and pairs of views whose
        half-vectors are less than one lobe width apart from each other's profile
        normals (median over the board): what lights one lights the other.
    """
    tool = design.scratch
    steepest = float(steepest_wall_deg(tool.width_mm, tool.depth_mm))
    lobe = lobe_deg(design.board.roughness)
    pts = board_points(design.board, grid)
    hs = {v.name: half_vectors(design, v, pts) for v in design.views}
    errors: list[str] = []
    warnings: list[str] = []
    views: dict[str, ViewFeasibility] = {}
    for v in design.views:
        tilt = tilt_deg(hs[v.name])
        frac = float(np.mean(tilt <= steepest + lobe))
        views[v.name] = ViewFeasibility(
            v.name, float(tilt.min()), float(np.median(tilt)), float(tilt.max()), frac, tilt
        )
        if frac < MIN_REACHABLE_FRACTION:
            errors.append(
                f"view '{v.name}' is unreachable: its half-vector tilts "
                f"{tilt.min():.1f}-{tilt.max():.1f} deg from the board normal but the tool's "
                f"steepest wall is {steepest:.1f} deg (+{lobe:.1f} deg lobe), so only "
                f"{100 * frac:.0f}% of the board can light up; move the camera or the light "
                "toward the mirror direction, or use a deeper or narrower tool"
            )
        elif frac < 1.0:
            warnings.append(
                f"view '{v.name}': only {100 * frac:.1f}% of the board can light up "
                f"(half-vector tilt up to {tilt.max():.1f} deg)"
            )
    pairs: list[PairFeasibility] = []
    for k in design.views:
        across = across_directions(hs[k.name])
        for j in design.views:
            if j.name == k.name:
                continue
            sep = arc_distance_deg(hs[j.name], across, steepest)
            cross = ggx_ratio(sep, design.board.roughness)
            pairs.append(
                PairFeasibility(
                    k.name,
                    j.name,
                    float(sep.min()),
                    float(np.median(sep)),
                    float(np.median(cross)),
                    cross,
                )
            )
    for a, b in combinations(design.views, 2):
        # The worse of the two directions decides: scratches for a seen by b, or back.
        worst = min(
            (p for p in pairs if {p.lit, p.other} == {a.name, b.name}),
            key=lambda p: p.separation_median_deg,
        )
        if worst.separation_median_deg < lobe:
            errors.append(
                f"views '{a.name}' and '{b.name}' are indistinguishable: scratches that "
                f"light '{worst.lit}' also light '{worst.other}' (its half-vector lies "
                f"{worst.separation_median_deg:.2f} deg from their normals, within the "
                f"{lobe:.1f} deg roughness lobe); move one of the views"
            )
        elif worst.separation_median_deg < WARN_SEPARATION_LOBES * lobe:
            warnings.append(
                f"views '{a.name}' and '{b.name}' are close: expected crosstalk "
                f"{worst.expected_crosstalk:.2f} ({worst.separation_median_deg:.1f} deg apart, "
                f"lobe {lobe:.1f} deg)"
            )
    return FeasibilityReport(steepest, lobe, views, pairs, errors, warnings)
