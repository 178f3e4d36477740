from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scratchfab.cli import main
from scratchfab.design.feasibility import (
    arc_distance_deg,
    check_feasibility,
    half_vectors,
    lobe_deg,
    tilt_deg,
)
from scratchfab.errors import ConfigError
from scratchfab.model.design import design_from_mapping
from scratchfab.render.profile import solve_wbar


def _design(views, light=(0.0, 187.3, 463.6), roughness=0.05):
    tables = {
        "board": {"width_mm": 40.0, "height_mm": 40.0, "roughness": roughness, "margin_mm": 1.0},
        "light": {"position_mm": list(light)},
        "scratch": {"count": 300, "min_length_mm": 1.0, "max_length_mm": 6.0},
        "views": [
            {
                "name": n,
                "azimuth_deg": az,
                "elevation_deg": el,
                "distance_mm": 500.0,
                "fov_deg": "auto",
                "resolution": [32, 32],
            }
            for n, az, el in views
        ],
    }
    return design_from_mapping(tables, "scene.toml", Path("."))


def test_arc_distance_matches_brute_force_over_profile_normals(rng):
    # Brute force: every normal n(x) of the dent (SPEC section 3) turned into the scratch's
    # across-direction, and the smallest angle to h.
    w, d = 0.05, 0.01
    wbar = float(solve_wbar(2 * w, d))
    x = np.linspace(-w, w, 200001)
    den = wbar**2 + 4 * x**2
    n_across = -4 * wbar * x / den
    n_z = (wbar**2 - 4 * x**2) / den
    steepest = math.degrees(2 * math.atan(2 * w / wbar))
    for _ in range(40):
        h = rng.normal(size=3)
        h[2] = abs(h[2]) + 0.3
        h /= np.linalg.norm(h)
        phi = rng.uniform(0, 2 * np.pi)
        across = np.array([math.cos(phi), math.sin(phi)])
        normals = np.stack([n_across * across[0], n_across * across[1], n_z], axis=1)
        brute = np.degrees(np.arccos(np.clip(normals @ h, -1, 1))).min()
        got = float(arc_distance_deg(h[None], across[None], steepest)[0])
        assert got == pytest.approx(brute, abs=2e-3)


def test_reachability_against_profile_range():
    design = _design([("a", -22.0, 0.0), ("b", 22.0, 0.0)])
    report = check_feasibility(design)
    assert report.ok, report.errors
    for v in design.views:
        # At the board's centre |wi + wo| = 2 cos(theta / 2) for the light-camera
        # angle theta, so the tilt is acos((wi_z + wo_z) / (2 cos(theta / 2))).
        wi = np.array([0.0, 187.3, 463.6])
        wo = np.array(v.position_mm)
        wi, wo = wi / np.linalg.norm(wi), wo / np.linalg.norm(wo)
        theta = math.acos(wi @ wo)
        centre_tilt = math.degrees(math.acos((wi[2] + wo[2]) / (2 * math.cos(theta / 2))))
        h = half_vectors(design, v, np.zeros((1, 2)))
        assert float(tilt_deg(h)[0]) == pytest.approx(centre_tilt, abs=1e-9)
        fv = report.views[v.name]
        assert fv.tilt_min_deg <= centre_tilt <= fv.tilt_max_deg
        assert fv.reachable_fraction == 1.0
    assert report.lobe_deg == pytest.approx(math.degrees(math.atan(0.05)))
    data = json.loads(json.dumps(report.to_json()))
    assert data["errors"] == [] and len(data["pairs"]) == 2


def test_unreachable_view_is_refused_by_name():
    design = _design([("near", -22.0, 0.0), ("far-away", 75.0, 0.0)])
    report = check_feasibility(design)
    assert len(report.errors) == 1
    assert "'far-away'" in report.errors[0] and "unreachable" in report.errors[0]
    assert report.views["far-away"].reachable_fraction < 0.5
    with pytest.raises(ConfigError, match="far-away.*--force"):
        report.raise_if_errors("scene.toml")


def test_duplicate_view_is_refused_naming_both():
    design = _design([("cat", -22.0, 0.0), ("dog", 22.0, 0.0), ("cat2", -22.0, 0.0)])
    report = check_feasibility(design)
    assert len(report.errors) == 1
    msg = report.errors[0]
    assert "'cat'" in msg and "'cat2'" in msg and "indistinguishable" in msg


def test_mirror_views_with_light_on_axis_are_indistinguishable():
    # The profile is symmetric: its normals tilt both ways across the scratch, so a
    # scratch for the left view also lights the mirrored right view when the light sits
    # straight in front (both half-vectors lean along x, in opposite directions).
    design = _design([("left", -30.0, 0.0), ("right", 30.0, 0.0)], light=(0.0, 0.0, 500.0))
    report = check_feasibility(design)
    assert any("indistinguishable" in e for e in report.errors)
    pair = report.pairs[0]
    assert pair.separation_median_deg < lobe_deg(0.05)
    # Raising the light turns the two half-vectors apart.
    ok = check_feasibility(_design([("left", -22.0, 0.0), ("right", 22.0, 0.0)]))
    assert ok.pairs[0].separation_median_deg > 5 * lobe_deg(0.05)
    assert ok.pairs[0].expected_crosstalk < 1e-2


def _png(path: Path) -> Path:
    Image.new("L", (16, 16), 255).save(path)
    return path


def test_cli_refuses_unless_forced_and_writes_nothing(tmp_path, capsys):
    a, b = _png(tmp_path / "a.png"), _png(tmp_path / "b.png")
    toml = tmp_path / "scene.toml"
    toml.write_text(
        "[board]\nwidth_mm = 40.0\nheight_mm = 40.0\nmargin_mm = 1.0\n"
        "[light]\nposition_mm = [0.0, 187.3, 463.6]\n"
        "[scratch]\ncount = 100\nmin_length_mm = 1.0\nmax_length_mm = 4.0\n"
        f'[[views]]\nname = "ok"\ntarget = "{a.name}"\nazimuth_deg = -22.0\n'
        'elevation_deg = 0.0\ndistance_mm = 500.0\nfov_deg = "auto"\nresolution = [24, 24]\n'
        f'[[views]]\nname = "steep"\ntarget = "{b.name}"\nazimuth_deg = 80.0\n'
        'elevation_deg = 0.0\ndistance_mm = 500.0\nfov_deg = "auto"\nresolution = [24, 24]\n'
    )
    job = tmp_path / "job"
    with pytest.raises(SystemExit) as info:
        main(["design", str(toml), "--out", str(job)])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "'steep'" in err and str(toml) in err
    assert not (job / "design").exists()
    main(["design", str(toml), "--out", str(job), "--force"])
    report = json.loads((job / "design" / "feasibility.json").read_text())
    assert any("'steep'" in e for e in report["errors"])
    assert (job / "design" / "feasibility_steep.png").is_file()


@pytest.mark.parametrize("order", [1, -1])
def test_one_sided_crosstalk_is_still_an_error(order):
    # A steep view's scratches carry a wide arc of normals that reaches a shallow view's
    # half-vector (1.7-2.2 deg) while the reverse is 8 deg apart: the worse side decides,
    # whichever order the views come in.
    views = [("low", 10.0, 0.0), ("high", 36.0, 16.0)][::order]
    report = check_feasibility(_design(views, light=(0.0, 0.0, 500.0)))
    seps = {(p.lit, p.other): p.separation_median_deg for p in report.pairs}
    assert seps[("high", "low")] < lobe_deg(0.05) < seps[("low", "high")]
    assert len(report.errors) == 1 and "indistinguishable" in report.errors[0]
    assert "light 'high' also light 'low'" in report.errors[0]


def test_map_classes_by_pixels_stay_apart_for_colour_blind_eyes():
    from scratchfab import figures
    from scratchfab.design import feasibility as fz
    from scratchfab.design.feasibility import board_points, map_figure
    from scratchfab.render.profile import steepest_wall_deg

    design = _design([("near", -22.0, 0.0), ("far", 40.0, 0.0)])
    report = check_feasibility(design, grid=48)
    fig = map_figure(report, "far")
    rgb = np.asarray(fig.image.convert("RGB")).astype(int)
    x0, y0, x1, y1 = fig.map_box
    assert x1 - x0 + 1 >= fz.MAP_MIN_PX and fig.cell * 48 == x1 - x0 + 1
    # Classes from the geometry, independently of the report's maps.
    reach = float(steepest_wall_deg(design.scratch.width_mm, design.scratch.depth_mm))
    limit = reach + lobe_deg(design.board.roughness)
    view = next(v for v in design.views if v.name == "far")
    tilt = tilt_deg(half_vectors(design, view, board_points(design.board, 48)))
    classes = {"reach": tilt <= reach, "lobe": (tilt > reach) & (tilt <= limit), "no": tilt > limit}
    assert all(c.sum() > 20 for c in classes.values())
    blocks = rgb[y0 : y1 + 1, x0 : x1 + 1].reshape(48, fig.cell, 48, fig.cell, 3)
    blocks = blocks.transpose(0, 2, 1, 3, 4)
    means = {k: blocks[c].mean(axis=(1, 2)) for k, c in classes.items()}
    # Nearest neighbour: reachable cells are flat blocks; unreachable ones hatched.
    flat = blocks[classes["reach"]]
    assert np.all(flat == flat[:, :1, :1])
    hatched = blocks[classes["no"]]
    assert np.all(np.any(np.all(hatched == fz.HATCH, axis=-1), axis=(1, 2)))
    for kind in ("protanopia", "deuteranopia"):
        sim = {k: figures.simulate_cvd(v, kind) for k, v in means.items()}
        # Blue against yellow and orange survive: blue minus red keeps its sign.
        assert np.all(sim["reach"][:, 2] - sim["reach"][:, 0] > 0.25)
        for k in ("lobe", "no"):
            assert np.all(sim[k][:, 0] - sim[k][:, 2] > 0.25)
        # The hatched orange is far darker than the lobe's yellow.
        gap = figures.lightness(sim["lobe"]).min() - figures.lightness(sim["no"]).max()
        assert gap > 25
    # The old red/green map failed exactly this: both shaded classes looked olive.
    red = figures.simulate_cvd(np.array([217, 26, 26]))
    green = figures.simulate_cvd(np.array([0.1, 0.75, 0.2]) * 255 * 0.6)
    assert np.sign(red[2] - red[0]) == np.sign(green[2] - green[0])


def test_map_scale_bar_and_key_show_the_map_colours():
    from scratchfab.design import feasibility as fz
    from scratchfab.design.feasibility import map_figure, tilt_colours

    report = check_feasibility(_design([("near", -22.0, 0.0), ("dup", -22.3, 0.2)]), grid=32)
    fig = map_figure(report, "near")
    rgb = np.asarray(fig.image.convert("RGB")).astype(int)
    reach = report.steepest_wall_deg
    limit = reach + report.lobe_deg
    bx0, by0, bx1, by1 = fig.bar_box
    row = rgb[(by0 + by1) // 2, bx0 : bx1 + 1]
    deg = (np.arange(bx1 - bx0 + 1) + 0.5) * fig.bar_deg / (bx1 - bx0 + 1)
    want = tilt_colours(deg, reach, limit, report.glint_deg).astype(int)
    plain = np.all(row != fz.HATCH, axis=-1)
    assert np.all(row[plain] == want[plain])
    # The bar's yellow starts at the steepest wall and its orange at wall + lobe.
    yellow = deg[np.all(row == fz.LOBE_ONLY, axis=-1)]
    assert yellow.min() == pytest.approx(reach, abs=fig.bar_deg / 100)
    assert yellow.max() == pytest.approx(limit, abs=fig.bar_deg / 100)
    # Every map colour class appears in the key box.
    lx0, ly0, lx1, ly1 = fig.legend_box
    key = rgb[ly0 : ly1 + 1, lx0 : lx1 + 1]
    for color in (fz.REACH_DARK, fz.LOBE_ONLY, fz.UNREACHABLE, fz.HATCH):
        assert np.all(key == color, axis=-1).any(), color
    # Near-duplicate views light each other: the map carries the crosstalk dots.
    mx0, my0, mx1, my1 = fig.map_box
    assert np.all(rgb[my0 : my1 + 1, mx0 : mx1 + 1] == 0, axis=-1).sum() > 50
    assert "blue" in report.to_json()["maps"] and "green" not in report.to_json()["maps"]


@pytest.mark.parametrize(("count", "crowded"), [(14440, False), (14441, True), (50000, True)])
def test_more_scratches_than_fit_side_by_side_are_refused(count, crowded):
    """38 x 38 mm inside the 1 mm margin, 1 mm x 0.1 mm dents at the shortest: 14440 fit.

    That many tile the inner square exactly (38 rows of 1 mm scratches, 380 across).
    """
    base = _design([("left", -22.0, 0.0), ("right", 22.0, 0.0)])
    assert (base.board.width_mm, base.board.margin_mm, base.scratch.min_length_mm) == (40, 1, 1)
    assert base.scratch.width_mm == 0.1
    report = check_feasibility(replace(base, scratch=replace(base.scratch, count=count)), grid=16)
    said = [e for e in report.errors if "would overlap" in e]
    assert bool(said) == crowded
    if crowded:
        assert f"{count} scratches of at least 1 x 0.1 mm" in said[0]
        assert "count to at most 14440" in said[0]


def _uniform_strokes_coverage(design, points: int = 240) -> float:
    """Groove coverage of a uniformly bright target, from the layout's rule for strokes.

    Centres spread evenly over the box min_length / 2 inside the margin where the view
    is reachable (the target's brightness is 0 elsewhere); each end runs max_length / 2
    along the scratch (across the view's half-vector) unless it leaves that box first,
    but at least min_length / 2. The views share the count evenly.
    """
    board, tool = design.board, design.scratch
    box = np.array(board.half_extent) - board.margin_mm
    inner = box - tool.min_length_mm / 2
    g = (np.arange(points) + 0.5) / points * 2 - 1
    centre = np.stack(np.meshgrid(g * inner[0], g * inner[1]), axis=-1).reshape(-1, 2)
    reach = check_feasibility(design, grid=8).steepest_wall_deg + lobe_deg(board.roughness)
    total = 0.0
    for view in design.views:
        h = half_vectors(design, view, centre)
        lit = tilt_deg(h) <= reach
        c, h = centre[lit], h[lit]
        along = np.stack([-h[:, 1], h[:, 0]], axis=1)
        along /= np.linalg.norm(along, axis=1, keepdims=True)
        length = 0.0
        for sign in (-1.0, 1.0):
            d = sign * along
            with np.errstate(divide="ignore"):
                room = np.min(np.where(d != 0, (inner - np.sign(d) * c) / np.abs(d), np.inf), 1)
            length = length + np.maximum(
                np.minimum(tool.max_length_mm / 2, room), tool.min_length_mm / 2
            )
        total += tool.count / len(design.views) * float(np.mean(length))
    return total * tool.width_mm / ((2 * box[0]) * (2 * box[1]))


def test_groove_coverage_of_a_uniform_target_warns_just_over_one():
    """Coverage against the strokes' rule; a count 1 % under 1 passes, 1 % over warns."""
    base = _design([("left", -22.0, 0.0), ("right", 22.0, 0.0)])
    boards = {"left": np.ones((64, 64)), "right": np.ones((64, 64))}
    at_one = base.scratch.count / _uniform_strokes_coverage(base)
    for factor, over in ((0.99, False), (1.01, True)):
        count = round(factor * at_one)
        design = replace(base, scratch=replace(base.scratch, count=count))
        report = check_feasibility(design, grid=16, boards=boards)
        assert report.groove_coverage == pytest.approx(_uniform_strokes_coverage(design), rel=3e-3)
        said = [w for w in report.warnings if "will overlap" in w]
        assert bool(said) == over
        assert report.ok  # a warning, not an error
        data = report.to_json()
        assert data["groove_coverage"] == pytest.approx(report.groove_coverage, abs=1e-4)
        if over:
            assert f"the {count} scratches' grooves" in said[0]
            assert f"cover {report.groove_coverage:.2f} times the 1444 mm^2" in said[0]
            # the counts and lengths it names bring the coverage to 1 or just under
            fits = int(said[0].split("count to at most ")[1].split()[0])
            longest = float(said[0].split("max_length_mm to at most ")[1])
            under = replace(design, scratch=replace(design.scratch, count=fits))
            assert _uniform_strokes_coverage(under) == pytest.approx(1.0, abs=3e-3)
            for length, fits_in in ((longest, True), (longest + 0.1, False)):
                tried = replace(design, scratch=replace(design.scratch, max_length_mm=length))
                got = check_feasibility(tried, grid=16, boards=boards).groove_coverage
                assert (got <= 1.0) == fits_in


def test_groove_coverage_follows_the_layout_drawn():
    """A bright disc on a dim ground: the coverage predicted is the layout's within 2 %.

    The layout's lengths follow the brightness (longer in the disc, fewer there) and
    stop at the disc's edge: the prediction weighs and stops them as the layout does.
    """
    from scratchfab.design.layout import initial_layout
    from scratchfab.design.targets import warp_to_view

    base = _design([("left", -22.0, 0.0), ("right", 22.0, 0.0)])
    design = replace(base, scratch=replace(base.scratch, count=3000))
    y, x = np.mgrid[-1:1:128j, -1:1:128j]
    disc = np.where(x**2 + y**2 < 0.4, 1.0, 0.1)
    boards = {"left": disc, "right": disc[:, ::-1] * 0.6}
    report = check_feasibility(design, grid=16, boards=boards)
    targets = {v.name: warp_to_view(boards[v.name], design.board, v) for v in design.views}
    drawn = initial_layout(design, targets, seed=3)
    length = float(np.hypot(*(drawn.p1 - drawn.p0).T).sum())
    assert report.groove_coverage == pytest.approx(length * 0.1 / 1444, rel=0.02)
    assert report.mean_length_mm == pytest.approx(length / 3000, rel=0.02)
    assert report.groove_coverage < 1 and not [w for w in report.warnings if "overlap" in w]


def test_design_reports_the_coverage_in_its_files(tmp_path, capsys):
    """design writes the coverage to feasibility.json, and the warning to it, the
    terminal and every map; without overlap the map is as tall as before."""
    a = tmp_path / "a.png"
    Image.new("L", (16, 16), 255).save(a)
    heights = {}
    for count, over in ((800, False), (3000, True)):
        toml = tmp_path / f"scene{count}.toml"
        toml.write_text(
            "[board]\nwidth_mm = 40.0\nheight_mm = 40.0\nmargin_mm = 1.0\n"
            "[light]\nposition_mm = [0.0, 187.3, 463.6]\n"
            f"[scratch]\ncount = {count}\nmin_length_mm = 1.0\nmax_length_mm = 6.0\n"
            + "".join(
                f'[[views]]\nname = "{n}"\ntarget = "a.png"\nazimuth_deg = {az}\n'
                'elevation_deg = 0.0\ndistance_mm = 500.0\nfov_deg = "auto"\n'
                "resolution = [24, 24]\n"
                for n, az in (("left", -22.0), ("right", 22.0))
            )
        )
        job = tmp_path / f"job{count}"
        main(["design", str(toml), "--out", str(job)])
        out = capsys.readouterr()
        report = json.loads((job / "design" / "feasibility.json").read_text())
        assert (report["groove_coverage"] > 1) == over
        said = [w for w in report["warnings"] if "will overlap" in w]
        assert bool(said) == over
        assert ("will overlap" in out.out + out.err) == over
        heights[over] = Image.open(job / "design" / "feasibility_left.png").height
    assert heights[True] > heights[False]


def test_the_summary_lists_the_closest_pairs_and_counts_the_rest() -> None:
    """Four views make twelve ordered pairs: the terminal gets the PAIR_LINES of most
    expected crosstalk (in the report's order) and a count of the others."""
    from scratchfab.design.feasibility import PAIR_LINES
    from scratchfab.design.quick import quick_design

    report = check_feasibility(quick_design([f"v{i}.png" for i in range(4)], (100.0, 100.0)))
    assert len(report.pairs) == 12 > PAIR_LINES
    lines = [line for line in report.summary_lines() if line.startswith("scratches for ")]
    kept = sorted((p.expected_crosstalk for p in report.pairs), reverse=True)[PAIR_LINES - 1]
    want = [
        f"scratches for '{p.lit}' seen by '{p.other}'"
        for p in report.pairs
        if p.expected_crosstalk >= kept
    ]
    assert [line.split(":")[0] for line in lines] == want
    assert f"... and {12 - PAIR_LINES} more pairs of views, less crosstalk expected " in "\n".join(
        report.summary_lines()
    )
    three = check_feasibility(quick_design([f"v{i}.png" for i in range(3)], (100.0, 100.0)))
    assert sum(line.startswith("scratches for ") for line in three.summary_lines()) == 6
    assert not any(line.startswith("... and") for line in three.summary_lines())
