from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import make_design
from PIL import Image
from shapely.geometry import Polygon, box

from scratchfab.design.images import linear_to_srgb
from scratchfab.design.targets import (
    board_image,
    cross_targets,
    fit_to_board,
    view_targets,
    warp_to_view,
)
from scratchfab.errors import ConfigError
from scratchfab.model.camera import Camera
from scratchfab.model.design import Board, design_from_mapping


def _save_linear(path: Path, lin: np.ndarray) -> Path:
    codes = np.round(linear_to_srgb(lin) * 65535).astype(np.uint16)
    Image.fromarray(codes).save(path)
    return path


def _front_design(resolution=(48, 40), board=(40.0, 30.0), fov="auto", target=None):
    view = {
        "name": "front",
        "position_mm": [6.0, -4.0, 250.0],
        "fov_deg": fov,
        "resolution": list(resolution),
    }
    if target is not None:
        view["target"] = str(target)
    tables = {
        "board": {"width_mm": board[0], "height_mm": board[1]},
        "light": {"position_mm": [0.0, 100.0, 300.0]},
        "views": [view],
    }
    return design_from_mapping(tables, "<test>", Path("."))


def test_board_image_orientation_top_is_plus_y_left_is_minus_x(tmp_path):
    pic = np.zeros((64, 64))
    pic[:32, :32] = 1.0  # the picture's top-left quadrant
    path = _save_linear(tmp_path / "q.png", pic)
    board = Board(width_mm=40.0, height_mm=40.0)
    img = board_image(path, board)
    design = _front_design(board=(40.0, 40.0), target=path)
    warped = warp_to_view(img, board, design.views[0])
    centres, _ = Camera.from_view(design.views[0]).center_grid()
    x, y = centres[..., 0], centres[..., 1]
    inner = (np.abs(x) < 18) & (np.abs(y) < 18) & (np.abs(x) > 2) & (np.abs(y) > 2)
    top_left = inner & (x < 0) & (y > 0)
    assert np.all(warped[top_left] > 0.99)
    assert np.all(warped[inner & ~top_left] < 0.01)


def test_fit_contain_pads_and_cover_crops():
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    wide = np.ones((50, 100))
    contain = fit_to_board(wide, board, "contain")
    rows, cols = contain.shape
    assert rows == cols
    # Black bars above and below the picture, which spans the full width.
    assert np.all(contain[: rows // 4 - 2] == 0) and np.all(contain[-(rows // 4 - 2) :] == 0)
    assert np.allclose(contain[rows // 2], 1.0)
    cover = fit_to_board(wide, board, "cover")
    assert np.allclose(cover, 1.0)
    # Cover keeps the centre of a picture whose left and right thirds differ.
    three = np.zeros((50, 150))
    three[:, 50:100] = 1.0
    cropped = fit_to_board(three, board, "cover")
    assert cropped[:, 3:-3].min() > 0.99
    with pytest.raises(ConfigError, match="fit must be one of contain, cover"):
        fit_to_board(wide, board, "stretch")


def test_gamma_and_contrast(tmp_path):
    ramp = np.tile(np.linspace(0, 1, 256), (256, 1))  # native size: no resampling
    path = _save_linear(tmp_path / "ramp.png", ramp)
    board = Board(width_mm=10.0, height_mm=10.0, margin_mm=1.0)
    base = board_image(path, board)
    np.testing.assert_allclose(board_image(path, board, gamma=2.0), base**2, atol=1e-6)
    flat = board_image(path, board, contrast=0.0)
    assert np.ptp(flat) < 1e-9 and flat.mean() == pytest.approx(base.mean(), abs=1e-6)
    with pytest.raises(ConfigError, match="gamma"):
        board_image(path, board, gamma=0.0)


def _polygon_centroid(quad: np.ndarray) -> np.ndarray:
    x, y = quad[:, 0], quad[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6 * area)


def test_warp_is_the_area_average_over_each_footprint():
    # A linear board image f(x, y) averages over a polygon to f at the polygon's centroid;
    # bilinear sampling reproduces a linear function exactly away from the border texels.
    board = Board(width_mm=40.0, height_mm=30.0)
    rows, cols = 300, 400
    x = -20 + (np.arange(cols) + 0.5) * 40 / cols
    y = 15 - (np.arange(rows) + 0.5) * 30 / rows
    a, bx, by = 0.4, 0.011, -0.007
    img = a + bx * x[None, :] + by * y[:, None]
    design = _front_design(resolution=(24, 20), board=(40.0, 30.0), fov=5.0)
    view = design.views[0]
    warped = warp_to_view(img, board, view)
    quads, valid = Camera.from_view(view).footprints()
    checked = 0
    for j in range(view.height):
        for i in range(view.width):
            q = quads[j, i]
            if not valid[j, i] or np.abs(q[:, 0]).max() > 19.5 or np.abs(q[:, 1]).max() > 14.5:
                continue
            cx, cy = _polygon_centroid(q)
            assert warped[j, i] == pytest.approx(a + bx * cx + by * cy, abs=2e-6)
            checked += 1
    assert checked > 300


def test_nan_exactly_where_the_pixel_centre_misses_the_board(tmp_path):
    board = Board(width_mm=40.0, height_mm=30.0)
    design = _front_design(resolution=(40, 40), board=(40.0, 30.0), fov=12.3)
    view = design.views[0]
    warped = warp_to_view(np.ones((30, 40)), board, view)
    # Independent ray-plane intersection of each pixel centre (SPEC section 2).
    pos = np.array(view.position_mm)
    f = -pos / np.linalg.norm(pos)
    r = np.cross(f, [0, 1, 0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    ty = np.tan(np.radians(view.fov) / 2)
    tx = ty * view.width / view.height
    jj, ii = np.mgrid[0 : view.height, 0 : view.width] + 0.5
    d = (
        f
        + ((2 * ii / view.width - 1) * tx)[..., None] * r
        + ((1 - 2 * jj / view.height) * ty)[..., None] * u
    )
    hit = pos[:2] + (-pos[2] / d[..., 2])[..., None] * d[..., :2]
    on = (np.abs(hit[..., 0]) <= 20) & (np.abs(hit[..., 1]) <= 15)
    assert np.array_equal(np.isfinite(warped), on)
    assert (~on).sum() > 100 and on.sum() > 100
    # Inside, a white board reads white; pixels straddling the edge are dimmed by the
    # share of their footprint on the board (exact polygon clipping by shapely).
    assert np.nanmax(warped) == pytest.approx(1.0)
    quads, _ = Camera.from_view(view).footprints()
    rect = box(-20, -15, 20, 15)
    straddling = 0
    for j, i in zip(*np.nonzero(on), strict=True):
        poly = Polygon(quads[j, i])
        share = poly.intersection(rect).area / poly.area
        if share < 0.999:
            straddling += 1
            assert warped[j, i] == pytest.approx(share, abs=0.1)
    assert straddling > 20


def test_view_and_cross_targets(tmp_path):
    a = np.zeros((32, 32))
    a[:, :16] = 1.0
    b = np.zeros((32, 32))
    b[:16, :] = 1.0
    pa = _save_linear(tmp_path / "a.png", a)
    pb = _save_linear(tmp_path / "b.png", b)
    design = make_design(resolution=24)
    views = tuple(
        v.__class__(**{**v.__dict__, "target": str(p)})
        for v, p in zip(design.views, (pa, pb), strict=True)
    )
    design = design.with_views(views)
    targets = view_targets(design)
    cross = cross_targets(design)
    assert set(targets) == {"left", "right"}
    assert set(cross) == {
        ("left", "left"),
        ("left", "right"),
        ("right", "left"),
        ("right", "right"),
    }
    np.testing.assert_array_equal(cross[("left", "left")], targets["left"])
    np.testing.assert_array_equal(cross[("right", "right")], targets["right"])
    expected = warp_to_view(board_image(pb, design.board), design.board, design.view("left"))
    np.testing.assert_array_equal(cross[("left", "right")], expected)
    assert not np.allclose(np.nan_to_num(cross[("left", "right")]), np.nan_to_num(targets["left"]))
