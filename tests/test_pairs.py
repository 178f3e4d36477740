"""Pair finding against a brute-force scratches x pixels intersection test."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely
from conftest import make_design
from test_neighbour_pairs import brute_force

from scratchfab.model.camera import Camera
from scratchfab.model.design import design_from_mapping
from scratchfab.render.pairs import PIXEL_SLACK, raster_pairs, scratch_rectangles
from scratchfab.render.renderer import ViewRenderer


def brute_pairs(quads: np.ndarray, ok: np.ndarray, rects: np.ndarray) -> set[tuple[int, int]]:
    """Every (pixel, scratch) whose footprint polygon meets the rectangle, by shapely."""
    foot = shapely.polygons(quads.reshape(-1, 4, 2))
    rect = shapely.polygons(rects)
    tree = shapely.STRtree(foot)
    r_idx, f_idx = tree.query(rect, predicate="intersects")
    return {(int(f), int(r)) for f, r in zip(f_idx, r_idx, strict=True) if ok[f]}


def random_rects(rng, n, extent, half_width=(0.02, 0.3), length=(0.05, 15.0), margin=0.0):
    c = rng.uniform(-extent, extent, (n, 2))
    ang = rng.uniform(0, 2 * np.pi, n)
    ln = rng.uniform(*length, n)
    d = 0.5 * ln[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
    w = rng.uniform(*half_width, n)
    return c - d, c + d, w


def distance_to_rect(quads, pixel, scratch, rects):
    foot = shapely.polygons(quads.reshape(-1, 4, 2)[pixel])
    return shapely.distance(foot, shapely.polygons(rects[scratch]))


TILTED = {
    "board": {"width_mm": 40.0, "height_mm": 30.0, "margin_mm": 1.0},
    "light": {"position_mm": [0.0, 150.0, 300.0]},
    "views": [
        {
            "name": "tilted",
            "position_mm": [90.0, -60.0, 120.0],
            "look_at_mm": [3.0, 2.0, 0.0],
            "up": [0.3, 1.0, 0.2],
            "fov_deg": 30.0,
            "resolution": [37, 23],
        }
    ],
}


@pytest.mark.parametrize("case", ["front", "tilted"])
@pytest.mark.parametrize("margin", [0.0, 0.4])
def test_pairs_equal_brute_force(case, margin, rng):
    if case == "front":
        design = make_design(resolution=40)
    else:
        design = design_from_mapping(TILTED, "<tilted>", Path("."))
    view = design.views[0]
    cam = Camera.from_view(view)
    quads, valid = cam.footprints()
    ok = valid.ravel()
    p0, p1, w = random_rects(rng, 300, 22.0)
    rects = scratch_rectangles(p0, p1, w, margin)
    pixel, scratch = raster_pairs(cam, rects, ok)
    got = set(zip(pixel.tolist(), scratch.tolist(), strict=True))
    assert len(got) == len(pixel)  # no duplicates
    want = brute_pairs(quads, ok, rects)
    assert len(want) > 500
    assert want <= got  # never misses a pair
    extra = np.array(sorted(got - want))
    if len(extra):
        # the only extras touch the rectangle up to the rasteriser's slack (in pixels)
        size = np.linalg.norm(np.diff(quads.reshape(-1, 4, 2)[ok], axis=1), axis=2).max()
        dist = distance_to_rect(quads, extra[:, 0], extra[:, 1], rects)
        assert np.all(dist < 3 * PIXEL_SLACK * size)
        assert len(extra) < 0.01 * len(want)


def test_margin_covers_moved_scratches(m, rng):
    """Pairs found with a margin stay complete while endpoints move by less than it."""
    design = make_design(resolution=48)
    vr = ViewRenderer(design, design.views[1], m)
    p0, p1, w = random_rects(rng, 400, 17.0, length=(1.0, 8.0))
    wide = vr.find_pairs(p0, p1, w, margin_mm=0.3)
    have = set(zip(wide.pixel_np.tolist(), wide.scratch_np.tolist(), strict=True))
    for _ in range(3):
        q0 = p0 + rng.uniform(-0.2, 0.2, p0.shape)
        q1 = p1 + rng.uniform(-0.2, 0.2, p1.shape)
        moved = vr.find_pairs(q0, q1, w)
        assert set(zip(moved.pixel_np.tolist(), moved.scratch_np.tolist(), strict=True)) <= have


def test_pairs_skip_pixels_off_the_board_and_behind_the_camera(rng):
    """A camera looking along the board sees part of it behind itself: still exact."""
    tables = {
        "board": {"width_mm": 40.0, "height_mm": 40.0, "margin_mm": 1.0},
        "light": {"position_mm": [0.0, 150.0, 300.0]},
        "views": [
            {
                "name": "grazing",
                "position_mm": [0.0, 0.0, 8.0],
                "look_at_mm": [60.0, 0.0, 0.0],
                "up": [0.0, 0.0, 1.0],
                "fov_deg": 60.0,
                "resolution": [30, 30],
            }
        ],
    }
    design = design_from_mapping(tables, "<grazing>", Path("."))
    cam = Camera.from_view(design.views[0])
    quads, valid = cam.footprints()
    assert not valid.all()  # the upper rows look at the sky
    ok = valid.ravel()
    p0, p1, w = random_rects(rng, 200, 19.0)
    rects = scratch_rectangles(p0, p1, w)
    behind = np.any(rects[..., 0] <= 0.0, axis=1) & np.any(rects[..., 0] > 0.0, axis=1)
    assert behind.sum() > 10  # some straddle the camera's own plane
    pixel, scratch = raster_pairs(cam, rects, ok)
    got = set(zip(pixel.tolist(), scratch.tolist(), strict=True))
    want = brute_pairs(np.where(valid[..., None, None], quads, 0.0), ok, rects)
    assert want <= got
    assert np.all(ok[pixel])


@pytest.mark.parametrize(("spacing", "strip_points"), [(16.0, 512), (2.0, 7), (0.0, 60)])
def test_neighbour_pairs_match_brute_force_at_the_edges(rng, spacing, strip_points):
    """Random and grazing layouts: pairs just inside and just outside the reach, all angles.

    Besides random scratches (lengths up to 30x the reach, so long ones are cut into
    pieces), each grazing pair puts a second scratch a distance of reach (1 +- 1e-7) from
    a first one, side by side, end to end or at an angle near the parallel limit, which
    is where the bounds that thin the candidates are tight.
    """
    from scratchfab.optimize.loss import PARALLEL_LIMIT, neighbour_pairs

    reach, slack = 0.5, 0.05
    n = 300
    c = rng.uniform(-12, 12, (n, 2))
    ang = rng.uniform(0, np.pi, n)
    half = rng.uniform(0.0, 7.5, n)[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
    half[:5] = 0.0  # points
    p0, p1 = [c - half], [c + half]
    g = 200
    base = rng.uniform(-12, 12, (g, 2))
    a = rng.uniform(0, np.pi, g)
    u = np.stack([np.cos(a), np.sin(a)], 1)
    normal = np.stack([-u[:, 1], u[:, 0]], 1)
    length = rng.uniform(0.2, 8.0, g)[:, None]
    gap = reach * (1 + rng.choice([-1e-7, 1e-7], g))[:, None]
    kind = rng.integers(0, 3, g)[:, None]
    turn = (PARALLEL_LIMIT + slack) * rng.uniform(0.9, 1.1, g)
    v = np.stack([np.cos(a + turn), np.sin(a + turn)], 1)
    end = base + length * u
    # side by side: shifted along by up to the length; end to end: beyond p1; angled:
    # starting `gap` to the side of the first one's middle, leaving away from it
    start = np.where(
        kind == 0,
        base + gap * normal + rng.uniform(-1, 1, (g, 1)) * length * u,
        np.where(kind == 1, end + gap * u, base + 0.5 * length * u + gap * normal),
    )
    p0 += [base, start]
    p1 += [end, start + rng.uniform(0.2, 8.0, (g, 1)) * np.where(kind == 2, v, u)]
    p0, p1 = np.concatenate(p0), np.concatenate(p1)
    order = rng.permutation(len(p0))
    p0, p1 = p0[order], p1[order]
    i, j = neighbour_pairs(p0, p1, reach, slack, spacing=spacing, strip_points=strip_points)
    n = len(p0)
    assert np.all(np.diff(i * n + j) > 0)  # sorted by (i, j), no repeats
    want = brute_force(p0, p1, reach, slack)
    assert set(zip(i.tolist(), j.tolist(), strict=True)) == want
    assert len(want) > 150
