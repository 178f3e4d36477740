"""The optimizer's PNGs and verify's sweep GIF, checked by their pixels."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from PIL import Image, ImageSequence

from scratchfab.optimize.plots import (
    AXIS_RGB,
    GRID_RGB,
    LOSS_RGB,
    MIN_CELL_PX,
    OFF_BOARD_RGB,
    VIEW_RGB,
    linear_ticks,
    log_ticks,
    rho_axis_floor,
    save_loss_plot,
    save_side_by_side,
)
from scratchfab.verify.sweep import (
    FRAME_MS,
    GIF_MIN_WIDTH,
    HOLD_MS,
    frame_labels,
    gif_bytes,
    nearest_frames,
    sweep_path,
)


def pixels(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.int16)


def is_color(img: np.ndarray, rgb) -> np.ndarray:
    return np.all(img == np.asarray(rgb, dtype=np.int16), axis=2)


def runs(indices: np.ndarray) -> list[float]:
    """Centres of runs of consecutive integers."""
    if indices.size == 0:
        return []
    splits = np.flatnonzero(np.diff(indices) > 1) + 1
    return [float(r.mean()) for r in np.split(indices, splits)]


def grid_rows(img: np.ndarray, min_count: int = 300) -> list[float]:
    return runs(np.flatnonzero(is_color(img, GRID_RGB).sum(axis=1) >= min_count))


def grid_cols(img: np.ndarray, lo: int, hi: int) -> list[float]:
    band = is_color(img[lo:hi], GRID_RGB)
    return runs(np.flatnonzero(band.sum(axis=0) >= 0.5 * (hi - lo)))


def srgb8(v: np.ndarray) -> np.ndarray:
    v = np.clip(v, 0.0, 1.0)
    enc = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    return np.round(enc * 255)


@pytest.mark.parametrize(
    ("lo", "hi", "expected"),
    [
        (1e-3, 2.0, [1e-3, 1e-2, 1e-1, 1.0]),  # many decades: decades only
        (0.03, 0.13, [0.05, 0.1]),  # under a decade: 1, 2, 5
        (0.012, 0.9, [0.02, 0.05, 0.1, 0.2, 0.5]),  # two decade ticks are too few
        (0.031, 0.069, [0.04, 0.05, 0.06]),  # not even 1-2-5 twice: every multiple
        (0.031, 0.038, [0.032, 0.034, 0.036, 0.038]),  # no multiple twice: linear steps
        (0.0342, 0.0358, [0.0345, 0.035, 0.0355]),
        (0.035, 0.035, [0.035]),  # one value: labelled all the same
    ],
)
def test_log_ticks_are_decades_then_1_2_5_then_every_multiple(lo, hi, expected):
    assert log_ticks(math.log10(lo), math.log10(hi)) == pytest.approx(expected)


def test_linear_ticks_are_round_steps_inside_the_range():
    assert linear_ticks(0.0, 120.0) == pytest.approx([0, 20, 40, 60, 80, 100, 120])
    assert linear_ticks(0.0, 1.0, 5) == pytest.approx([0, 0.2, 0.4, 0.6, 0.8, 1.0])
    assert linear_ticks(3.0, 9.0) == pytest.approx([3, 4, 5, 6, 7, 8, 9])


def test_loss_curve_meets_each_decade_gridline_at_the_iteration_it_reaches_that_loss(tmp_path):
    it = np.arange(0, 101, dtype=np.float64)
    loss = 10.0 ** (-it / 40)  # 1 at 0, 0.1 at 40, 0.01 at 80, 10^-2.5 at 100
    save_loss_plot(tmp_path / "loss.png", it, loss)
    img = pixels(tmp_path / "loss.png")
    rows = grid_rows(img)
    assert len(rows) == 3  # the decades 1, 0.1 and 0.01 inside 10^-2.5..1
    top, mid, bottom = rows
    assert mid - top == pytest.approx(bottom - mid, abs=1.5)  # equal space per decade
    px_per_decade = (bottom - top) / 2
    cols = grid_cols(img, int(top), int(bottom))
    assert len(cols) == 4  # 20, 40, 60, 80 (0 and 100 lie on the frame)
    px_per_iter = (cols[-1] - cols[0]) / 60
    curve = is_color(img, LOSS_RGB)
    for k, col in enumerate(cols):
        iteration = 20 * (k + 1)
        expect = top + (iteration / 40) * px_per_decade  # log10(loss) = -iteration / 40
        hit = np.flatnonzero(curve[:, round(col)])
        assert hit.size and abs(hit.mean() - expect) <= 2.0, (iteration, hit, expect)
    # The curve starts on the left edge at loss 1's row and ends on the right edge.
    left = cols[0] - 20 * px_per_iter
    right = cols[-1] + 20 * px_per_iter
    assert abs(np.flatnonzero(curve[:, round(left) + 1]).mean() - top) <= 2.5
    assert (
        abs(np.flatnonzero(curve[:, round(right) - 1]).mean() - (top + 2.5 * px_per_decade)) <= 2.5
    )
    # A title and tick labels in a readable size: dark glyph rows over 10 px tall.
    dark = np.all(img < 90, axis=2)
    title_rows = np.flatnonzero(dark[: int(top) - 5, int(left) + 2 :].any(axis=1))
    assert title_rows.size and title_rows.max() - title_rows.min() >= 10
    label = dark[int(top) - 12 : int(top) + 12, : int(left) - 5]
    assert label.any(axis=1).sum() >= 8


def test_quality_panel_draws_each_views_rho_on_a_0_to_1_axis_with_a_key(tmp_path):
    it = np.arange(0, 61, dtype=np.float64)
    rho = {"sun": it / 60, "house": np.full(it.shape, 0.25)}
    save_loss_plot(tmp_path / "loss.png", it, 1.0 / (1 + it), rho)
    img = pixels(tmp_path / "loss.png")
    rows = grid_rows(img)
    # Loss 1/61..1 (1.8 decades): 1-2-5 ticks; then rho 0.2, 0.4, 0.6, 0.8.
    loss_ticks = [v for v in (0.02, 0.05, 0.1, 0.2, 0.5, 1.0) if 1 / 61 <= v <= 1]
    assert len(rows) == len(loss_ticks) + 4
    r02, r04, r06, r08 = rows[-4:][::-1]
    step = r04 - r02
    assert r06 - r04 == pytest.approx(step, abs=1.5) and r08 - r06 == pytest.approx(step, abs=1.5)
    cols = grid_cols(img, int(r08), int(r02))
    assert len(cols) == 5  # 10 .. 50
    sun = is_color(img, VIEW_RGB[0])
    house = is_color(img, VIEW_RGB[1])
    for k, col in enumerate(cols):
        rho_sun = (10 * (k + 1)) / 60
        expect = r02 + (rho_sun - 0.2) / 0.2 * step
        hit = np.flatnonzero(sun[:, round(col)])
        assert hit.size and abs(hit.mean() - expect) <= 2.0, (k, hit, expect)
    house_rows = np.flatnonzero(house[:, round(cols[0])])
    assert abs(house_rows.mean() - (r02 + 0.25 * step)) <= 2.0
    # The key: a swatch of each colour off its curve's rows, with dark text beside it.
    for color, curve_rows in ((VIEW_RGB[0], None), (VIEW_RGB[1], r02 + 0.25 * step)):
        wide = np.flatnonzero(is_color(img, color).sum(axis=1) >= 15)
        if curve_rows is not None:
            wide = wide[np.abs(wide - curve_rows) > 4]
        assert wide.size, color
        row = np.flatnonzero(is_color(img, color)[wide[0]])
        ends = np.flatnonzero(np.diff(np.append(row, row[-1] + 2)) > 1)
        starts = np.concatenate([[0], ends[:-1] + 1])
        longest = int(np.argmax(ends - starts))
        assert ends[longest] - starts[longest] >= 14  # a swatch, not a curve crossing
        x1 = int(row[ends[longest]])
        text = np.all(img[wide.min() - 4 : wide.max() + 5, x1 + 1 : x1 + 80] < 90, axis=2)
        assert text.sum() > 20, color


@pytest.mark.parametrize(
    ("lows", "floor"),
    [((0.0, 0.3), 0.0), ((0.93, -0.2), 0.0), ((0.55, 0.9), 0.5), ((0.85, 0.99), 0.8),
     ((0.93, 0.95), 0.9), ((0.999, 1.0), 0.9), ((float("nan"), 0.95), 0.9), ((), 0.0),
     ((0.9, 0.95), 0.8), ((0.5,), 0.0)],  # a curve never on the frame's bottom edge
)  # fmt: skip
def test_the_rho_axis_starts_at_the_highest_floor_under_every_view(lows, floor):
    views = {f"v{k}": [low, np.nan, 1.0] for k, low in enumerate(lows)}
    assert rho_axis_floor(views) == floor


def test_a_run_near_1_is_drawn_on_an_axis_from_0_9_not_flat_at_the_top(tmp_path):
    """Rho between 0.93 and 0.99 used the panel's top tenth; from 0.9, gridlines every 0.02
    and a value of 0.95 halfway between those of 0.94 and 0.96."""
    it = np.arange(0, 61, dtype=np.float64)
    save_loss_plot(tmp_path / "loss.png", it, 1.0 / (1 + it), {"sun": np.full(it.shape, 0.95)})
    img = pixels(tmp_path / "loss.png")
    panel = img.shape[0] // 2
    rows = [r for r in grid_rows(img) if r > panel]
    assert len(rows) == 4  # 0.92, 0.94, 0.96, 0.98 (0.9 and 1 are the frame)
    r098, r096, r094, r092 = rows
    step = r094 - r096
    assert r092 - r094 == pytest.approx(step, abs=1.5) and r096 - r098 == pytest.approx(
        step, abs=1.5
    )
    cols = grid_cols(img, int(r098), int(r092))
    curve = np.flatnonzero(is_color(img, VIEW_RGB[0])[:, round(cols[0])])
    assert curve.size and abs(curve.mean() - (r094 + r096) / 2) <= 2.0


def test_side_by_side_shows_off_board_in_the_documented_grey_and_explains_it(tmp_path):
    target = np.full((20, 30), np.nan)
    target[4:16, 5:25] = np.linspace(0.0, 1.0, 20)[None, :]
    render = np.where(np.isfinite(target), 2.0 * target, 0.3)  # twice as bright: exposure 1/2
    save_side_by_side(tmp_path / "sbs.png", {"v": target}, {"v": render})
    img = pixels(tmp_path / "sbs.png")
    factor = math.ceil(MIN_CELL_PX / 30)
    grey = is_color(img, OFF_BOARD_RGB)
    off = int(np.isnan(target).sum())
    swatch = grey.sum() - 2 * off * factor**2
    assert 0 < swatch < 400  # the caption's swatch, besides both cells' off-board pixels
    assert not is_color(img, (16, 24, 64)).any()
    # Each cell is the target enlarged by a whole factor; the render, exposed, equals it.
    expect = np.where(np.isfinite(target), srgb8(np.nan_to_num(target)), OFF_BOARD_RGB[0])
    expect = np.kron(expect, np.ones((factor, factor)))
    cells = []
    g = img[..., 1]
    for x0 in range(img.shape[1] - expect.shape[1] + 1):
        for y0 in range(img.shape[0] - expect.shape[0] + 1):
            if grey[y0, x0] and np.array_equal(
                g[y0 : y0 + expect.shape[0], x0 : x0 + expect.shape[1]], expect
            ):
                cells.append((x0, y0))
    assert len(cells) == 2 and cells[0][1] == cells[1][1]
    # Caption text under the cells: dark pixels in rows below them.
    bottom = cells[0][1] + expect.shape[0]
    assert (img[bottom:, :, :].max(axis=2) < 120).sum() > 50


def frame_pictures(gif: Image.Image, shape: tuple[int, int]) -> tuple[list[np.ndarray], int]:
    """The pictures of a labelled GIF, shrunk back by its whole enlargement factor."""
    factor = gif.width // shape[1]
    out = []
    for frame in ImageSequence.Iterator(gif):
        a = np.asarray(frame.convert("L"), dtype=np.int16)
        out.append(a[: shape[0] * factor : factor, ::factor])
    return out, factor


def test_gif_plays_forward_then_back_enlarged_labelled_and_holding_design_views():
    n, shape = 5, (12, 16)
    images = [np.full(shape, (k + 1) / 6.0) for k in range(n)]
    images[0][0, 0] = 1.0  # white point: the 99.5th percentile is then 5/6
    labels = [f"frame {k}" for k in range(n)]
    gif = Image.open(io.BytesIO(gif_bytes(images, labels, {1, 4})))
    assert gif.n_frames == 2 * n - 2
    assert gif.width >= GIF_MIN_WIDTH and gif.width % shape[1] == 0
    factor = gif.width // shape[1]
    assert gif.info["loop"] == 0
    shown, _ = frame_pictures(gif, shape)
    levels = [srgb8(np.full(1, min((k + 1) / 6.0 / (5 / 6), 1.0)))[0] for k in range(n)]
    order = [int(np.argmin([abs(p[5, 5] - lv) for lv in levels])) for p in shown]
    assert order == [0, 1, 2, 3, 4, 3, 2, 1]
    durations = [f.info["duration"] for f in ImageSequence.Iterator(gif)]
    assert durations == [HOLD_MS if k in (1, 4) else FRAME_MS for k in order]
    assert HOLD_MS > FRAME_MS
    for frame in ImageSequence.Iterator(gif):
        a = np.asarray(frame.convert("L"), dtype=np.int16)
        pic = a[: shape[0] * factor]
        assert (pic == np.kron(pic[::factor, ::factor], np.ones((factor, factor)))).all()
        strip = a[shape[0] * factor :]
        assert strip.shape[0] >= 14 and (strip < 80).sum() > 30  # dark text in a light strip
        assert np.median(strip) > 200


def test_sweep_labels_name_the_azimuth_and_the_nearest_design_view(small_design):
    frames, view_params = sweep_path(small_design, 9)
    nearest = nearest_frames(frames, view_params)
    labels = frame_labels(frames, nearest)
    for k, (frame, label) in enumerate(zip(frames, labels, strict=True)):
        x, _, z = frame.view.position_mm
        az = round(math.degrees(math.atan2(x, z)))
        assert label.startswith(f"azimuth {az:+d}\u00b0")
        named = [name for name, i in nearest.items() if i == k]
        assert ("view: " in label) == bool(named)
        for name in named:
            assert name in label.split("\n")[1]


@pytest.mark.parametrize(
    ("iterations", "losses"),
    [([0], [0.37]), ([], []), ([0, 1, 2], [math.nan, 0.0, -1.0]), ([5, 6], [0.2, 0.2])],
)
def test_loss_plot_of_few_or_no_usable_rows_still_draws_framed_axes(tmp_path, iterations, losses):
    save_loss_plot(tmp_path / "loss.png", iterations, losses, {"v": [0.5] * len(iterations)})
    img = pixels(tmp_path / "loss.png")
    frame = is_color(img, (0, 0, 0))
    assert (frame.sum(axis=1) > 500).sum() >= 4  # both panels' top and bottom edges
    finite = [v for v in losses if v > 0]
    assert is_color(img, LOSS_RGB).any() == bool(finite)


@pytest.mark.parametrize("n", [2, 3, 5, 6])
def test_every_view_stays_visible_where_the_rho_curves_coincide(tmp_path, n):
    """Identical rho curves: each view's colour still shows along the shared line."""
    it = np.arange(0, 201, dtype=np.float64)
    shared = 0.2 + 0.6 * it / 200  # a diagonal, away from the key's corners
    rho = {f"v{k}": shared.copy() for k in range(n)}
    save_loss_plot(tmp_path / "loss.png", it, 1.0 / (1 + it), rho)
    img = pixels(tmp_path / "loss.png")
    height = img.shape[0]
    panel = img[height // 2 :]
    # Pixels on the curve: near the line fitted through the coloured pixels, leaving out
    # the rows of the key's swatches (horizontal runs the diagonal curve does not make).
    drawn = np.zeros(panel.shape[:2], bool)
    for k in range(n):
        drawn |= is_color(panel, VIEW_RGB[k])
    drawn[drawn.sum(axis=1) >= 15] = False
    ys, xs = np.nonzero(drawn)
    slope, icpt = np.polyfit(xs, ys, 1)
    on_line = np.abs(ys - (slope * xs + icpt)) <= 3
    assert on_line.sum() >= 0.9 * len(ys) >= 600  # the fit is the curve
    total = on_line.sum()
    for k in range(n):
        mine = is_color(panel, VIEW_RGB[k])[ys[on_line], xs[on_line]].sum()
        assert mine >= 0.5 * total / n, (k, mine, total)
    assert AXIS_RGB not in VIEW_RGB[:n]  # a curve in the frame's colour would read as the frame


def test_side_by_side_is_wide_enough_for_a_long_view_name(tmp_path):
    """A row's title (view name and rho) ends before the picture's right edge."""
    target = np.linspace(0.0, 1.0, 16 * 16).reshape(16, 16)
    name = "a_rather_long_view_name_from_its_file"
    save_side_by_side(tmp_path / "sbs.png", {name: target}, {name: target})
    img = pixels(tmp_path / "sbs.png")
    title = img[: MIN_CELL_PX // 8]  # the first row's title band, above its cells
    ink = np.flatnonzero((title.min(axis=-1) < 200).any(axis=0))
    assert ink.size and ink.max() < img.shape[1] - 4, (ink.max(), img.shape[1])
