"""Can the tool's profile show each view, and can it tell the views apart?

A scratch lights view k at board point p when one of its profile normals equals the
half-vector h_k(p) within the GGX lobe (SPEC section 4). The profile's normals lie in
the plane spanned by the scratch's across-direction and z, tilted at most by the
steepest wall 2 atan(2w / wbar) (SPEC section 3). Hence:

- view k is reachable at p when tilt(h_k) = atan(|h_xy| / h_z) <= steepest wall + lobe;
- a scratch turned to light view k at p (across-direction along h_k's horizontal
  part) carries the arc of normals {cos(t) z + sin(t) a_k : |t| <= steepest}; it also
  lights view j by the angle between h_j and that arc compared with the lobe;
- the bare board glints into view k at p when its own microfacets, turned up (D(h_z)),
  return more than a scratch covering the pixel can at best (D averaged across the
  profile): there every scratch only darkens the pixel, so no layout shows the image.
  That happens where tilt(h_k) is below :func:`glint_limit_deg`, about 1.5 lobe widths.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from scratchfab import figures
from scratchfab.design import quick
from scratchfab.errors import ConfigError
from scratchfab.model.design import MAX_SCRATCHES, Board, Design, View
from scratchfab.render.profile import profile_normal, solve_wbar, steepest_wall_deg

#: A view must be able to light at least this share of the board.
MIN_REACHABLE_FRACTION = 0.5
#: Pairs closer than this many lobe widths (median over the board) get a warning.
WARN_SEPARATION_LOBES = 3.0
#: A view whose board is outshone past the glint on at least this share gets a warning.
#: Measured on a 200 mm demo board (300 steps, rho past the glint, sun / house): 1.7 % of it
#: outshone (20,000 scratches) 0.94 / 0.92, 4.9 % (8036) 0.78 / 0.75, 8.7 % (4000) 0.51 /
#: 0.47; at 2 % the advised count (17,846) comes near the first.
SHOULDER_WARN_FRACTION = 0.02
#: Pairs of views the terminal summary lists (most expected crosstalk first; three views make six).
PAIR_LINES = 6
#: Map dots where another view sees at least this share of the GGX peak (one lobe width).
CROSSTALK_DOTS = 0.25
#: Map colours (Okabe-Ito based; blue against yellow/orange survives red-green blindness).
REACH_LIGHT = (166, 206, 227)
REACH_DARK = (31, 90, 160)
LOBE_ONLY = figures.OKABE_ITO["yellow"]
UNREACHABLE = figures.OKABE_ITO["vermillion"]
#: The bare board's glint (hatched too: no layout shows the image there).
GLINT = figures.OKABE_ITO["reddish_purple"]
#: The line around where the bare board outshines the layout's grooves (the glint and its
#: shoulder past it): the glint's purple darkened to CIE L* 35, so that it stands out on
#: the light blues of small tilts in grey and under red-green blindness too.
SHOULDER = (117, 49, 90)
HATCH = figures.HATCH_RGB
#: The map is drawn at least this wide (pixels), each grid cell a square block.
MAP_MIN_PX = 384

#: How a design refusal ends: the option that overrides it (``run`` names its own).
DESIGN_ANYWAY = "(use --force to design anyway)"


def lobe_deg(roughness: float) -> float:
    """Angular width of the GGX lobe, atan(alpha): where D falls to about a quarter of its peak."""
    return math.degrees(math.atan(roughness))


def ggx_ratio(angle_deg: np.ndarray, roughness: float) -> np.ndarray:
    """D(cos angle) / D(1) for GGX (SPEC section 4): the relative response off the lobe's peak."""
    return ggx_ratio_cos(np.cos(np.radians(angle_deg)), roughness)


def ggx_ratio_cos(c: np.ndarray, roughness: float) -> np.ndarray:
    """:func:`ggx_ratio` of the angle whose cosine is ``c`` (> 0)."""
    a2 = roughness * roughness
    return a2 * a2 / (1.0 + (a2 - 1.0) * c * c) ** 2


def scratch_response(
    tilt: np.ndarray | float, width_mm: float, depth_mm: float, roughness: float
) -> np.ndarray:
    """What a scratch covering a pixel returns at best, over the flat board's peak D(1).

    The footprint NDF (SPEC section 4) of a footprint that a scratch's width fills: D(h . n(x))
    averaged across the profile, for h tilted ``tilt`` degrees in the plane of the profile's
    normals (the scratch's across-direction along h's horizontal part, its brightest turn).
    Trapezoid rule over x, 64 nodes per lobe width of the profile's normals.
    """
    w = 0.5 * width_mm
    wbar = float(solve_wbar(width_mm, depth_mm))
    # The normal turns 4 / wbar radians per mm at the centre (fastest): a lobe is alpha wbar / 4.
    nodes = max(2001, math.ceil(64 * 2 * w / (roughness * wbar / 4)) + 1)
    nx, nz = profile_normal(np.linspace(-w, w, nodes), wbar)
    t = np.radians(np.asarray(tilt, dtype=np.float64))[..., None]
    c = np.sin(t) * nx + np.cos(t) * nz
    ratio = ggx_ratio_cos(c, roughness)  # c > 0 on the profile
    inner = ratio[..., 1:-1].sum(axis=-1) + 0.5 * (ratio[..., 0] + ratio[..., -1])
    return np.asarray(inner / (nodes - 1))


def design_glint_deg(design: Design) -> float:
    """The glint limit (degrees of half-vector tilt) of the design's tool and board."""
    tool = design.scratch
    return glint_limit_deg(tool.width_mm, tool.depth_mm, design.board.roughness)


def glint_limit_deg(width_mm: float, depth_mm: float, roughness: float) -> float:
    """Half-vector tilt below which the bare board outshines any scratch (the glint).

    Where tilt(h) < this, the flat board's D(h_z) exceeds :func:`scratch_response`: a pixel
    grows darker the more scratches cover it, so no layout can show a bright pixel on a
    dark one there. :func:`outshine_limit_deg` at full coverage.
    """
    return outshine_limit_deg(width_mm, depth_mm, roughness, 1.0)


def outshine_ratio(
    tilt: np.ndarray | float, width_mm: float, depth_mm: float, roughness: float
) -> np.ndarray:
    """The groove coverage whose light equals the bare board's at half-vector ``tilt`` (deg).

    A pixel a share c of which grooves turned toward h cover returns c S(t) + (1 - c) D(t)
    over D(1) (SPEC section 4, S = :func:`scratch_response`, D(t) = :func:`ggx_ratio`): the
    grooves' light c S(t) outshines the bare board's D(t) where c exceeds D(t) / S(t),
    which this returns (above 1 inside the glint).
    """
    flat = ggx_ratio(np.asarray(tilt, dtype=np.float64), roughness)
    return np.asarray(flat / scratch_response(tilt, width_mm, depth_mm, roughness))


def outshine_limit_deg(
    width_mm: float, depth_mm: float, roughness: float, coverage: float
) -> float:
    """Half-vector tilt below which the bare board outshines grooves covering ``coverage``.

    Below it :func:`outshine_ratio` exceeds ``coverage``: the polished board mirrors more
    light into the view than grooves covering that share of a pixel return at their
    brightest turn. At coverage 1 it is the glint (:func:`glint_limit_deg`); a sparser
    layout pushes it out along the GGX lobe's shoulder (10.4 deg at coverage 0.05 for the
    default tool). The flat board's D falls from its peak within a lobe width while a
    scratch's average stays about flat up to the steepest wall, so the ratio falls once
    below it (bisection); the steepest wall itself when it does not get there.
    """
    top = float(steepest_wall_deg(width_mm, depth_mm))

    def brighter(t: float) -> bool:
        return bool(outshine_ratio(t, width_mm, depth_mm, roughness) > coverage)

    if brighter(top):
        return top
    lo, hi = 0.0, top
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if brighter(mid) else (lo, mid)
    return 0.5 * (lo + hi)


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
    return half_vectors_from(design.light_for(view), view.camera_position, points)


def half_vectors_from(light: np.ndarray, camera: np.ndarray, points: np.ndarray) -> np.ndarray:
    """:func:`half_vectors` for a light and a camera at the given positions (mm).

    Component by component (a norm over a last axis of 3 is slow in NumPy), summing the
    squares in x, y, z order as that norm does.
    """
    points = np.asarray(points, dtype=float)
    x, y = points[..., 0], points[..., 1]

    def unit(source: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dx, dy = source[0] - x, source[1] - y
        dz = np.full_like(dx, source[2])
        norm = np.sqrt(dx * dx + dy * dy + dz * dz)
        return dx / norm, dy / norm, dz / norm

    wi = unit(np.asarray(light, dtype=float))
    wo = unit(np.asarray(camera, dtype=float))
    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    norm = np.sqrt(hx * hx + hy * hy + hz * hz)
    return np.stack([hx / norm, hy / norm, hz / norm], axis=-1)


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
    """Per-view result: tilt of the half-vector against what the profile reaches.

    ``glint_fraction`` is the share of the board where the bare board glints into the view
    (tilt below :func:`glint_limit_deg`); ``shoulder_fraction`` the share past it where
    the bare board still outshines the initial layout's grooves (tilt below
    :attr:`FeasibilityReport.shoulder_deg`), None when the check had no target images.
    """

    name: str
    tilt_min_deg: float
    tilt_median_deg: float
    tilt_max_deg: float
    reachable_fraction: float
    tilt_map: np.ndarray = field(repr=False)
    glint_fraction: float = 0.0
    shoulder_fraction: float | None = None

    def to_json(self) -> dict[str, Any]:
        """JSON-ready summary (the map is written as a PNG)."""
        return {
            "tilt_min_deg": round(self.tilt_min_deg, 4),
            "tilt_median_deg": round(self.tilt_median_deg, 4),
            "tilt_max_deg": round(self.tilt_max_deg, 4),
            "reachable_fraction": round(self.reachable_fraction, 6),
            "glint_fraction": round(self.glint_fraction, 6),
            "shoulder_fraction": _rounded(self.shoulder_fraction, 6),
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
    """Everything the check found; ``errors`` stop ``design`` unless forced.

    ``groove_coverage`` is the initial layout's groove area (expected length times the
    tool's width) over the board inside the margin, and ``mean_length_mm`` the expected
    scratch length; both None when the check had no target images. ``glint_deg`` is
    :func:`glint_limit_deg` of the design's tool and board; ``shoulder_deg``
    :func:`outshine_limit_deg` at the groove coverage (capped at 1), the tilt below which
    the bare board outshines the layout's grooves, and ``shoulder_count`` the
    ``[scratch] count`` whose grooves outshine it wherever it does not glint (None when
    they already do, when no count up to :data:`MAX_SCRATCHES` does without grooves
    covering more than the board, or without target images).
    """

    steepest_wall_deg: float
    lobe_deg: float
    views: dict[str, ViewFeasibility]
    pairs: list[PairFeasibility]
    errors: list[str]
    warnings: list[str]
    groove_coverage: float | None = None
    mean_length_mm: float | None = None
    glint_deg: float = 0.0
    shoulder_deg: float | None = None
    shoulder_count: int | None = None

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
            "glint_limit_deg": round(self.glint_deg, 4),
            "shoulder_limit_deg": _rounded(self.shoulder_deg, 4),
            "shoulder_count": self.shoulder_count,
            "views": {name: v.to_json() for name, v in self.views.items()},
            "pairs": [p.to_json() for p in self.pairs],
            "groove_coverage": _rounded(self.groove_coverage, 4),
            "mean_length_mm": _rounded(self.mean_length_mm, 4),
            "errors": list(self.errors),
            "warnings": list(self.warnings),
            "maps": (
                "feasibility_<view>.png: board seen from the front (top = +y); blue: the "
                "profile reaches the half-vector (darker: tilted closer to the steepest wall), "
                "yellow: only through the roughness lobe, orange with hatching: unreachable, "
                "purple with hatching: the bare board glints (half-vector tilt below "
                "glint_limit_deg: the polished board mirrors the light into the view brighter "
                "than a scratch can shine there); a dark purple line around the half-vectors "
                "tilted below shoulder_limit_deg: the bare board outshines the layout's grooves "
                "inside it, past the glint too, so the image shows only faintly there; "
                f"black dots: expected crosstalk with another view at least {CROSSTALK_DOTS:g} "
                "of the peak (within one lobe width); the key under the map gives the tilt "
                "scale in degrees"
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
            f"(+{self.lobe_deg:.1f} deg roughness lobe); the bare board glints brighter than "
            f"a scratch where they tilt less than {self.glint_deg:.1f} deg"
        ]
        for name, v in self.views.items():
            glint = f", {100 * v.glint_fraction:.1f}% glints" if v.glint_fraction else ""
            lines.append(
                f"view '{name}': half-vector tilt {v.tilt_min_deg:.1f}-{v.tilt_max_deg:.1f} deg, "
                f"{100 * v.reachable_fraction:.0f}% of the board reachable{glint}"
            )
        # Many views make many pairs: the terminal gets those most likely to show crosstalk.
        order = sorted(range(len(self.pairs)), key=lambda i: -self.pairs[i].expected_crosstalk)
        shown = sorted(order[:PAIR_LINES])
        for p in (self.pairs[i] for i in shown):
            lines.append(
                f"scratches for '{p.lit}' seen by '{p.other}': {p.separation_median_deg:.1f} deg "
                f"off their normals (median), expected crosstalk {p.expected_crosstalk:.3f}"
            )
        if len(self.pairs) > len(shown):
            lines.append(
                f"... and {len(self.pairs) - len(shown)} more pairs of views, less crosstalk expected "
                "(every pair in feasibility.json)"
            )
        lines += [f"warning: {w}" for w in self.warnings]
        lines += [f"error: {e}" for e in self.errors] if errors else []
        return lines

    def raise_if_errors(self, source: str) -> None:
        """Raise one ConfigError naming the source and every problem (with the --force hint)."""
        if self.errors:
            raise ConfigError(f"{source}: " + "; ".join(self.errors) + f" {DESIGN_ANYWAY}")

    def map_image(self, name: str) -> Image.Image:
        """The feasibility map of one view as an RGB picture with its key (see :func:`map_figure`)."""
        return map_figure(self, name).image


def check_feasibility(
    design: Design, grid: int = 96, boards: Mapping[str, np.ndarray] | None = None
) -> FeasibilityReport:
    """Check every view and every pair of views on a board grid.

    Args:
        design: The resolved design.
        grid: Points along the board's long side.
        boards: View name -> its target as a board-space image
            (:func:`scratchfab.design.targets.board_image`); with them the report gives
            the initial layout's groove coverage, and warns when it is above 1.

    Returns:
        The report; ``errors`` name views no scratch can light on most of the board
        (reachable share below :data:`MIN_REACHABLE_FRACTION`), views that can show their
        image on less than that share because the bare board glints on the rest (any
        glint is a warning: the glint outshines the image), pairs of views whose
        half-vectors are less than one lobe width apart from each other's profile
        normals (median over the board): what lights one lights the other, and more
        scratches than fit at their shortest.
    """
    tool = design.scratch
    steepest = float(steepest_wall_deg(tool.width_mm, tool.depth_mm))
    lobe = lobe_deg(design.board.roughness)
    glint_deg = design_glint_deg(design)
    pts = board_points(design.board, grid)
    hs = {v.name: half_vectors(design, v, pts) for v in design.views}
    errors: list[str] = []
    warnings: list[str] = []
    coverage = mean_length = None
    drawn: tuple[int, float] | None = None
    shoulder_deg = shoulder_count = None
    crowded: list[str] = []
    density: tuple[np.ndarray, dict[str, np.ndarray]] | None = None
    if boards:
        # imported here: the layout imports this module's geometry
        from scratchfab.design.layout import board_densities, length_by_count

        density = board_densities(design, boards)
        lengths = length_by_count(design, *density)
        coverage, mean_length, fits, crowded = _coverage(design, *density, lengths)
        drawn = (fits, mean_length)
        shoulder_deg = outshine_limit_deg(
            tool.width_mm, tool.depth_mm, design.board.roughness, min(coverage, 1.0)
        )
    views: dict[str, ViewFeasibility] = {}
    for v in design.views:
        tilt = tilt_deg(hs[v.name])
        frac = float(np.mean(tilt <= steepest + lobe))
        glint = float(np.mean(tilt < glint_deg))
        views[v.name] = ViewFeasibility(
            v.name, float(tilt.min()), float(np.median(tilt)), float(tilt.max()), frac, tilt, glint
        )
        if frac >= MIN_REACHABLE_FRACTION and glint:
            shows = frac - glint  # glint (low tilt) and unreachable (high) never overlap
            problem = _glint_problem(design, v, pts, tilt, glint_deg, glint, shows, shoulder_deg)
            (errors if shows < MIN_REACHABLE_FRACTION else warnings).append(problem)
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
    warnings += crowded
    if density is not None and coverage is not None and shoulder_deg is not None:
        for found in views.values():
            tilt = found.tilt_map
            found.shoulder_fraction = float(np.mean((tilt >= glint_deg) & (tilt < shoulder_deg)))
        if any(
            (found.shoulder_fraction or 0.0) >= SHOULDER_WARN_FRACTION for found in views.values()
        ):
            advised = _outshining_count(design, views, glint_deg, lengths, coverage)
            shoulder_count = advised[0] if advised is not None else None
            warnings.append(
                _shoulder_problem(design, views, pts, glint_deg, shoulder_deg, coverage, advised)
            )
    errors += _crowding_errors(design, drawn)
    pairs = _pairs(design, hs, steepest)
    apart: list[tuple[str, str, PairFeasibility]] = []  # (a, b, the worse direction)
    for a, b, worst in _worst_pairs(design, pairs):
        if worst.separation_median_deg < lobe:
            apart.append((a, b, worst))
        elif worst.separation_median_deg < WARN_SEPARATION_LOBES * lobe:
            warnings.append(
                f"views '{a}' and '{b}' are close: expected crosstalk "
                f"{worst.expected_crosstalk:.2f} ({worst.separation_median_deg:.1f} deg apart, "
                f"lobe {lobe:.1f} deg)"
            )
    if apart:
        errors.append(_indistinguishable(design, apart, lobe, steepest, grid))
    return FeasibilityReport(
        steepest,
        lobe,
        views,
        pairs,
        errors,
        warnings,
        coverage,
        mean_length,
        glint_deg,
        shoulder_deg,
        shoulder_count,
    )


def _pairs(design: Design, hs: Mapping[str, np.ndarray], steepest: float) -> list[PairFeasibility]:
    """Every ordered pair of views: how scratches turned for one light the other.

    Args:
        design: The resolved design.
        hs: View name -> its half-vectors on the board grid (:func:`half_vectors`).
        steepest: The tool's steepest wall (degrees).
    """
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
    return pairs


def _worst_pairs(
    design: Design, pairs: list[PairFeasibility]
) -> list[tuple[str, str, PairFeasibility]]:
    """Each unordered pair of views (in the design's order) with its worse direction.

    The worse of the two directions decides: scratches for a seen by b, or back.
    """
    return [
        (
            a.name,
            b.name,
            min(
                (p for p in pairs if {p.lit, p.other} == {a.name, b.name}),
                key=lambda p: p.separation_median_deg,
            ),
        )
        for a, b in combinations(design.views, 2)
    ]


#: Pairs of views an "indistinguishable" error names before counting the rest.
NAMED_PAIRS = 4


def _indistinguishable(
    design: Design,
    apart: list[tuple[str, str, PairFeasibility]],
    lobe: float,
    steepest: float,
    grid: int,
) -> str:
    """One error for every pair of views whose scratches light each other, with one piece of advice.

    The quick form's advice names how many images it can keep apart
    (:func:`quick_images_apart`).
    """
    (a, b, worst), rest = apart[0], apart[1:]
    seps = [p.separation_median_deg for _, _, p in apart]
    lo, hi = min(seps), max(seps)
    if not rest:
        what = (
            f"views '{a}' and '{b}' are indistinguishable: scratches that light '{worst.lit}' "
            f"also light '{worst.other}' (its half-vector lies {lo:.2f} deg"
        )
    else:
        named = ", ".join(f"'{x}' and '{y}'" for x, y, _ in rest[: NAMED_PAIRS - 1])
        more = len(rest) - (NAMED_PAIRS - 1)
        named += f" and {more} more pair{'s' if more > 1 else ''}" if more > 0 else ""
        spread = f"{lo:.2f} deg" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}-{hi:.2f} deg"
        what = (
            f"views '{a}' and '{b}' are indistinguishable, as are {named} ({len(apart)} pairs): "
            "scratches that light one view of a pair also light the other (its half-vector "
            f"lies {spread}"
        )
    if _quick(design):
        most = quick_images_apart(design, lobe, steepest, grid)
        change = f"give fewer images (at most {most})"
    else:
        change = "move one of the views" if not rest else "move the views of each pair apart"
    return (
        f"{what} from their normals, median over the board, within the {lobe:.1f} deg "
        f"roughness lobe); {change}"
    )


def quick_images_apart(design: Design, lobe: float, steepest: float, grid: int = 96) -> int:
    """How many images the quick form keeps apart on ``design``'s board (at least 1).

    Judged as :func:`check_feasibility` judges, on a board grid of ``grid`` points along
    the long side.

    Places 2, 3, ... views as the quick form does until a pair's median separation falls
    within the lobe (the views draw closer with each one added); at most one fewer than
    ``design`` has, which the caller found too close.
    """
    for n in range(1, len(design.views)):
        tried = quick.quick_design(
            [f"view{i}.png" for i in range(n + 1)], (design.board.width_mm, design.board.height_mm)
        )
        pts = board_points(tried.board, grid)
        hs = {v.name: half_vectors(tried, v, pts) for v in tried.views}
        pairs = _worst_pairs(tried, _pairs(tried, hs, steepest))
        if any(p.separation_median_deg < lobe for _, _, p in pairs):
            return n
    return max(1, len(design.views) - 1)


#: The farthest :func:`glint_free_scale` looks (times the camera's and light's distances).
GLINT_SCALE_LIMIT = 20.0


def glint_free_scale(
    design: Design,
    views: Sequence[View],
    points: np.ndarray,
    glint_deg: float,
    shoulder_deg: float | None = None,
) -> float | None:
    """The least factor on the views' cameras' and lights' positions that ends their glint.

    They stand that many times as far from the board's centre (the origin), so their
    directions seen from the board spread less and every half-vector of each view at
    ``points`` tilts at least ``glint_deg``; given ``shoulder_deg``, also under
    :data:`SHOULDER_WARN_FRACTION` of ``points`` tilt less than it (no shoulder warning:
    with no glint its share is those points'). In tenths; None where no factor up to
    :data:`GLINT_SCALE_LIMIT` does (the light's mirror image then stays near the board's
    centre: the view must move).
    """
    places = [(design.light_for(v), v.camera_position) for v in views]

    def clear(k: float) -> bool:
        for light, camera in places:
            tilt = tilt_deg(half_vectors_from(k * light, k * camera, points))
            if tilt.min() < glint_deg:
                return False
            if shoulder_deg is not None and np.mean(tilt < shoulder_deg) >= SHOULDER_WARN_FRACTION:
                return False
        return True

    steps = np.round(np.arange(10, round(10 * GLINT_SCALE_LIMIT) + 1) / 10.0, 1)
    return next((float(k) for k in steps if clear(float(k))), None)


def _glint_problem(
    design: Design,
    view: View,
    pts: np.ndarray,
    tilt: np.ndarray,
    glint_deg: float,
    share: float,
    shows: float,
    shoulder_deg: float | None = None,
) -> str:
    """The message for a view into which the bare board glints on ``share`` of the board.

    ``shows`` is the share where the view can show its image (reachable, no glint); below
    :data:`MIN_REACHABLE_FRACTION` the message says so. Given the shoulder's limit
    (:attr:`FeasibilityReport.shoulder_deg`), the distance advice also names the factor
    that ends the band past the glint where the bare board still outshines the layout's
    grooves, where it is another than the glint's.
    """
    tool = design.scratch
    peak = float(ggx_ratio(np.asarray(tilt.min()), design.board.roughness))
    times = peak / float(
        scratch_response(tilt.min(), tool.width_mm, tool.depth_mm, design.board.roughness)
    )
    x, y = pts[np.unravel_index(np.argmin(tilt), tilt.shape)]
    scale = None if _quick(design) else glint_free_scale(design, [view], pts, glint_deg)
    farther = (
        f"at least {scale:.1f} times as far from the board's centre"
        if scale is not None
        else "farther away in proportion to the board"
    )
    spread = "its half-vectors then spread less"
    if scale is not None and shoulder_deg is not None:
        both = glint_free_scale(design, [view], pts, glint_deg, shoulder_deg)
        band = (
            "also ends the glint's shoulder, the band past it where the bare board still "
            f"outshines the layout's grooves, tilted up to {shoulder_deg:.1f} deg"
        )
        if both is None:
            spread += f"; no factor up to {GLINT_SCALE_LIMIT:g} {band}"
        elif both > scale:
            spread += f"; at least {both:.1f} times {band}"
    change = (
        "move the camera or the light so that the light's mirror image leaves the board "
        f"(every half-vector tilted at least {glint_deg:.1f} deg), stand both {farther} "
        f"({spread}), or use a smaller board"
    )
    if _quick(design):
        # No option helps: the quick form stands its cameras and light farther away in
        # proportion to a board above 100 mm, and places them for its one tool.
        change = (
            "the quick form places the cameras and the light itself, and no option of it "
            "moves them: design from a design.toml instead (with --force the quick form "
            f"writes one in JOB/design to start from) and there {change}"
        )
    return (
        f"view '{view.name}': the bare board mirrors the light into it on "
        f"{100 * share:.1f}% of the board, around ({x:.0f}, {y:.0f}) mm, where its "
        f"half-vector tilts less than {glint_deg:.1f} deg (down to {tilt.min():.1f}): the "
        f"polished board shines there up to {times:.0f} times brighter than a scratch "
        "covering it can, so scratches only darken it and the glint outshines the image"
        + (
            f" (shown on only {100 * shows:.0f}% of the board)"
            if shows < MIN_REACHABLE_FRACTION
            else ""
        )
        + f"; {change}"
    )


def _warned_below(tilt: np.ndarray, glint_deg: float) -> float:
    """The tilt below which under :data:`SHOULDER_WARN_FRACTION` of the grid is past the glint.

    Infinite when all of ``tilt``'s grid past ``glint_deg`` is less than that share.
    """
    past = np.sort(tilt[tilt >= glint_deg], axis=None)
    k = math.ceil(SHOULDER_WARN_FRACTION * tilt.size) - 1
    return float(past[k]) if k < past.size else math.inf


def _outshining_count(
    design: Design,
    views: Mapping[str, ViewFeasibility],
    glint_deg: float,
    lengths: Callable[[int], float],
    coverage: float,
) -> tuple[int, float] | None:
    """The least ``[scratch] count`` whose grooves leave no warning past the glint.

    Returns the count and the groove coverage it gives; None where it is above
    :data:`MAX_SCRATCHES` or its grooves would cover more than the board (the coverage
    grows with the count up to 1, where the limit is the glint's).

    The groove coverage must exceed :func:`outshine_ratio` at the tilt below which each
    view keeps less than :data:`SHOULDER_WARN_FRACTION` of the check's grid past
    ``glint_deg`` (at most 1 there, so the grooves need not overlap);
    the coverage grows with the count in proportion, bar the rounding of the views' shares,
    which the search settles on the layout's own expected length.

    Args:
        design: The resolved design.
        views: The views' results (their tilt maps).
        glint_deg: :func:`glint_limit_deg` of the design.
        lengths: The layout's expected total length by count
            (:func:`scratchfab.design.layout.length_by_count` on its density grid).
        coverage: The groove coverage at the design's count.
    """
    tool = design.scratch
    roughness = design.board.roughness
    least = min(_warned_below(v.tilt_map, glint_deg) for v in views.values())
    need = float(outshine_ratio(least, tool.width_mm, tool.depth_mm, roughness))

    def covers(count: int) -> float:
        return _groove_coverage(design, lengths, count)[0]

    count = max(tool.count + 1, math.ceil(tool.count * need / coverage))
    while count <= MAX_SCRATCHES:
        cov = covers(count)
        if cov > 1.0:
            break
        if outshine_limit_deg(tool.width_mm, tool.depth_mm, roughness, cov) <= least:
            return count, cov
        count += max(1, count // 1000)
    return None


def _shoulder_problem(
    design: Design,
    views: Mapping[str, ViewFeasibility],
    pts: np.ndarray,
    glint_deg: float,
    shoulder_deg: float,
    coverage: float,
    advised: tuple[int, float] | None,
) -> str:
    """The warning for views where the bare board outshines the layout's grooves past the glint.

    Names each such view with its share of the board and where it is worst (the smallest
    tilt past the glint), and the count that makes the grooves outshine it with the
    coverage it gives (``advised``, :func:`_outshining_count`; None: no count does).
    """
    tool = design.scratch
    where = []
    worst = 0.0
    for v in views.values():
        if not v.shoulder_fraction:
            continue
        tilt = np.where(v.tilt_map >= glint_deg, v.tilt_map, np.inf)
        x, y = pts[np.unravel_index(np.argmin(tilt), tilt.shape)]
        # the band rings a glint; elsewhere its worst point is its smallest tilt
        near = "around its glint" if v.glint_fraction else f"worst around ({x:.0f}, {y:.0f}) mm"
        where.append(f"'{v.name}' on {100 * v.shoulder_fraction:.1f}% of the board, {near}")
        ratio = outshine_ratio(tilt.min(), tool.width_mm, tool.depth_mm, design.board.roughness)
        worst = max(worst, float(ratio))
    views_said = "view " + ", ".join(where) if len(where) == 1 else "views " + ", ".join(where)
    move = (
        "move the cameras or the light so that every half-vector tilts at least "
        f"{shoulder_deg:.1f} deg"
    )
    scale = (
        None
        if _quick(design)
        else glint_free_scale(design, design.views, pts, glint_deg, shoulder_deg)
    )
    if scale is not None:
        move += (
            f" on all but {100 * SHOULDER_WARN_FRACTION:.0f}% of the board (standing the "
            f"cameras and the light at least {scale:.1f} times as far from the board's centre "
            "does)"
        )
    if advised is None:
        change = (
            f"no scratch count up to {MAX_SCRATCHES:,} makes the grooves outshine it there "
            "without covering more than the board: "
            + (
                "the quick form places the cameras and the light itself: design from a "
                f"design.toml and {move}"
                if _quick(design)
                else move
            )
        )
    elif _quick(design):
        count, covered = advised
        change = (
            f"give --count {count} or more (groove coverage {covered:.2f}) so that the grooves "
            f"outshine it on all but {100 * SHOULDER_WARN_FRACTION:.0f}% of the board past the "
            "glint (the quick form places the cameras "
            "and the light itself: to move them, design from a design.toml)"
        )
    else:
        count, covered = advised
        change = (
            f"set [scratch] count to at least {count} (groove coverage {covered:.2f}) so that "
            f"the grooves outshine it on all but {100 * SHOULDER_WARN_FRACTION:.0f}% of the "
            f"board past the glint, or {move}"
        )
    return (
        f"past the glint, the bare board still outshines the scratches where the half-vector "
        f"tilts {glint_deg:.1f}-{shoulder_deg:.1f} deg: {views_said}; there the polished "
        "board's gloss mirrors more light into the view than the grooves return at the "
        f"layout's groove coverage of {coverage:.2f} (up to {worst / coverage:.0f} times), so "
        f"the image shows only faintly over a bright haze; {change}"
    )


def _crowding_errors(design: Design, drawn: tuple[int, float] | None = None) -> list[str]:
    """Refuse more scratches than fit side by side, even at their shortest, inside the margin.

    Each cuts a dent ``width_mm`` wide along at least ``min_length_mm``; more dent than
    board means overlapping dents, which cut each other's walls away.

    Args:
        design: The resolved design.
        drawn: How many fit at the lengths the targets give them (the coverage warning's
            count, smaller) and their mean length; the error then says why the two differ.
    """
    tool = design.scratch
    usable = usable_area(design.board)
    least = tool.count * tool.min_length_mm * tool.width_mm
    fits = _fit_at_shortest(design)
    if tool.count <= fits:
        return []
    why = (
        f" (at the {drawn[1]:.1f} mm the targets' brightness gives them on average, "
        f"{drawn[0]} fit: the overlap warning's count)"
        if drawn is not None
        else ""
    )
    return [
        f"{tool.count} scratches of at least {tool.min_length_mm:g} x {tool.width_mm:g} mm "
        f"cover {least:g} mm^2, more than the {usable:g} mm^2 of board inside the margin: "
        f"they would overlap even at their shortest{why}; "
        + (
            f"give --count at most {fits} or a larger --board"
            if _quick(design)
            else f"set [scratch] count to at most {fits} or shorten min_length_mm"
        )
    ]


def _fit_at_shortest(design: Design) -> int:
    """How many scratches fit side by side inside the margin at ``min_length_mm``."""
    tool = design.scratch
    return math.floor(
        usable_area(design.board) / (tool.min_length_mm * tool.width_mm) * (1 + 1e-12)
    )


def _quick(design: Design) -> bool:
    """Whether ``design`` is the quick form's: its user changes options, not a file's keys."""
    return design.source == quick.SOURCE


def usable_area(board: Board) -> float:
    """The board's area inside the margin (mm^2)."""
    return (board.width_mm - 2 * board.margin_mm) * (board.height_mm - 2 * board.margin_mm)


def _groove_coverage(
    design: Design, lengths: Callable[[int], float], count: int
) -> tuple[float, float]:
    """The initial layout's groove coverage and its total scratch length (mm) at ``count``.

    Coverage: groove area over the board inside the margin; ``lengths`` is
    :func:`scratchfab.design.layout.length_by_count` on the layout's density grid
    (as :func:`_coverage` takes it).
    """
    total = lengths(count)
    return total * design.scratch.width_mm / usable_area(design.board), total


def _coverage(
    design: Design, pts: np.ndarray, dens: dict[str, np.ndarray], lengths: Callable[[int], float]
) -> tuple[float, float, int, list[str]]:
    """Groove coverage, mean length, the count keeping it to 1, and a warning above 1.

    All of the initial layout's, from its density grid ``pts`` and the views' densities
    ``dens`` (:func:`scratchfab.design.layout.board_densities`); ``lengths`` is
    :func:`scratchfab.design.layout.length_by_count` on them.

    The layout's lengths follow the targets' brightness
    (:func:`scratchfab.design.layout.expected_length`); grooves covering more than the
    board inside the margin must overlap, and the machine cuts overlapping grooves into
    one wider dent.
    """
    # imported here: the layout imports this module's geometry
    from scratchfab.design.layout import longest_for_length

    tool = design.scratch
    usable = usable_area(design.board)
    coverage, total = _groove_coverage(design, lengths, tool.count)
    mean = total / tool.count
    fits = math.floor(tool.count / coverage) if coverage > 0 else tool.count
    if coverage <= 1.0:
        return coverage, mean, fits, []
    shortest = _fit_at_shortest(design)
    crowded = (
        f" (the crowding error's {shortest} counts every scratch at min_length_mm)"
        if tool.count > shortest
        else ""
    )
    longest = longest_for_length(design, pts, dens, usable / tool.width_mm)
    if _quick(design):
        change = f"give --count at most {fits}{crowded}"
        if longest is not None:
            change += (
                f", or set [scratch] max_length_mm to at most {longest:g} in the design.toml "
                "it writes and design from that file"
            )
    else:
        change = f"set [scratch] count to at most {fits}{crowded}"
        if longest is not None:
            change += f" or max_length_mm to at most {longest:g}"
    return (
        coverage,
        mean,
        fits,
        [
            f"the {tool.count} scratches' grooves ({tool.width_mm:g} mm wide, "
            f"{mean:.1f} mm long on average: the targets' brightness sets each length "
            f"between min_length_mm {tool.min_length_mm:g} and max_length_mm "
            f"{tool.max_length_mm:g}) cover {coverage:.2f} times the {usable:g} mm^2 of "
            "board inside the margin, so they will overlap, and the machine cuts "
            f"overlapping grooves as one wider dent; {change}"
        ],
    )


def _rounded(value: float | None, digits: int) -> float | None:
    """``value`` rounded, None kept."""
    return None if value is None else round(value, digits)


def tilt_colours(
    tilt: np.ndarray, reach_deg: float, limit_deg: float, glint_deg: float = 0.0
) -> np.ndarray:
    """Map colour (uint8 RGB, (..., 3)) of half-vector tilts in degrees.

    Purple below ``glint_deg`` (the bare board's glint, hatched on the map); blue, lighter
    toward 0 and darker toward the steepest wall ``reach_deg``; yellow up to ``limit_deg``
    (steepest wall + lobe); orange beyond (hatched on the map).
    """
    t = np.asarray(tilt, dtype=np.float64)
    f = np.clip(t / max(reach_deg, 1e-9), 0.0, 1.0)[..., None]
    rgb = (1.0 - f) * np.array(REACH_LIGHT) + f * np.array(REACH_DARK)
    rgb = np.where((t > reach_deg)[..., None], np.array(LOBE_ONLY, dtype=np.float64), rgb)
    rgb = np.where((t > limit_deg)[..., None], np.array(UNREACHABLE, dtype=np.float64), rgb)
    rgb = np.where((t < glint_deg)[..., None], np.array(GLINT, dtype=np.float64), rgb)
    return np.round(rgb).astype(np.uint8)


@dataclass
class MapFigure:
    """A drawn feasibility map and where its parts are (pixels, inclusive boxes).

    Attributes:
        image: The whole picture.
        map_box: The map: grid cell (i, j) fills ``cell`` x ``cell`` pixels from
            (map_box[0] + j * cell, map_box[1] + i * cell).
        cell: Pixels per grid cell.
        bar_box: The tilt scale bar; ``bar_deg`` is the tilt at its right end.
        bar_deg: Tilt at the bar's right end (its left end is 0 deg).
        legend_box: The key.
    """

    image: Image.Image
    map_box: tuple[int, int, int, int]
    cell: int
    bar_box: tuple[int, int, int, int]
    bar_deg: float
    legend_box: tuple[int, int, int, int]


def map_figure(report: FeasibilityReport, name: str) -> MapFigure:
    """Draw one view's feasibility map with its title, tilt scale and key.

    The map shows the board from the front (row 0 at +y), each grid cell as a square
    block of pixels (nearest neighbour). Unreachable cells are hatched as well as orange,
    glint cells as well as purple, so they stay apart in grey too; cells where a scratch
    for this view lights another one (or back) at :data:`CROSSTALK_DOTS` of the peak or
    more carry dots.
    """
    v = report.views[name]
    reach = report.steepest_wall_deg
    limit = reach + report.lobe_deg
    tilt = v.tilt_map
    rows, cols = tilt.shape
    cell = max(1, -(-MAP_MIN_PX // cols))
    mw, mh = cols * cell, rows * cell
    glint = report.glint_deg
    cells = tilt_colours(tilt, reach, limit, glint)
    big = figures.enlarge(cells, cell)
    figures.hatch_cells(big, figures.enlarge((tilt > limit) | (tilt < glint), cell), HATCH)
    shoulder = report.shoulder_deg
    outshone = shoulder is not None and bool(np.any((tilt >= glint) & (tilt < shoulder)))
    if shoulder is not None and outshone:
        figures.outline_cells(big, figures.enlarge(tilt < shoulder, cell), SHOULDER)
    img = Image.fromarray(big)
    draw = ImageDraw.Draw(img)
    cross = np.zeros(tilt.shape)
    for p in report.pairs:
        if name in (p.lit, p.other):
            cross = np.maximum(cross, p.crosstalk_map)
    step = max(4, cell * 2)
    for y in range(step // 2, mh, step):
        for x in range(step // 2, mw, step):
            if cross[y // cell, x // cell] >= CROSSTALK_DOTS:
                draw.rectangle((x - 1, y - 1, x, y), fill=(0, 0, 0))

    size = figures.TEXT_PX
    m = 12
    text_w = figures.text_size("+y", size)[0]
    side = text_w + 14  # the +y arrow right of the map
    bar_deg = float(max(1.25 * limit, v.tilt_max_deg * 1.05))
    items = [
        figures.LegendItem("profile reaches it (darker: steeper)", REACH_DARK, "box"),
        figures.LegendItem("only through the roughness lobe", LOBE_ONLY, "box"),
        figures.LegendItem("unreachable", UNREACHABLE, "hatch"),
        figures.LegendItem("bare board glints brighter than a scratch", GLINT, "hatch"),
        figures.LegendItem(f"crosstalk >= {CROSSTALK_DOTS:g} of peak", (0, 0, 0), "dots"),
    ]
    if outshone:
        items.insert(
            4,
            figures.LegendItem(
                "inside the line: the bare board outshines the layout's grooves",
                SHOULDER,
                "outline",
                fill=REACH_LIGHT,
            ),
        )
    lw, lh = figures.legend_size(items, size)
    bar_label = "half-vector tilt from the board normal (deg)"
    note = (
        f"{bar_label}\ntool: steepest wall {reach:.1f} + lobe {report.lobe_deg:.1f} deg; "
        f"glint below {glint:.1f}"
    )
    # lines under the note (the picture taller by them): where the bare board outshines
    # the layout's grooves, and a warning of overlapping grooves
    more = []
    if outshone:
        more.append(f"the bare board outshines the layout's grooves below {shoulder:.1f}")
    if report.groove_coverage is not None and report.groove_coverage > 1.0:
        more.append(
            f"warning: the grooves cover {report.groove_coverage:.2f} times\n"
            "the board inside the margin: they will overlap"
        )
    warn = "\n".join(more)
    extra = figures.text_size(f"{note}\n{warn}", size)[1] - figures.text_size(note, size)[1]
    width = max(mw + side, lw, figures.text_size(note, size)[0] + 10)
    width = max(width, figures.text_size(warn, size)[0] + 10) if warn else width
    bar_h = 14
    tick_h = figures.text_size("0", size)[1]
    height = mh + 10 + tick_h + 10 + bar_h + 6 + tick_h + 6 + 2 * tick_h + 14 + lh
    height += extra if warn else 0
    canvas = Image.new("RGB", (width + 2 * m, height + 2 * m), (255, 255, 255))
    canvas.paste(img, (m, m))
    cd = ImageDraw.Draw(canvas)
    cd.rectangle((m - 1, m - 1, m + mw, m + mh), outline=figures.FRAME)
    ax = m + mw + 8 + text_w // 2
    figures.draw_arrow(cd, (ax, m + 50), (ax, m + 6), (0, 0, 0), width=2, head=8)
    cd.text((m + mw + 8, m + 54), "+y", fill=(0, 0, 0), font=figures.font(size))

    # Tilt scale: this view's range on top, the colour bar, ticks under it.
    bx0, bx1 = m, m + mw - 1
    y = m + mh + 10
    span = bx1 - bx0

    def xdeg(d: float) -> int:
        return bx0 + int(round(span * d / bar_deg))

    r0, r1 = xdeg(v.tilt_min_deg), xdeg(min(v.tilt_max_deg, bar_deg))
    label = f"view '{name}': {v.tilt_min_deg:.1f}-{v.tilt_max_deg:.1f}"
    lx = min(max(bx0, (r0 + r1) // 2 - figures.text_size(label, size)[0] // 2), bx1 - 10)
    cd.text((lx, y), label, fill=(0, 0, 0), font=figures.font(size))
    y += tick_h + 10
    cd.line([(r0, y - 4), (r1, y - 4)], fill=(0, 0, 0), width=3)
    degs = (np.arange(span + 1) + 0.5) * bar_deg / (span + 1)
    strip = np.repeat(tilt_colours(degs, reach, limit, glint)[None], bar_h, axis=0)
    strip_img = Image.fromarray(strip)
    sd = ImageDraw.Draw(strip_img)
    lim_x = xdeg(limit) - bx0
    if lim_x < span:
        figures.hatch(sd, (lim_x + 1, 0, span, bar_h - 1), HATCH, step=6)
    glint_x = int(np.searchsorted(degs, glint))  # the strip's first column at or past it
    if glint_x > 0:
        figures.hatch(sd, (0, 0, glint_x - 1, bar_h - 1), HATCH, step=6)
    if shoulder is not None and outshone:
        strip = np.asarray(strip_img).copy()
        below = np.broadcast_to(degs < shoulder, strip.shape[:2])
        figures.outline_cells(strip, below, SHOULDER)
        strip_img = Image.fromarray(strip)
    canvas.paste(strip_img, (bx0, y))
    bar_box = (bx0, y, bx1, y + bar_h - 1)
    cd.rectangle((bx0 - 1, y - 1, bx1 + 1, y + bar_h), outline=figures.FRAME)
    y += bar_h + 2
    ticks = [(0.0, "0"), (glint, f"{glint:.1f}"), (reach, f"{reach:.1f}"), (limit, f"{limit:.1f}")]
    if shoulder is not None and outshone:
        ticks.append((shoulder, f"{shoulder:.1f}"))
    ticks = sorted(ticks) + [(bar_deg, f"{bar_deg:.0f}")]
    last_right = -999
    for d, text in ticks:
        x = xdeg(d)
        cd.line([(x, y), (x, y + 4)], fill=(0, 0, 0), width=1)
        tw = figures.text_size(text, size)[0]
        tx = min(max(bx0, x - tw // 2), bx1 - tw)
        if tx > last_right + 4:
            cd.text((tx, y + 4), text, fill=(0, 0, 0), font=figures.font(size))
            last_right = tx + tw
    y += 4 + tick_h + 6
    note = f"{note}\n{warn}" if warn else note
    cd.multiline_text((bx0, y), note, fill=(0, 0, 0), font=figures.font(size), spacing=3)
    y += figures.text_size(note, size)[1] + 10
    legend_box = figures.draw_legend(canvas, items, (m, y), size)
    title = [f"view '{name}': where a scratch can light it", "board seen from the front, top = +y"]
    out = figures.add_title(canvas, title, size + 1, margin=m)
    dy = out.height - canvas.height

    def shift(b: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
        return (b[0], b[1] + dy, b[2], b[3] + dy)

    return MapFigure(
        out, shift((m, m, m + mw - 1, m + mh - 1)), cell, shift(bar_box), bar_deg, shift(legend_box)
    )
