"""The analytic renderer against the brute-force reference and physical properties."""

from __future__ import annotations

from pathlib import Path

import drjit as dr
import numpy as np
import pytest
from conftest import FULL, make_design
from reference_render import ggx_d, reference_render

from scratchfab.model.design import design_from_mapping
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.render.renderer import ViewRenderer, onboard_area, render_pairs, render_scratches


def random_scratches(
    rng: np.random.Generator,
    n: int,
    half_extent: float,
    lengths: tuple[float, float] = (0.5, 6.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Random segments fully inside |x|, |y| <= half_extent."""
    centre = rng.uniform(-half_extent, half_extent, (n, 2))
    angle = rng.uniform(0, 2 * np.pi, n)
    length = rng.uniform(*lengths, n)
    d = 0.5 * length[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    # keep the whole segment inside by pulling the centre in where needed
    centre = np.clip(centre, -half_extent + np.abs(d), half_extent - np.abs(d))
    return centre - d, centre + d


def rel_l2(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def mixed_design(resolution: int = 32):
    """Two views: one square with the design's light, one 40x28 with its own light and a tilted up."""
    tables = {
        "board": {"width_mm": 40.0, "height_mm": 36.0, "roughness": 0.05, "margin_mm": 1.0},
        "light": {"position_mm": [0.0, 150.0, 300.0]},
        "scratch": {"width_mm": 0.1, "depth_mm": 0.01},
        "views": [
            {
                "name": "left",
                "position_mm": [-120.0, 0.0, 300.0],
                "fov_deg": "auto",
                "resolution": [resolution, resolution],
            },
            {
                "name": "right",
                "position_mm": [110.0, -30.0, 280.0],
                "look_at_mm": [2.0, 1.0, 0.0],
                "up": [0.1, 1.0, 0.0],
                "fov_deg": "auto",
                "resolution": [resolution + 8, resolution - 4],
                "light_position_mm": [-40.0, 160.0, 260.0],
            },
        ],
    }
    return design_from_mapping(tables, "<mixed>", Path("."))


def test_render_matches_brute_force_reference(tmp_path, rng):
    """SPEC section 4 end to end: per-row widths/depths from a CSV, ends inside footprints."""
    design = mixed_design()
    n = 300 if FULL else 200
    p0, p1 = random_scratches(rng, n, 17.0)
    width = rng.uniform(0.05, 0.2, n)
    depth = width * rng.uniform(0.05, 0.2, n)
    csv = tmp_path / "s.csv"
    ScratchSet.from_arrays(p0, p1, width, depth).save(csv)
    assert "width,depth" in csv.read_text().splitlines()[0]
    scratches = load_scratches(csv, design.scratch, design.board)
    images = render_scratches(design, scratches)
    ref = reference_render(design, scratches, seed=7, across=128, along_step_mm=0.01)
    for view in design.views:
        img, r = images[view.name], ref[view.name]
        assert img.shape == (view.height, view.width) and img.dtype == np.float32
        err = rel_l2(img, r)
        # the scratches carry most of the image: the comparison is not of flat boards
        flat = render_scratches(design, scratches.subset(np.zeros(n, bool)))[view.name]
        assert rel_l2(flat, r) > 0.2
        assert err <= 0.01, (view.name, err)


def test_flat_board_matches_reference_including_board_edges():
    """No scratches: |P ∩ B| D(h_z) with footprints cut by the board's edges."""
    design = mixed_design(24)
    empty = ScratchSet.from_arrays(np.zeros((0, 2)), np.zeros((0, 2)), 0.1, 0.01)
    images = render_scratches(design, empty)
    ref = reference_render(design, empty, samples_per_pixel=4096, seed=1)
    for name, img in images.items():
        assert np.count_nonzero(img == 0) > 0  # pixels off the board are dark
        assert rel_l2(img, ref[name]) < 1e-3


@pytest.mark.parametrize("f0", [0.05, 0.91])
def test_fresnel_at_a_grazing_mirror_angle_matches_reference(f0):
    """Schlick's F(wi . h) where it differs from f0: light and camera low on opposite sides."""
    tables = {
        "board": {"width_mm": 40.0, "height_mm": 40.0, "roughness": 0.1, "f0": f0},
        "light": {"position_mm": [0.0, 200.0, 40.0]},
        "views": [
            {"name": "low", "position_mm": [0.0, -200.0, 40.0], "resolution": [24, 24]},
        ],
    }
    design = design_from_mapping(tables, "<grazing>", Path("."))
    empty = ScratchSet.from_arrays(np.zeros((0, 2)), np.zeros((0, 2)), 0.1, 0.01)
    img = render_scratches(design, empty)["low"]
    ref = reference_render(design, empty, samples_per_pixel=1024, seed=2)["low"]
    # F at the mirror point, (1 - wi.h)^5 with wi.h = cos 78.7 deg: well above f0.
    assert f0 + (1 - f0) * (1 - np.cos(np.arctan(200 / 40))) ** 5 > f0 + 0.3 * (1 - f0)
    assert rel_l2(img, ref) < 1e-3


def test_onboard_area_against_sampling(rng):
    """|P ∩ B| of real footprints that straddle the board's edges, by point sampling."""
    from scratchfab.model.camera import Camera

    design = mixed_design(12)
    hw, hh = design.board.half_extent
    quads, _ = Camera.from_view(design.views[1]).footprints()
    quads = quads.reshape(-1, 4, 2)
    got = onboard_area(quads, hw, hh)
    area = np.abs(
        0.5
        * np.sum(
            quads[..., 0] * np.roll(quads[..., 1], -1, 1)
            - np.roll(quads[..., 0], -1, 1) * quads[..., 1],
            axis=1,
        )
    )
    straddle = np.flatnonzero((got > 0.05 * area) & (got < 0.95 * area))
    assert len(straddle) >= 8
    for k in straddle[:12]:
        q = quads[k]
        lo, hi = q.min(axis=0), q.max(axis=0)
        pts = rng.uniform(lo, hi, (100_000, 2))
        edge = np.roll(q, -1, axis=0) - q
        cross = edge[:, 0] * (pts[:, None, 1] - q[:, 1]) - edge[:, 1] * (pts[:, None, 0] - q[:, 0])
        in_quad = np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)
        on_board = (np.abs(pts[:, 0]) <= hw) & (np.abs(pts[:, 1]) <= hh)
        box = np.prod(hi - lo)
        assert abs(in_quad.mean() * box - area[k]) < 0.02 * area[k]
        estimate = (in_quad & on_board).mean() * box
        assert abs(got[k] - estimate) < 0.02 * area[k], (k, got[k], estimate)


def lit_direction(design, view_name: str, point: np.ndarray) -> np.ndarray:
    """The unit scratch direction whose walls reflect the light into ``view_name`` at ``point``."""
    view = design.view(view_name)
    p = np.array([point[0], point[1], 0.0])
    wi = design.light_for(view) - p
    wo = view.camera_position - p
    h = wi / np.linalg.norm(wi) + wo / np.linalg.norm(wo)
    along = np.array([-h[1], h[0]])
    return along / np.linalg.norm(along)


@pytest.mark.parametrize(("lit", "dark"), [("left", "right"), ("right", "left")])
def test_scratch_lights_only_the_view_it_is_turned_to(lit, dark):
    design = make_design(resolution=48)
    centre = np.array([3.0, -2.0])
    along = lit_direction(design, lit, centre)
    other = lit_direction(design, dark, centre)
    assert abs(along @ other) < 0.9  # the two half-vectors lie in different planes
    one = ScratchSet.from_arrays(centre - 2.5 * along, centre + 2.5 * along, 0.3, 0.03)
    none = one.subset(np.zeros(1, bool))
    with_s = render_scratches(design, one)
    without = render_scratches(design, none)
    gain_lit = with_s[lit] - without[lit]
    gain_dark = with_s[dark] - without[dark]
    assert gain_lit.max() > 5 * without[lit].max()
    # where the scratch covers the board, the dark view only loses its flat part
    assert gain_dark.max() <= 1e-3 * gain_lit.max()
    assert np.count_nonzero(gain_lit > 0.1 * gain_lit.max()) >= 5


def test_mirror_symmetric_boards_give_mirrored_images(rng):
    design = make_design(resolution=40)  # cameras at x = -120 / +120, light on x = 0
    p0, p1 = random_scratches(rng, 150, 18.0)
    flip = np.array([-1.0, 1.0])
    width = rng.uniform(0.06, 0.15, 150)
    depth = rng.uniform(0.005, 0.015, 150)
    s = ScratchSet.from_arrays(p0, p1, width, depth)
    mirrored = ScratchSet.from_arrays(p0 * flip, p1 * flip, width, depth)
    a = render_scratches(design, s)
    b = render_scratches(design, mirrored)
    assert rel_l2(a["left"], a["right"][:, ::-1]) > 0.1  # not symmetric by itself
    np.testing.assert_allclose(a["left"], b["right"][:, ::-1], rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(a["right"], b["left"][:, ::-1], rtol=1e-5, atol=1e-12)
    both = ScratchSet.from_arrays(
        np.concatenate([p0, p0 * flip]),
        np.concatenate([p1, p1 * flip]),
        np.concatenate([width, width]),
        np.concatenate([depth, depth]),
    )
    c = render_scratches(design, both)
    np.testing.assert_allclose(c["left"], c["right"][:, ::-1], rtol=1e-5, atol=1e-12)


def test_gradients_of_pixel_sum_match_finite_differences(m, rng):
    design = make_design(resolution=20, size_mm=16.0)
    view = design.views[0]
    vr = ViewRenderer(design, view, m)
    n = 40
    p0, p1 = random_scratches(rng, n, 7.0, lengths=(0.5, 4.0))
    s = ScratchSet.from_arrays(p0, p1, rng.uniform(0.1, 0.3, n), rng.uniform(0.01, 0.05, n))
    # turn half of them toward the view so the sum depends strongly on the endpoints
    for k in range(0, n, 2):
        c = 0.5 * (s.p0[k] + s.p1[k])
        along = lit_direction(design, view.name, c)
        along = along * np.cos(0.1) + np.array([-along[1], along[0]]) * np.sin(0.1)
        s.p0[k], s.p1[k] = c - along, c + along * 1.3
    weights = m.Float64(rng.uniform(0.5, 1.5, vr.pixel_count))
    pairs = vr.find_pairs(s.p0, s.p1, s.width / 2, margin_mm=0.01)

    def loss(arrays):
        return dr.sum(vr.render(*arrays, pairs) * weights)

    arrays = list(vr.scratch_arrays(s))
    base = [np.array(a, dtype=np.float64, copy=True) for a in arrays]
    for a in arrays[:4]:
        dr.enable_grad(a)
    dr.backward(loss(arrays))
    grads = [np.array(dr.grad(a), dtype=np.float64, copy=True) for a in arrays[:4]]
    scale = max(np.abs(g).max() for g in grads)
    assert scale > 0

    def shifted(coord: int, k: int, step: float) -> float:
        values = [b.copy() for b in base]
        values[coord][k] += step
        return float(loss([m.Float64(v) for v in values])[0])

    step = 1e-5
    checked = 0
    for coord in range(4):
        for k in rng.choice(n, 3, replace=False):
            fd = (shifted(coord, k, step) - shifted(coord, k, -step)) / (2 * step)
            g = grads[coord][k]
            assert abs(fd - g) <= 1e-6 * scale + 1e-4 * abs(g), (coord, k, fd, g)
            checked += abs(g) > 1e-2 * scale
    assert checked >= 4  # most checks are of gradients that matter


def test_render_is_sum_of_parts(m, rng):
    """Scatter-add accumulation: disjoint groups of overlapping scratches add up, pair by pair."""
    design = make_design(resolution=24)
    vr = ViewRenderer(design, design.views[1], m)
    p0, p1 = random_scratches(rng, 90, 18.0, lengths=(2.0, 12.0))
    s = ScratchSet.from_arrays(p0, p1, 0.1, 0.01)
    pairs = vr.find_pairs(s.p0, s.p1, s.width / 2)
    full = np.asarray(vr.render(*vr.scratch_arrays(s), pairs))
    groups = [np.arange(90) % 3 == g for g in range(3)]
    parts = np.zeros_like(full)
    for sel in groups:
        sub = s.subset(sel)
        parts += np.asarray(vr.render(*vr.scratch_arrays(sub), vr.find_pairs(sub.p0, sub.p1, 0.05)))
    flat = vr.factor.ravel() * vr.area_on_board.ravel() * vr.d_flat.ravel()
    # the flat remainder is linear while unclamped: sum of group images minus 2 flat boards
    shared = np.bincount(pairs.pixel_np, minlength=vr.pixel_count) >= 2
    assert np.count_nonzero(shared) > 20  # scratches of different groups share pixels
    np.testing.assert_allclose(full, parts - 2 * flat, rtol=1e-9, atol=1e-9 * full.max())


def test_flat_remainder_clamps_at_zero(m):
    """Stacked scratches cover more than |P ∩ B|: the flat remainder clamps, the reference agrees."""
    design = make_design(resolution=16)
    vr = ViewRenderer(design, design.views[0], m)
    k = 30
    s = ScratchSet.from_arrays(
        np.tile([[-6.0, 0.3]], (k, 1)), np.tile([[6.0, 0.5]], (k, 1)), 1.0, 0.05
    )
    pairs = vr.find_pairs(s.p0, s.p1, s.width / 2)
    img = np.asarray(vr.render(*vr.scratch_arrays(s), pairs))
    one = s.subset(np.array([0]))
    single = np.asarray(vr.render(*vr.scratch_arrays(one), vr.find_pairs(one.p0, one.p1, 0.5)))
    flat = vr.factor.ravel() * vr.area_on_board.ravel() * vr.d_flat.ravel()
    unclamped = k * single - (k - 1) * flat  # the SPEC formula without max(0, .)
    assert np.all(img >= unclamped - 1e-9 * img.max())
    assert np.count_nonzero(img > unclamped + 1e-3 * flat.max()) >= 5
    ref = reference_render(design, s, seed=3, across=64, along_step_mm=0.01)["left"]
    assert rel_l2(img.reshape(ref.shape), ref) < 0.01


def test_ggx_reference_normalisation():
    """The D of the reference integrates to 1 over projected solid angle (sanity of SPEC D)."""
    theta = np.linspace(0, np.pi / 2, 200_001)
    for alpha in (0.05, 0.3):
        integrand = ggx_d(np.cos(theta), alpha) * np.cos(theta) * np.sin(theta) * 2 * np.pi
        assert abs(np.trapezoid(integrand, theta) - 1) < 1e-3


def test_render_pairs_can_be_frozen(m, rng):
    """The optimizer may wrap a step in @dr.freeze: same images and gradients, replayed."""
    design = make_design(resolution=20)
    vr = ViewRenderer(design, design.views[0], m)
    p0, p1 = random_scratches(rng, 50, 18.0)
    s = ScratchSet.from_arrays(p0, p1, 0.1, 0.01)
    pairs = vr.find_pairs(s.p0, s.p1, s.width / 2, margin_mm=0.05)
    fixed = vr.scratch_arrays(s)

    def step(state, pixel, scratch, x0, y0, x1, y1, hw, wb):
        dr.enable_grad(x0)
        img = render_pairs(state, vr.alpha, vr.pixel_count, x0, y0, x1, y1, hw, wb, pixel, scratch)
        dr.backward(dr.sum(img * img))
        return img, dr.grad(x0)

    frozen = dr.freeze(step)
    for shift in (0.0, 0.01, -0.02, 0.03):
        x0 = np.array(fixed[0], dtype=np.float64) + shift
        args = (m.Float64(x0), *fixed[1:])
        img_f, grad_f = frozen(vr.state, pairs.pixel, pairs.scratch, *args)
        img_p, grad_p = step(vr.state, pairs.pixel, pairs.scratch, m.Float64(x0), *fixed[1:])
        np.testing.assert_allclose(np.asarray(img_f), np.asarray(img_p), rtol=1e-12)
        np.testing.assert_allclose(np.asarray(grad_f), np.asarray(grad_p), rtol=1e-9, atol=1e-20)
    # at most a second recording, which makes changed literals opaque; then replays
    assert frozen.n_recordings <= 2
