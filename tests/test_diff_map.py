"""Difference maps of verify: the array against hand arithmetic, the PNG read back, the report."""

from __future__ import annotations

import base64
import html
import json
import math
import re
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from conftest import CHROMIUM, chromium_dom, make_design, write_pipeline
from PIL import Image
from test_report import fake_job

from scratchfab.figures import OFF_BOARD_RGB, lightness, simulate_cvd
from scratchfab.metrics import exposed_difference, psnr
from scratchfab.model.job import JobLayout
from scratchfab.model.scratches import ScratchSet
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.manifest import Manifest
from scratchfab.pipeline.report import write_report
from scratchfab.pipeline.runner import run_pipeline
from scratchfab.render.renderer import render_scratches
from scratchfab.verify.diffmap import (
    BRIGHTER_RGB,
    DARKER_RGB,
    DIFF_SCALE,
    EQUAL_RGB,
    GLINT_RGB,
    HATCH_RGB,
    diff_colours,
    diff_figure,
    write_diff_map,
)
from scratchfab.verify.noise import diff_noise_advice
from scratchfab.verify.verify import VerifyGateError, VerifySettings, run_verify

NAN = math.nan


def _exact_exposure(render: list[list[float]], target: list[list[float]]) -> Fraction:
    """sum(R T) / sum(R R) over the pixels where both are numbers, in exact arithmetic."""
    pairs = [
        (Fraction(r), Fraction(t))
        for rr, tt in zip(render, target, strict=True)
        for r, t in zip(rr, tt, strict=True)
        if not (math.isnan(r) or math.isnan(t))
    ]
    return sum(r * t for r, t in pairs) / sum(r * r for r, _ in pairs)


def test_difference_is_the_exposed_render_minus_the_target_on_the_board():
    target = [[0.25, 0.5, NAN], [0.75, 1.0, 0.5]]
    render = [[1.0, 2.0, 7.0], [3.0, 8.0, NAN]]  # (1, 1) far brighter than the rest
    diff, s = exposed_difference(np.array(render), np.array(target))
    # By hand: the board is the four pixels where both are numbers;
    # s = (0.25 + 1 + 2.25 + 8) / (1 + 4 + 9 + 64) = 11.5 / 78.
    assert _exact_exposure(render, target) == Fraction(23, 156)
    assert s == pytest.approx(23 / 156, rel=1e-15)
    for i in range(2):
        for j in range(3):
            if math.isnan(render[i][j]) or math.isnan(target[i][j]):
                assert math.isnan(diff[i, j]), (i, j)
            else:
                want = Fraction(23, 156) * Fraction(render[i][j]) - Fraction(target[i][j])
                assert diff[i, j] == pytest.approx(float(want), abs=1e-15), (i, j)
    assert diff[1, 1] > 0 and diff[0, 0] < 0  # brighter is positive
    # The PSNR of metrics.json squares exactly this difference.
    board = np.isfinite(diff)
    assert psnr(np.array(render), np.array(target)) == pytest.approx(
        -10 * math.log10(np.mean(diff[board] ** 2)), rel=1e-12
    )


def test_colours_are_symmetric_clipped_at_the_scale_and_white_at_zero():
    d = DIFF_SCALE * np.array([[-3.0, -1.0, -0.5, 0.0, 0.5, 1.0, 3.0, NAN]])
    rgb = diff_colours(d)
    assert tuple(rgb[0, 0]) == tuple(rgb[0, 1]) == DARKER_RGB  # clipped at -scale
    assert tuple(rgb[0, 6]) == tuple(rgb[0, 5]) == BRIGHTER_RGB  # clipped at +scale
    assert tuple(rgb[0, 3]) == EQUAL_RGB == (255, 255, 255)
    assert tuple(rgb[0, 7]) == OFF_BOARD_RGB
    # Half the scale: half way from white to the end colour, per channel.
    for col, end in ((2, DARKER_RGB), (4, BRIGHTER_RGB)):
        for c in range(3):
            assert abs(int(rgb[0, col, c]) - (255 + end[c]) / 2) <= 0.5
    # A scale of its own: the end colour at that scale, not before.
    assert tuple(diff_colours(np.array([0.2]), scale=0.2)[0]) == BRIGHTER_RGB
    assert tuple(diff_colours(np.array([0.19]), scale=0.2)[0]) != BRIGHTER_RGB
    with pytest.raises(ValueError, match="scale"):
        diff_colours(d, scale=0.0)


def test_lightness_tells_the_size_and_the_sides_survive_colour_blindness():
    steps = DIFF_SCALE * np.linspace(0, 1, 21)
    up = diff_colours(steps[None])[0]
    down = diff_colours(-steps[None])[0]
    for side in (up, down):
        assert np.all(np.diff(lightness(side / 255.0)) < 0)  # larger: darker, both sides
    # Equal sizes look equally strong: the same CIE L* within 1.5 at every step.
    assert np.max(np.abs(lightness(up / 255.0) - lightness(down / 255.0))) < 1.5
    # Seen by a dichromat, brighter stays yellowish (red > blue channel) and darker
    # blue, from a fifth of the scale on.
    for kind in ("protanopia", "deuteranopia"):
        seen_up, seen_down = simulate_cvd(up, kind), simulate_cvd(down, kind)
        strong = steps >= DIFF_SCALE / 5
        assert np.all(seen_up[strong, 0] - seen_up[strong, 2] > 0.05), kind
        assert np.all(seen_down[strong, 2] - seen_down[strong, 0] > 0.05), kind


def _block(img: np.ndarray, box: tuple[int, int, int, int], factor: int, i: int, j: int):
    y, x = box[1] + i * factor, box[0] + j * factor
    return img[y : y + factor, x : x + factor].reshape(-1, 3)


def test_png_shows_each_pixel_in_its_colour_with_off_board_hatched(tmp_path):
    # Target 0 except three bright pixels; column 0 lies off the board.
    target = np.zeros((6, 5))
    target[:, 0] = NAN
    target[1, 1] = target[2, 2] = 1.0
    render = np.zeros((6, 5))
    render[2, 2] = 1.0  # lit as wanted
    render[3, 3] = 1.0  # lit where the target is black
    render[4, 4] = 0.5
    # s = 1 / (1 + 1 + 0.25) = 4/9: (1, 1) -1, (2, 2) -5/9, (3, 3) +4/9, (4, 4) +2/9.
    path = tmp_path / "diff" / "v.png"
    fig = write_diff_map(path, render, target, "v")
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape[:2] == (fig.image.height, fig.image.width)
    assert fig.factor * 5 >= 256 and fig.map_box[2] - fig.map_box[0] + 1 == 5 * fig.factor

    def colour(i: int, j: int) -> tuple[int, ...]:
        pixels = np.unique(_block(img, fig.map_box, fig.factor, i, j), axis=0)
        assert len(pixels) == 1, (i, j, pixels)
        return tuple(int(v) for v in pixels[0])

    def blend(end: tuple[int, int, int], t: float) -> tuple[int, ...]:
        return tuple(round(255 + t * (e - 255)) for e in end)

    assert colour(1, 1) == DARKER_RGB  # -1, clipped
    assert colour(2, 2) == DARKER_RGB  # -5/9, clipped
    assert colour(3, 3) == blend(BRIGHTER_RGB, (4 / 9) / DIFF_SCALE)  # brighter: red side
    assert colour(4, 4) == blend(BRIGHTER_RGB, (2 / 9) / DIFF_SCALE)
    assert colour(0, 1) == colour(5, 4) == EQUAL_RGB
    # Off the board: grey with dark hatch lines, nothing else.
    off = np.vstack([_block(img, fig.map_box, fig.factor, i, 0) for i in range(6)])
    seen = {tuple(int(v) for v in p) for p in np.unique(off, axis=0)}
    assert seen == {OFF_BOARD_RGB, HATCH_RGB}
    # The colour bar runs from darker (left) through white to brighter (right).
    x0, y0, x1, y1 = fig.bar_box
    mid_y = (y0 + y1) // 2
    assert tuple(int(v) for v in img[mid_y, x0]) == pytest.approx(DARKER_RGB, abs=2)
    assert tuple(int(v) for v in img[mid_y, x1]) == pytest.approx(BRIGHTER_RGB, abs=2)
    assert tuple(int(v) for v in img[mid_y, (x0 + x1) // 2]) == pytest.approx(EQUAL_RGB, abs=2)
    # The key shows both colours and the hatch.
    lx0, ly0, lx1, ly1 = fig.legend_box
    key = {tuple(int(v) for v in p) for p in img[ly0 : ly1 + 1, lx0 : lx1 + 1].reshape(-1, 3)}
    assert {BRIGHTER_RGB, DARKER_RGB, OFF_BOARD_RGB, HATCH_RGB} <= key
    # The title names the view: another name draws another title, the same map.
    other = write_diff_map(tmp_path / "w.png", render, target, "another-view")
    mine = np.asarray(fig.image)
    theirs = np.asarray(other.image)
    y, x = fig.map_box[1], fig.map_box[0]
    assert other.map_box[1] == y
    assert not np.array_equal(mine[:y], theirs[:y])
    assert np.array_equal(
        mine[y : fig.map_box[3] + 1, x : fig.map_box[2] + 1],
        theirs[y : other.map_box[3] + 1, x : other.map_box[2] + 1],
    )


def test_verify_draws_the_map_of_its_own_render_on_the_metrics_footing(tmp_path):
    design = make_design(resolution=16)
    rng = np.random.default_rng(5)
    p0 = rng.uniform(-15, 15, (120, 2))
    angle = rng.uniform(0, np.pi, 120)
    p1 = np.clip(p0 + 3 * np.column_stack([np.cos(angle), np.sin(angle)]), -18, 18)
    board = ScratchSet.from_arrays(p0, p1, design.scratch.width_mm, design.scratch.depth_mm)
    analytic = render_scratches(design, board)
    target = rng.uniform(0, 1, (16, 16))
    target[:3] = NAN
    out = tmp_path / "v"
    stale = out / "diff" / "right.png"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"a map of another board")
    metrics = run_verify(
        design, board, out, VerifySettings(spp=32), analytic=analytic, targets={"left": target}
    )
    assert not stale.exists()  # right has no target: no map, and the old one is gone
    render = np.load(out / "left.npy")
    diff, s = exposed_difference(render, target)
    assert s == pytest.approx(metrics["views"]["left"]["exposure"], rel=1e-12)
    img = np.asarray(Image.open(out / "diff" / "left.png").convert("RGB"))
    # The map of Mitsuba's render, not of the analytic one it is compared with; at 32 spp
    # the map is mostly sampling noise and says so in its note (as verify words it).
    note = diff_noise_advice(metrics["views"]["left"], "spp")
    assert note
    fig = write_diff_map(tmp_path / "mine.png", render, target, "left", note=note)
    assert np.array_equal(img, np.asarray(fig.image))
    analytic_fig = write_diff_map(
        tmp_path / "analytic.png", analytic["left"], target, "left", note=note
    )
    assert not np.array_equal(img, np.asarray(analytic_fig.image))
    want = diff_colours(diff)
    for i in range(3, 16):
        for j in range(16):
            block = _block(img, fig.map_box, fig.factor, i, j)
            assert np.all(block == want[i, j]), (i, j)


def test_the_glint_is_outlined_on_the_map_and_named_in_its_title_and_key():
    """Where the bare board glints, the map outlines the region on its own colours (the
    cells inside keep theirs), the title gives the glint's share of the board and the key
    its colour; an empty glint draws the map exactly as none."""
    from scratchfab.optimize.glint import ViewGlint

    rng = np.random.default_rng(3)
    diff = rng.uniform(-0.3, 0.3, (12, 10))
    diff[:, -1] = NAN  # off the board
    mask = np.zeros(diff.shape, bool)
    mask[0:5, 0:4] = True  # a corner, as a glint lies
    plain = diff_figure(diff, "v")
    fig = diff_figure(diff, "v", glint=ViewGlint("v", mask, 0.0734, 0.8))
    img = np.asarray(fig.image.convert("RGB"))
    f = fig.factor
    assert f >= 4
    x0, y0 = fig.map_box[:2]
    drawn = np.all(img[y0 : y0 + 12 * f, x0 : x0 + 10 * f] == GLINT_RGB, axis=-1)
    cells = drawn.reshape(12, f, 10, f).any(axis=(1, 3))
    # Exactly the region's border cells: those with a neighbour outside it or off the map
    # (a 2 px line inside cells of at least 4 px).
    padded = np.pad(mask, 1, constant_values=False)
    inner = mask & padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:]
    assert np.array_equal(cells, mask & ~inner)
    want = diff_colours(diff)
    inside = [(i, j) for i in range(1, 4) for j in range(1, 3)]  # away from the outline
    for i, j in inside:
        centre = img[y0 + i * f + f // 2, x0 + j * f + f // 2]
        assert tuple(centre) == tuple(want[i, j]), (i, j)
    # The title's last line says it; the key shows the outline colour.
    assert fig.image.height > plain.image.height
    lx0, ly0, lx1, ly1 = fig.legend_box
    assert np.any(np.all(img[ly0 : ly1 + 1, lx0 : lx1 + 1] == GLINT_RGB, axis=-1))
    plain_img = np.asarray(plain.image.convert("RGB"))
    assert not np.any(np.all(plain_img == GLINT_RGB, axis=-1))
    none = diff_figure(diff, "v", glint=ViewGlint("v", np.zeros_like(mask), 0.0, 0.0))
    assert np.array_equal(np.asarray(none.image), np.asarray(plain.image))
    with pytest.raises(ValueError, match="glint mask"):
        diff_figure(diff, "v", glint=ViewGlint("v", mask[:-1], 0.07, 0.8))


def test_verify_outlines_the_glint_design_predicts_and_its_gate_names_it(tmp_path):
    """The test design on a 200 mm board glints (design's check says where): verify
    records each view's glint share as the check predicts it, outlines on the maps the
    pixels whose half-vector tilts below the glint limit and, when the views fall short,
    says the glint is why and what to move."""
    from scratchfab.backend import array_module
    from scratchfab.design.feasibility import (
        check_feasibility,
        design_glint_deg,
        half_vectors,
        tilt_deg,
    )
    from scratchfab.optimize.glint import ViewGlint
    from scratchfab.render.renderer import ViewRenderer

    design = make_design(resolution=24, size_mm=200.0)
    report = check_feasibility(design)
    assert all(report.views[v.name].glint_fraction > 0.02 for v in design.views)
    rng = np.random.default_rng(7)
    p0 = rng.uniform(-90, 90, (300, 2))
    angle = rng.uniform(0, np.pi, 300)
    p1 = np.clip(p0 + 8 * np.column_stack([np.cos(angle), np.sin(angle)]), -95, 95)
    board = ScratchSet.from_arrays(p0, p1, design.scratch.width_mm, design.scratch.depth_mm)
    targets = {v.name: rng.uniform(0, 1, (24, 24)) for v in design.views}
    out = tmp_path / "v"
    with pytest.raises(VerifyGateError) as caught:
        run_verify(design, board, out, VerifySettings(spp=16, min_rho=0.99), targets=targets)
    said = str(caught.value)
    names = [v.name for v in design.views]
    assert f"; the bare board glints into {', '.join(names)} (design warned" in said
    assert "optimizing longer does not help: move the camera or the light" in said
    assert caught.value.named("[verify] min_rho =", "p.toml").glinting == tuple(names)
    metrics = json.loads((out / "metrics.json").read_text())
    limit = design_glint_deg(design)
    for view in design.views:
        share = metrics["views"][view.name]["glint_share"]
        assert share == pytest.approx(report.views[view.name].glint_fraction, abs=0.01)
        # The outline: the pixels whose centre's half-vector (the check's own function)
        # tilts below the limit, on the board.
        vr = ViewRenderer(design, view, array_module("llvm"))
        tilt = tilt_deg(half_vectors(design, view, vr.center))
        mask = (tilt < limit) & (vr.area_on_board > 0)
        assert 0 < mask.sum() < mask.size
        render = np.load(out / f"{view.name}.npy")
        want = write_diff_map(
            tmp_path / f"{view.name}.png",
            render,
            targets[view.name],
            view.name,
            glint=ViewGlint(view.name, mask, share, 0.0),
        )
        got = np.asarray(Image.open(out / "diff" / f"{view.name}.png").convert("RGB"))
        assert np.array_equal(got, np.asarray(want.image))
    # A board without glint: no share, no outline.
    small = make_design(resolution=16)
    plain = run_verify(
        small,
        ScratchSet.from_arrays(
            0.18 * p0, 0.18 * p1, design.scratch.width_mm, design.scratch.depth_mm
        ),
        tmp_path / "w",
        VerifySettings(spp=16),
        targets={"left": rng.uniform(0, 1, (16, 16))},
    )
    assert all(v["glint_share"] == 0.0 for v in plain["views"].values())
    img = np.asarray(Image.open(tmp_path / "w" / "diff" / "left.png").convert("RGB"))
    assert not np.any(np.all(img == GLINT_RGB, axis=-1))


def _tiny_job(tmp_path: Path) -> Path:
    edits = {
        "count = 250": "count = 150",
        "resolution = [24, 24]": "resolution = [16, 16]",
        "iterations = 4": "iterations = 2",
        "spp = 256": "spp = 16",
    }
    return write_pipeline(tmp_path, edits=edits)


def test_report_shows_the_map_after_the_verify_render_and_not_without_it(tmp_path):
    job = fake_job(tmp_path)
    layout = JobLayout(job)
    target = np.full((8, 8), 0.5)
    write_diff_map(layout.verify_diff_png("left"), np.eye(8), target, "left")
    page = write_report(job).read_text()
    data = base64.b64encode(layout.verify_diff_png("left").read_bytes()).decode("ascii")

    def row(name: str) -> str:
        start = page.index(f"<h3>view {name}</h3>")
        return page[start : page.index("<h3", start + 1)]

    left = row("left")
    assert left.index("left verify render") < left.index(data)  # after the verify render
    assert left.index(data) < left.index("left feasibility") if "feasibility" in left else True
    assert "brighter (orange) or darker (blue) than the target" in left
    assert "difference map" not in row("right")  # right has none
    assert page.count(data) == 1
    assert page.count("<figure") == page.count("<figcaption>")
    # An old job (verified before the maps existed) still reports, without one.
    layout.verify_diff_png("left").unlink()
    page = write_report(job).read_text()
    assert data not in page and "difference map" not in page
    assert "verify render" in page


def test_pipeline_records_the_maps_so_a_missing_one_reruns_verify(tmp_path):
    path = _tiny_job(tmp_path)
    pipe = load_pipeline(path)
    job = tmp_path / "job"
    layout = JobLayout(job)
    first = run_pipeline(pipe, job, until="verify")
    assert "verify" in first.ran
    outputs = Manifest.load(job).stages["verify"]["outputs"]
    maps = ["verify/diff/bar.png", "verify/diff/disc.png"]
    assert outputs == sorted(["verify/metrics.json", *maps])
    page = layout.report_html.read_text()
    for name in ("disc", "bar"):
        assert base64.b64encode(layout.verify_diff_png(name).read_bytes()).decode() in page
    assert run_pipeline(pipe, job, until="verify").skipped == ["design", "optimize", "verify"]
    layout.verify_diff_png("bar").unlink()
    assert run_pipeline(pipe, job, until="verify").ran == ["verify"]
    assert layout.verify_diff_png("bar").is_file()
    # A job verified before the maps: its manifest names metrics.json alone. It stays up
    # to date (verify is not run again for a picture) and its report simply lacks them.
    manifest = json.loads((job / "manifest.json").read_text())
    manifest["stages"]["verify"]["outputs"] = ["verify/metrics.json"]
    (job / "manifest.json").write_text(json.dumps(manifest))
    for name in ("disc", "bar"):
        layout.verify_diff_png(name).unlink()
    again = run_pipeline(pipe, job, until="verify")
    assert again.skipped == ["design", "optimize", "verify"]
    page = layout.report_html.read_text()
    assert "difference map" not in page and "verify render" in page


def _job_with_a_map(tmp_path: Path, size: int) -> tuple[Path, int]:
    """fake_job with a difference map of view left, ``size`` pixels square; its PNG width."""
    job = fake_job(tmp_path)
    layout = JobLayout(job)
    rng = np.random.default_rng(5)
    target = np.full((size, size), 0.5)
    write_diff_map(layout.verify_diff_png("left"), rng.uniform(0, 1, target.shape), target, "left")
    with Image.open(layout.verify_diff_png("left")) as image:
        return job, image.width


@pytest.mark.parametrize("size", [8, 64, 300, 700])
def test_report_boxes_of_the_views_are_as_wide_as_the_widest_picture(tmp_path, size):
    """Every view's boxes (the difference map's among them) get one width: the map's own
    (drawn at full size for its key's text, at most 640 px), or the pictures' 256 px."""
    job, map_width = _job_with_a_map(tmp_path, size)
    assert map_width > 256  # the map's key is wider than a picture
    page = write_report(job).read_text()
    start = page.index("<h3>view ")
    rows = re.findall(r"<div class='row views'>(.*?)</div>", page[start:])
    assert len(rows) == 2
    widths = [re.findall(r"<figure[^>]*style='width:(\d+)px'>", row) for row in rows]
    assert [len(w) for w in widths] == [3, 4]  # right: no map; left: its map
    assert {int(w) for row in widths for w in row} == {min(640, map_width)}
    assert all(row.count("<figure") == len(w) for row, w in zip(rows, widths, strict=True))


@pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (.ci/run installs it)"
)
@pytest.mark.parametrize("size", [64, 700])
def test_report_boxes_of_the_views_measured_in_chromium(tmp_path, size):
    """As laid out by a browser: every view's boxes one width, each picture inside its box,
    the difference map at its own size (up to 640 px), the others at 256 px."""
    job, map_width = _job_with_a_map(tmp_path, size)
    page = write_report(job)
    measure = """<script>
window.addEventListener('load', function () {
  var out = [];
  document.querySelectorAll('.views figure').forEach(function (f) {
    var b = f.getBoundingClientRect(), img = f.querySelector('img');
    var i = img.getBoundingClientRect(), c = f.querySelector('figcaption').getBoundingClientRect();
    out.push([b.left, b.right, i.left, i.right, c.right, img.naturalWidth, img.alt]);
  });
  document.body.setAttribute('data-boxes', JSON.stringify(out));
});
</script></body>"""
    page.write_text(page.read_text().replace("</body>", measure))
    dom = chromium_dom(page, tmp_path / "profile")
    found = re.search(r'data-boxes="([^"]*)"', dom)
    assert found, dom[:2000]
    boxes = json.loads(html.unescape(found.group(1)))
    assert len(boxes) == 7
    widths = {round(right - left, 1) for left, right, *_ in boxes}
    assert len(widths) == 1  # one width for every box
    shown = min(640, map_width)
    for left, right, img_left, img_right, caption_right, natural, alt in boxes:
        assert left < img_left and img_right < right and caption_right < right
        want = shown if alt == "left difference map" else 256
        assert img_right - img_left == pytest.approx(want, abs=0.5), alt
        assert right - left == pytest.approx(shown + 2 * 8 + 2, abs=1.0)  # padding, border
        if alt == "left difference map":
            assert natural == map_width


def test_report_of_a_map_larger_than_pillow_opens_shows_it_at_the_cap(tmp_path, monkeypatch):
    """The report reads only the map's width: a map with more pixels than Pillow's
    decompression-bomb limit (a view near the 16384 px resolution bound) is shown at the
    640 px cap, not a DecompressionBombError out of write_report."""
    job, map_width = _job_with_a_map(tmp_path, 700)
    assert map_width > 640
    with Image.open(JobLayout(job).verify_diff_png("left")) as image:
        pixels = image.width * image.height
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", pixels // 3)  # past twice the limit: error
    page = write_report(job).read_text()
    widths = re.findall(r"<figure[^>]*style='width:(\d+)px'>", page)
    assert len(widths) == 7 and set(widths) == {"640"}
