"""raster_pairs (compiled scan) against the numpy version it replaced.

The optimizer and renderer depend on the pairs' order for bit-identical results, so the
compiled scan must give the same pairs in the same order, on real cameras and on corners
placed on the rasteriser's boundaries: pixel edges, the slack around them, edges a hair
from flat, non-finite and huge coordinates. ``numpy_raster_pairs`` is the numpy version,
kept here to compare (tests/test_pairs.py compares both with brute force).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import make_design
from test_pairs import TILTED, random_rects

from scratchfab.model.camera import Camera
from scratchfab.model.design import design_from_mapping
from scratchfab.render.pairs import PIXEL_SLACK, raster_pairs, scratch_rectangles

CHUNK = 16384


def _row_spans(q: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column extent (s_min, s_max) of convex quads q (R, 4, 2) within strips [row, row + 1]."""
    lo = rows - PIXEL_SLACK
    hi = rows + 1 + PIXEL_SLACK
    s_min = np.full(len(rows), np.inf)
    s_max = np.full(len(rows), -np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for e in range(4):
            sa, ta = q[:, e, 0], q[:, e, 1]
            sb, tb = q[:, (e + 1) % 4, 0], q[:, (e + 1) % 4, 1]
            dt = tb - ta
            flat = np.abs(dt) < 1e-12
            u1 = (lo - ta) / np.where(flat, 1.0, dt)
            u2 = (hi - ta) / np.where(flat, 1.0, dt)
            ulo = np.maximum(0.0, np.minimum(u1, u2))
            uhi = np.minimum(1.0, np.maximum(u1, u2))
            ulo = np.where(flat, 0.0, ulo)
            uhi = np.where(flat, 1.0, uhi)
            ok = np.where(flat, (ta >= lo) & (ta <= hi), ulo <= uhi)
            s1 = sa + ulo * (sb - sa)
            s2 = sa + uhi * (sb - sa)
            s_min = np.where(ok, np.minimum(s_min, np.minimum(s1, s2)), s_min)
            s_max = np.where(ok, np.maximum(s_max, np.maximum(s1, s2)), s_max)
    return s_min, s_max


def _runs(base: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``base[k] + 0 .. base[k] + count[k] - 1`` for every k, laid end to end."""
    starts = np.cumsum(count) - count
    offset = base - starts
    total = int(count.sum())
    small = total < 2**31 and (len(offset) == 0 or int(np.abs(offset).max()) < 2**31 - total)
    dtype = np.int32 if small else np.int64
    return np.repeat(offset.astype(dtype), count) + np.arange(total, dtype=dtype)


def numpy_raster_pairs(
    camera: Camera, corners: np.ndarray, pixel_ok: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The version before the compiled scan (vectorised per chunk of scratches)."""
    W, H = camera.width, camera.height
    pix_out: list[np.ndarray] = []
    sid_out: list[np.ndarray] = []
    for start in range(0, len(corners), CHUNK):
        quad = corners[start : start + CHUNK]
        n = len(quad)
        pts = np.concatenate([quad, np.zeros((n, 4, 1))], axis=2)
        st, front = camera.project(pts)
        whole = ~np.all(front, axis=1) | ~np.all(np.isfinite(st), axis=(1, 2))
        st = np.where(whole[:, None, None], 0.0, st)
        t_min = np.where(whole, 0.0, st[:, :, 1].min(axis=1) - PIXEL_SLACK)
        t_max = np.where(whole, H - 1.0, st[:, :, 1].max(axis=1) + PIXEL_SLACK)
        j0 = np.clip(np.floor(t_min), 0, H).astype(np.int64)
        j1 = np.clip(np.floor(t_max), -1, H - 1).astype(np.int64)
        row_count = np.maximum(0, j1 - j0 + 1)
        owner = np.repeat(np.arange(n, dtype=np.int32), row_count)
        rows = _runs(j0, row_count)
        s_min, s_max = _row_spans(st[owner], rows.astype(np.float64))
        s_min = np.where(whole[owner], 0.0, s_min - PIXEL_SLACK)
        s_max = np.where(whole[owner], W - 1.0, s_max + PIXEL_SLACK)
        empty = ~(s_min <= s_max)
        i0 = np.clip(np.floor(np.where(empty, 0.0, s_min)), 0, W).astype(np.int64)
        i1 = np.clip(np.floor(np.where(empty, -1.0, s_max)), -1, W - 1).astype(np.int64)
        col_count = np.maximum(0, i1 - i0 + 1)
        pixel = _runs(rows.astype(np.int64) * W + i0, col_count)
        keep = pixel_ok[pixel]
        scratch = np.repeat((owner + start).astype(np.uint32), col_count)
        pix_out.append(pixel[keep].astype(np.uint32))
        sid_out.append(scratch[keep])
    if not pix_out:
        return np.zeros(0, np.uint32), np.zeros(0, np.uint32)
    return np.concatenate(pix_out), np.concatenate(sid_out)


def assert_same_pairs(camera: Camera, corners: np.ndarray, ok: np.ndarray) -> int:
    """Both versions give the same uint32 pairs in the same order; returns how many."""
    pixel, scratch = raster_pairs(camera, corners, ok)
    want_pixel, want_scratch = numpy_raster_pairs(camera, corners, ok)
    assert pixel.dtype == scratch.dtype == np.uint32
    np.testing.assert_array_equal(pixel, want_pixel)
    np.testing.assert_array_equal(scratch, want_scratch)
    return len(pixel)


class ImagePlane(Camera):
    """The board plane taken as the image plane: board (x, y) mm are image (s, t) pixels.

    Corners then land exactly where a test puts them in the image, on the rasteriser's
    boundaries; ``behind`` marks scratches whose corners count as behind the camera.
    """

    behind: np.ndarray | None = None

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s, t) = (x, y), in front unless ``behind`` says otherwise."""
        points = np.asarray(points, dtype=np.float64)
        front = np.ones(points.shape[:-1], bool)
        if self.behind is not None:
            front[self.behind, 1] = False
        return points[..., :2].copy(), front


def image_plane(width: int, height: int, behind: np.ndarray | None = None) -> ImagePlane:
    e = np.eye(3)
    cam = ImagePlane(e[0], e[2], e[0], e[1], 1.0, 1.0, width, height)
    object.__setattr__(cam, "behind", behind)
    return cam


def edge_values(size: int, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` coordinates on and a rounding away from pixel edges and their slack."""
    k = rng.integers(-2, size + 3, n).astype(np.float64)
    kind = rng.integers(0, 9, n)
    v = np.select(
        [kind == 0, kind == 1, kind == 2, kind == 3, kind == 4, kind == 5, kind == 6],
        [
            k,
            k - PIXEL_SLACK,
            k + 1 + PIXEL_SLACK,
            k + PIXEL_SLACK,  # an edge's s_min - slack lands on k
            k - 1 - PIXEL_SLACK,
            k + 0.5,
            k + rng.uniform(0, 1, n),
        ],
        k - 2 * PIXEL_SLACK,
    )
    step = rng.choice([-np.inf, 0.0, 0.0, np.inf], n)
    return np.nextafter(v, step)


def test_random_layouts_on_real_cameras(rng):
    """Random scratches, thin to long, some off the board, front and tilted cameras."""
    cameras = [Camera.from_view(v) for v in make_design(views=3, resolution=41).views]
    cameras.append(Camera.from_view(design_from_mapping(TILTED, "<tilted>", Path(".")).views[0]))
    total = 0
    for cam in cameras:
        _, valid = cam.footprints()
        ok = valid.ravel()
        for margin in (0.0, 0.35):
            p0, p1, w = random_rects(rng, 700, 26.0, length=(0.0, 20.0))
            total += assert_same_pairs(cam, scratch_rectangles(p0, p1, w, margin), ok)
    assert total > 50_000


def test_more_scratches_than_a_chunk_of_the_numpy_version(rng):
    """Scratch indices past the numpy version's chunk of 16384 keep their order."""
    cam = Camera.from_view(make_design(views=1, resolution=24).views[0])
    p0, p1, w = random_rects(rng, CHUNK + 2000, 21.0, length=(0.0, 3.0))
    ok = np.ones(cam.width * cam.height, bool)
    assert assert_same_pairs(cam, scratch_rectangles(p0, p1, w, 0.1), ok) > CHUNK


def test_degenerate_scratches(rng):
    """Zero-length, zero-width and point scratches, and all of them in one place."""
    cam = Camera.from_view(make_design(views=2, resolution=37).views[1])
    ok = cam.footprints()[1].ravel()
    n = 400
    c = rng.uniform(-18, 18, (n, 2))
    d = rng.uniform(-3, 3, (n, 2))
    d[: n // 2] = 0.0  # zero length
    w = rng.uniform(0.0, 0.3, n)
    w[n // 4 : 3 * n // 4] = 0.0  # zero width (with and without length)
    for margin in (0.0, 0.2):
        assert assert_same_pairs(cam, scratch_rectangles(c, c + d, w, margin), ok) > 0
    same = np.repeat(c[:1], 50, axis=0)  # fifty identical points
    assert_same_pairs(cam, scratch_rectangles(same, same, 0.0), ok)


def test_rectangles_on_pixel_edges_of_a_real_camera(rng):
    """Quads whose corners are the board points of pixel corners (and of the slack)."""
    cam = Camera.from_view(make_design(views=3, resolution=29).views[2])
    W, H = cam.width, cam.height
    n = 600
    s = rng.integers(-1, W + 2, (n, 2)).astype(np.float64)
    t = rng.integers(-1, H + 2, (n, 2)).astype(np.float64)
    shift = rng.choice([0.0, PIXEL_SLACK, -PIXEL_SLACK, 1e-9, -1e-9], (n, 1))
    s, t = np.sort(s, axis=1) + shift, np.sort(t, axis=1) - shift
    quad_s = np.stack([s[:, 0], s[:, 1], s[:, 1], s[:, 0]], axis=1)
    quad_t = np.stack([t[:, 0], t[:, 0], t[:, 1], t[:, 1]], axis=1)
    corners, valid = cam.board_hits(quad_s, quad_t)
    assert valid.all()
    ok = cam.footprints()[1].ravel()
    assert assert_same_pairs(cam, corners, ok) > 1000


def test_corners_on_the_rasteriser_boundaries(rng):
    """Corners on pixel edges, the slack around them and one ulp either side."""
    for width, height in [(9, 7), (1, 1), (16, 3)]:
        cam = image_plane(width, height)
        n = 3000
        s = edge_values(width, rng, 4 * n).reshape(n, 4)
        t = edge_values(height, rng, 4 * n).reshape(n, 4)
        corners = np.stack([s, t], axis=2)
        # axis-aligned boxes too: every edge exactly flat or exactly upright
        boxes = np.stack([s[:, [0, 1, 1, 0]], t[:, [0, 0, 1, 1]]], axis=2)
        ok = rng.random(width * height) < 0.8
        assert assert_same_pairs(cam, np.concatenate([corners, boxes]), ok) > 1000


def test_edges_a_hair_from_flat(rng):
    """Edges whose rise is about the flatness threshold 1e-12, at strip boundaries."""
    cam = image_plane(12, 10)
    n = 2000
    corners = np.stack(
        [rng.uniform(-2, 14, (n, 4)), np.repeat(edge_values(10, rng, n)[:, None], 4, 1)], axis=2
    )
    rise = rng.choice([1e-12, -1e-12, 0.999e-12, 1.001e-12, 5e-13, 0.0, 1e-9], (n, 4))
    corners[:, :, 1] += np.cumsum(rise, axis=1)
    corners[:, 2:, 1] += rng.choice([0.0, 1.0, 2.0 + 2 * PIXEL_SLACK], (n, 1))
    assert assert_same_pairs(cam, corners, np.ones(120, bool)) > 1000


def test_slivers_across_strip_boundaries_at_the_flatness_threshold():
    """Edges rising the nearest float steps below and above 1e-12 across a strip's bound.

    Flat edges (rise < 1e-12) count whole when they start in the strip, others are cut
    at its bound, which in these slivers (both long edges from s = 0 to s = 10) decides
    the row's span. (A rise of exactly 1e-12 only occurs near t = 0, inside row 0's
    strip, where both readings give the same span.)
    """
    cam = image_plane(12, 5)
    quads = []
    for j in range(5):
        for bound, sign in ((j + 1 + PIXEL_SLACK, 1.0), (j - PIXEL_SLACK, -1.0)):
            ulp = np.spacing(bound)
            for f in np.linspace(0.05, 0.95, 20):
                ta = bound - sign * f * 1e-12
                for k in range(-3, 4):
                    tb = ta + sign * (np.floor(1e-12 / ulp) + k) * ulp
                    quads.append([[0.0, ta], [10.0, tb], [10.0, tb], [0.0, ta]])
    corners = np.array(quads)
    rise = np.abs(corners[:, 1, 1] - corners[:, 0, 1])
    assert (rise < 1e-12).sum() > 300
    assert (rise > 1e-12).sum() > 300
    assert assert_same_pairs(cam, corners, np.ones(60, bool)) > 1000


def test_overflowing_edges(rng):
    """Finite corners whose edges overflow (s from -1.7e308 to 1.7e308): NaN spans."""
    cam = image_plane(10, 8)
    n = 2000
    s = rng.choice([-1.7e308, -1e308, -5.0, 3.0, 3.5, 20.0, 1e308, 1.7e308], (n, 4))
    t = edge_values(8, rng, 4 * n).reshape(n, 4)
    corners = np.stack([s, t], axis=2)
    with np.errstate(over="ignore"):  # the numpy version's (sb - sa)
        assert assert_same_pairs(cam, corners, np.ones(80, bool)) > 1000


def test_non_finite_huge_and_behind_the_camera(rng):
    """NaN, infinite and overflowing corners, and corners behind the camera."""
    n = 600
    behind = rng.random(n) < 0.1
    cam = image_plane(8, 6, behind)
    corners = rng.uniform(-3, 11, (n, 4, 2))
    pick = rng.random((n, 4, 2))
    corners[pick < 0.03] = np.nan
    corners[(pick >= 0.03) & (pick < 0.06)] = np.inf
    huge = rng.choice([1e300, -1e300, 1.7e308, -1.7e308, 1e16, -1e16], (n, 4, 2))
    corners = np.where((pick >= 0.06) & (pick < 0.2), huge, corners)
    ok = rng.random(48) < 0.7
    with np.errstate(over="ignore"):  # the numpy version's (sb - sa) and the like
        assert assert_same_pairs(cam, corners, ok) > 1000


@pytest.mark.parametrize("mask", ["holes", "none", "all", "one"])
def test_pixel_ok_masks(rng, mask):
    """Pixels left out: random holes, every pixel, none, all but one."""
    cam = Camera.from_view(design_from_mapping(TILTED, "<tilted>", Path(".")).views[0])
    valid = cam.footprints()[1].ravel()
    ok = {
        "holes": valid & (rng.random(valid.size) < 0.6),
        "none": np.zeros(valid.size, bool),
        "all": np.ones(valid.size, bool),
        "one": valid & (np.arange(valid.size) != int(np.flatnonzero(valid)[valid.sum() // 2])),
    }[mask]
    p0, p1, w = random_rects(rng, 500, 22.0)
    found = assert_same_pairs(cam, scratch_rectangles(p0, p1, w, 0.2), ok)
    assert (found == 0) == (mask == "none")


@pytest.mark.parametrize("elevation", [0.5, 5.0, 89.9])
def test_grazing_cameras(rng, elevation):
    """Cameras low over the board and one at its edge, some scratches behind them."""
    rad = np.radians(elevation)
    position = [-60.0 * np.cos(rad), 0.0, 60.0 * np.sin(rad) + 0.5]
    tables = {
        "board": {"width_mm": 40.0, "height_mm": 40.0, "margin_mm": 1.0},
        "light": {"position_mm": [0.0, 150.0, 300.0]},
        "views": [
            {
                "name": "low",
                "position_mm": position,
                "look_at_mm": [0.0, 0.0, 0.0],
                "up": [0.0, 0.0, 1.0],
                "fov_deg": 60.0,
                "resolution": [33, 27],
            }
        ],
    }
    cam = Camera.from_view(design_from_mapping(tables, "<grazing>", Path(".")).views[0])
    ok = cam.footprints()[1].ravel()
    p0, p1, w = random_rects(rng, 300, 70.0)  # reaching past the camera
    assert assert_same_pairs(cam, scratch_rectangles(p0, p1, w, 0.1), ok) > 100


def test_empty_input():
    cam = Camera.from_view(make_design(views=1, resolution=8).views[0])
    for corners in (np.zeros((0, 4, 2)), np.zeros((0, 4, 2), np.float32)):
        pixel, scratch = raster_pairs(cam, corners, np.ones(64, bool))
        assert pixel.dtype == scratch.dtype == np.uint32
        assert len(pixel) == len(scratch) == 0


def test_importing_the_renderer_does_not_load_numba():
    """numba loads on the first pair search, not when the package is imported."""
    code = "import sys, scratchfab.render.pairs; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
