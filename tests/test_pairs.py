"""Pair finding against a brute-force scratches x pixels intersection test."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely
from conftest import make_design

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
