from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image, ImageDraw

from scratchfab import figures
from scratchfab.figures import LegendItem


def _rgb(img: Image.Image) -> np.ndarray:
    return np.asarray(img.convert("RGB")).astype(int)


def _has(rgb: np.ndarray, color: tuple[int, int, int]) -> bool:
    return bool(np.any(np.all(rgb == np.array(color), axis=-1)))


def test_pad_keeps_the_picture_at_its_offset(rng):
    src = rng.integers(0, 256, size=(7, 11, 3), dtype=np.uint8)
    out = figures.pad(Image.fromarray(src), (3, 5, 2, 4), fill=(1, 2, 3))
    arr = np.asarray(out)
    assert arr.shape == (7 + 5 + 4, 11 + 3 + 2, 3)
    assert np.array_equal(arr[5:12, 3:14], src)
    border = np.ones(arr.shape[:2], bool)
    border[5:12, 3:14] = False
    assert np.all(arr[border] == (1, 2, 3))


def test_text_grows_with_size_and_length():
    w1, h1 = figures.text_size("12 mm", 10)
    w2, h2 = figures.text_size("12 mm", 20)
    assert w2 > 1.6 * w1 and h2 > 1.6 * h1
    assert figures.text_size("12 mm and more", 10)[0] > w1
    assert figures.text_size("a\nb", 10)[1] > 1.8 * figures.text_size("a", 10)[1]


def test_title_band_holds_the_text_above_the_picture():
    img = Image.new("RGB", (40, 30), (0, 0, 255))
    out = figures.add_title(img, ["a long title line that is wider", "second"])
    rgb = _rgb(out)
    band = out.height - 30
    assert out.width >= figures.text_size("a long title line that is wider", 16)[0]
    assert np.all(rgb[band:, :40] == (0, 0, 255))
    dark = rgb[:band].sum(axis=-1) < 200
    assert dark.sum() > 50 and not np.any(dark[:, :2])


@pytest.mark.parametrize("corner", ["top-left", "top-right", "bottom-left", "bottom-right"])
def test_legend_box_sits_in_its_corner_with_its_swatches(corner):
    img = Image.new("RGB", (400, 300), (200, 200, 200))
    items = [
        LegendItem("cut", (0, 0, 0), "line"),
        LegendItem("travel", (213, 94, 0), "line"),
        LegendItem("board", (0, 114, 178), "box"),
        LegendItem("start", (0, 158, 115), "ring"),
        LegendItem("no", (230, 159, 0), "hatch"),
        LegendItem("cross", (204, 121, 167), "dots"),
        LegendItem("to start", (86, 180, 233), "arrow"),
    ]
    x0, y0, x1, y1 = figures.draw_legend(img, items, corner, title="key")
    w, h = figures.legend_size(items, title="key")
    assert (x1 - x0 + 1, y1 - y0 + 1) == (w, h)
    assert (x0 == 6) == corner.endswith("left") and (y0 == 6) == corner.startswith("top")
    assert 0 <= x0 and x1 < 400 and 0 <= y0 and y1 < 300
    rgb = _rgb(img)
    inside = rgb[y0 : y1 + 1, x0 : x1 + 1]
    for it in items:
        assert _has(inside, it.color), it
    outside = rgb.copy()
    outside[y0 : y1 + 1, x0 : x1 + 1] = 200
    assert np.all(outside == 200)
    # Swatches come in order, top to bottom.
    swatches = inside[:, 8:30]
    rows = [
        np.flatnonzero(np.all(swatches == it.color, axis=-1).any(axis=1)).mean() for it in items
    ]
    assert rows == sorted(rows)


def test_hatch_lines_are_diagonal_and_inside_the_box():
    img = Image.new("RGB", (50, 50), (255, 255, 255))
    figures.hatch(ImageDraw.Draw(img), (10, 12, 30, 40), (0, 0, 0), step=6)
    ys, xs = np.nonzero(_rgb(img).sum(axis=-1) == 0)
    assert xs.min() >= 10 and xs.max() <= 30 and ys.min() >= 12 and ys.max() <= 40
    # Each line is x - y = const: the differences fall on a few values step apart.
    sums = np.unique(xs - ys)
    assert len(sums) > 5 and np.all(np.diff(sums) >= 5)


def test_nice_length_is_the_largest_round_value_below_the_limit(rng):
    candidates = sorted(m * 10.0**e for m in (1, 2, 5) for e in range(-4, 6))
    for limit in np.concatenate([rng.uniform(0.001, 5e5, 200), [1.0, 2.0, 5.0, 50.0, 0.2]]):
        want = max(c for c in candidates if c <= limit * (1 + 1e-12))
        assert figures.nice_length(float(limit)) == pytest.approx(want)
    with pytest.raises(ValueError):
        figures.nice_length(0.0)


def test_scale_bar_spans_its_length_in_pixels():
    img = Image.new("RGB", (400, 60), (255, 255, 255))
    length, (x0, _, x1, _) = figures.draw_scale_bar(img, 7.3, (20, 30), max_px=160)
    assert length == 20.0  # 160 / 7.3 = 21.9 mm -> 20 mm
    assert x1 - x0 == round(length * 7.3)
    row = _rgb(img)[30]
    black = np.flatnonzero(row.sum(axis=-1) == 0)
    assert black.min() == 20 and black[black < x1 + 3].max() >= x1 - 1
    assert np.all(row[21 : x1 - 1] == 0)


def test_arrow_ends_at_its_head():
    img = Image.new("RGB", (100, 100), (255, 255, 255))
    figures.draw_arrow(ImageDraw.Draw(img), (10, 10), (80, 60), (0, 0, 255), head=10)
    ys, xs = np.nonzero(np.all(_rgb(img) == (0, 0, 255), axis=-1))
    far = np.argmax(xs + ys)
    assert abs(xs[far] - 80) <= 1 and abs(ys[far] - 60) <= 1
    # The head is wider than the shaft: near b the mark spans several pixels across.
    u = np.array([70, 50]) / math.hypot(70, 50)
    across = (xs - 80) * -u[1] + (ys - 60) * u[0]
    along = (xs - 80) * u[0] + (ys - 60) * u[1]
    assert np.ptp(across[along > -8]) >= 5 and np.ptp(across[along < -20]) <= 3


def test_cvd_simulation_keeps_greys_and_merges_red_with_green():
    greys = np.stack([np.full(3, v) for v in (0, 40, 128, 200, 255)])
    for kind in ("protanopia", "deuteranopia"):
        assert np.allclose(figures.simulate_cvd(greys, kind) * 255, greys, atol=0.05)
    # A red and some pure green (no red light in it) look alike to a deuteranope.
    sim_red = figures.simulate_cvd(np.array([200, 30, 30]))
    g, b = np.meshgrid(np.arange(256), np.arange(0, 121, 2))
    greens = np.stack([np.zeros_like(g), g, b], axis=-1).reshape(-1, 3)
    sims = figures.simulate_cvd(greens)
    err = np.abs(sims - sim_red).max(axis=-1)
    assert err.min() < 0.035 and greens[np.argmin(err), 1] > 100
    # Okabe-Ito's blue and orange stay far apart.
    blue, orange = figures.OKABE_ITO["blue"], figures.OKABE_ITO["orange"]
    for kind in ("protanopia", "deuteranopia"):
        a, b = figures.simulate_cvd(np.array([blue, orange]), kind)
        assert np.abs(a - b).max() > 0.4


def test_lightness_matches_cie_reference_points():
    assert figures.lightness(np.array([1.0, 1.0, 1.0])) == pytest.approx(100.0)
    assert figures.lightness(np.array([0.0, 0.0, 0.0])) == pytest.approx(0.0)
    # sRGB mid grey 119/255 has L* about 50 (CIE: L* = 116 Y^(1/3) - 16 at Y = 0.1845).
    assert figures.lightness(np.full(3, 119 / 255)) == pytest.approx(50.0, abs=0.3)
    assert figures.linear_to_srgb(figures.srgb_to_linear(np.linspace(0, 1, 11))) == pytest.approx(
        np.linspace(0, 1, 11)
    )


@pytest.mark.parametrize("width", [1, 2, 3])
def test_outline_marks_the_pixels_of_a_region_near_its_border(width, rng):
    """Against the definition: a region pixel is drawn when a pixel outside the region (or
    off the picture) lies within ``width`` steps up, down, left or right (city-block)."""
    mask = np.zeros((14, 17), bool)
    mask[3:11, 4:13] = True
    mask[0:5, 0:3] = True  # touching the picture's corner
    mask[6, 8] = False  # a hole
    mask |= rng.uniform(size=mask.shape) < 0.05  # specks
    rgb = np.zeros((*mask.shape, 3), np.uint8)
    figures.outline_cells(rgb, mask, (1, 2, 3), width)
    drawn = np.all(rgb == (1, 2, 3), axis=-1)
    h, w = mask.shape
    for i in range(h):
        for j in range(w):
            near_outside = any(
                not (0 <= i + di < h and 0 <= j + dj < w) or not mask[i + di, j + dj]
                for di in range(-width, width + 1)
                for dj in range(-width, width + 1)
                if abs(di) + abs(dj) <= width
            )
            assert drawn[i, j] == (mask[i, j] and near_outside), (i, j)
    assert np.all(rgb[~drawn] == 0)  # nothing else touched


def test_outline_swatch_is_framed_in_its_colour_around_white():
    img = Image.new("RGB", (400, 120), (200, 200, 200))
    colour = (204, 121, 167)
    box = figures.draw_legend(img, [LegendItem("glint", colour, "outline")], (5, 5))
    rgb = _rgb(img)[box[1] : box[3] + 1, box[0] : box[2] + 1]
    assert _has(rgb, colour) and _has(rgb, (255, 255, 255))
