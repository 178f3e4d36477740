"""The Mitsuba ``scratch_board`` plugin against closed forms, quadrature and brute force."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from scratchfab.model.camera import Camera
from scratchfab.model.design import design_from_mapping
from scratchfab.model.scratches import ScratchSet
from scratchfab.verify.dent import solve_wbar
from scratchfab.verify.index import build_grid
from scratchfab.verify.scene import Sky, board_bsdf, scene_dict, sky_emitter, use_variant
from scratchfab.verify.verify import BoardRenderer, relative_l2


def ggx(c: np.ndarray, alpha: float) -> np.ndarray:
    a2 = alpha * alpha
    q = 1.0 + (a2 - 1.0) * c * c
    return np.where(c > 0, a2 / (math.pi * q * q), 0.0)


def schlick(c: np.ndarray, f0: float) -> np.ndarray:
    return f0 + (1 - f0) * (1 - c) ** 5


def profile_normal(across: np.ndarray, e: np.ndarray, wbar: float) -> np.ndarray:
    """SPEC section 3 normal at across-coordinate x along the across axis e (world)."""
    den = wbar**2 + 4 * across**2
    tilt = -4 * wbar * across / den
    return np.stack([tilt * e[0], tilt * e[1], (wbar**2 - 4 * across**2) / den], axis=-1)


def one_view_design(
    position, light=(0.0, 150.0, 300.0), size=12.0, resolution=32, roughness=0.05, fov="auto"
):
    tables = {
        "board": {"width_mm": size, "height_mm": size, "roughness": roughness, "margin_mm": 0.5},
        "light": {"position_mm": list(light)},
        "scratch": {"width_mm": 0.1, "depth_mm": 0.01},
        "views": [
            {
                "name": "v",
                "position_mm": list(position),
                "fov_deg": fov,
                "resolution": [resolution, resolution],
            }
        ],
    }
    return design_from_mapping(tables, "<test>", Path("."))


def quadrature_render(design, view, scratch_fn, n=48):
    """SPEC section 4 by midpoint quadrature over each pixel's footprint.

    ``scratch_fn(points (..., 2), h (3,)) -> (D summed over covering scratches, count)``.
    The footprint integral is weighted by the board area per image-plane area
    (proportional to 1 / |d_z|^3 for f . d = 1); h, F and the radiometric factor are
    taken at the pixel centre, and the flat remainder max(0, |P n B| - sum_i |P n S_i|)
    is clamped per footprint, as SPEC section 4 prescribes.
    """
    cam = Camera.from_view(view)
    hw, hh = design.board.half_extent
    light = design.light_for(view)
    alpha = design.board.roughness
    f0 = design.board.f0
    offsets = (np.arange(n) + 0.5) / n
    out = np.zeros((cam.height, cam.width))
    centres, ok = cam.center_grid()
    for j in range(cam.height):
        t = j + offsets[:, None] * np.ones((1, n))
        for i in range(cam.width):
            if not ok[j, i]:
                continue
            s = i + offsets[None, :] * np.ones((n, 1))
            pts, hit = cam.board_hits(s, t)
            jac = np.where(hit, 1.0 / np.abs(cam.directions(s, t)[..., 2]) ** 3, 0.0)
            c3 = np.array([*centres[j, i], 0.0])
            wi = light - c3
            r2 = wi @ wi
            wi /= math.sqrt(r2)
            wo = cam.position - c3
            wo /= np.linalg.norm(wo)
            h = (wi + wo) / np.linalg.norm(wi + wo)
            on = hit & (np.abs(pts[..., 0]) <= hw) & (np.abs(pts[..., 1]) <= hh)
            d_sum, count = scratch_fn(pts, h)
            scratch_area = np.sum(np.where(on, count, 0.0) * jac)
            flat_area = max(0.0, np.sum(np.where(on, jac, 0.0)) - scratch_area)
            d_int = np.sum(np.where(on, d_sum, 0.0) * jac) + flat_area * ggx(h[2], alpha)
            dhat = d_int / np.sum(jac)
            out[j, i] = design.light.intensity * schlick(wi @ h, f0) * dhat / (4 * r2 * wo[2])
    return out


def test_solve_wbar_satisfies_eq2_and_agrees_with_the_renderers_solver():
    width = np.geomspace(0.02, 2.0, 9)[:, None]
    depth = width * np.geomspace(0.005, 5.0, 11)[None, :]
    wbar = solve_wbar(width, depth)
    w = width / 2
    assert np.all(wbar > 2 * w)
    residual = -(wbar / 2) * np.log1p(-4 * w * w / (wbar * wbar)) - depth
    assert np.max(np.abs(residual / depth)) < 1e-10
    profile = pytest.importorskip("scratchfab.render.profile")
    np.testing.assert_allclose(wbar, profile.solve_wbar(width, depth), rtol=1e-10)


def test_grid_lists_every_scratch_that_covers_a_point(rng, monkeypatch):
    n = 300
    centre = rng.uniform(-9, 9, (n, 2))
    angle = rng.uniform(0, np.pi, n)
    length = rng.uniform(0.2, 6.0, n)
    u = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    p0 = centre - 0.5 * length[:, None] * u
    p1 = centre + 0.5 * length[:, None] * u
    half = rng.uniform(0.02, 0.4, n)
    grid = build_grid(p0, p1, half, (10.0, 10.0))
    # Points near scratches (including just outside their rectangles) and on cell edges.
    k = rng.integers(0, n, 4000)
    pts = (
        centre[k]
        + rng.normal(0, 1.0, (4000, 2)) * np.stack([length[k], half[k] * 4], 1).mean(1)[:, None]
    )
    edges = grid.origin[0] + grid.cell * rng.integers(0, grid.nx, (1000, 1))
    pts = np.vstack([pts, np.hstack([edges, rng.uniform(-10, 10, (1000, 1))])])
    pts = np.clip(pts, -10, 10)
    rel = pts[:, None, :] - p0[None]
    along = np.einsum("pnk,nk->pn", rel, u)
    across = rel[..., 1] * u[:, 0] - rel[..., 0] * u[:, 1]
    covers = (np.abs(across) <= half) & (along >= 0) & (along <= length)
    assert covers.sum() > 500
    for p, row in zip(pts, covers, strict=True):
        listed = set(grid.candidates(*p).tolist())
        assert set(np.flatnonzero(row).tolist()) <= listed
    assert grid.max_count < 40
    # built in batches of a few scratches' cells, the grid is the same
    monkeypatch.setattr("scratchfab.verify.index.BATCH_CELLS", 50)
    batched = build_grid(p0, p1, half, (10.0, 10.0))
    assert np.array_equal(batched.starts, grid.starts)
    assert np.array_equal(batched.items, grid.items)


def test_flat_board_matches_the_closed_form_highlight():
    """No scratches: every pixel is I F D(h_z) |P n B| / (|P| 4 r^2 wo_z); interior pixels exactly."""
    design = one_view_design(position=(0.0, -150.0, 300.0), size=40.0)
    view = design.views[0]
    empty = ScratchSet.from_arrays(np.zeros((0, 2)), np.zeros((0, 2)), 0.1, 0.01)
    image = BoardRenderer(design, empty).render(view, 256).image
    cam = Camera.from_view(view)
    quads, ok = cam.footprints()
    inside = ok & np.all(np.abs(quads) <= 20.0, axis=(2, 3))
    centres, _ = cam.center_grid()
    c3 = np.concatenate([centres, np.zeros(centres.shape[:2] + (1,))], axis=-1)
    wi = design.light.position_mm - c3
    r2 = np.sum(wi * wi, -1)
    wi /= np.sqrt(r2)[..., None]
    wo = cam.position - c3
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    expected = schlick(np.sum(wi * h, -1), 0.91) * ggx(h[..., 2], 0.05) / (4 * r2 * wo[..., 2])
    assert inside.sum() > 0.6 * inside.size
    assert expected[inside].max() > 10 * expected[inside].min()
    assert relative_l2(image[inside], expected[inside]) < 2e-3
    # Pixels whose whole footprint is off the board stay black.
    off = ok & np.all((np.abs(quads[..., 0]) > 20.0) | (np.abs(quads[..., 1]) > 20.0), axis=2)
    assert np.all(image[off] == 0)


def test_wide_scratch_matches_quadrature_of_spec_section_4():
    """A 2 mm wide dent spans several pixels: its lit wall against numpy quadrature."""
    design = one_view_design(position=(-120.0, 0.0, 300.0), size=12.0, roughness=0.1)
    view = design.views[0]
    h = np.array([-0.371, 0.447, 1.822])
    e = h[:2] / np.linalg.norm(h[:2])
    along = np.array([-e[1], e[0]])
    p0 = -3.5 * along + np.array([0.3, -0.2])
    p1 = 3.5 * along + np.array([0.3, -0.2])
    width, depth = 2.0, 0.2
    wbar = float(solve_wbar(np.array(width), np.array(depth)))
    assert 2 * math.degrees(math.atan(width / wbar)) > 20  # the wall reaches the view's h
    scratches = ScratchSet.from_arrays(p0, p1, width, depth)

    def one_scratch(pts, hh):
        rel = pts - p0
        a = rel @ along
        x = rel[..., 1] * along[0] - rel[..., 0] * along[1]
        inside = (np.abs(x) <= width / 2) & (a >= 0) & (a <= 7.0)
        n = profile_normal(x, np.array([-along[1], along[0]]), wbar)
        return np.where(inside, ggx(n @ hh, 0.1), 0.0), inside.astype(float)

    expected = quadrature_render(design, view, one_scratch)
    result = BoardRenderer(design, scratches).render(view, 1024)
    lit = expected > 0.05 * expected.max()
    assert 10 < lit.sum() < 0.5 * lit.size
    err = relative_l2(result.image, expected)
    assert err < 0.01 + 3 * result.noise, (err, result.noise)


def test_stacked_scratches_clamp_the_flat_remainder_per_footprint():
    """Four overlapping dents under the flat highlight: SPEC's clamp, not the signed sum."""
    design = one_view_design(position=(0.0, -150.0, 300.0), size=12.0, roughness=0.1)
    view = design.views[0]
    offsets = np.array([0.0, 0.15, 0.3, 0.45])
    p0 = np.column_stack([offsets - 0.5, np.full(4, -3.0)])
    p1 = np.column_stack([offsets - 0.5, np.full(4, 3.0)])
    width, depth = 1.2, 0.05
    wbar = float(solve_wbar(np.array(width), np.array(depth)))
    scratches = ScratchSet.from_arrays(p0, p1, width, depth)

    def stack(pts, hh):
        d_sum = np.zeros(pts.shape[:-1])
        count = np.zeros(pts.shape[:-1])
        for a in p0:
            x = pts[..., 0] - a[0]
            inside = (np.abs(x) <= width / 2) & (np.abs(pts[..., 1]) <= 3.0)
            n = profile_normal(x, np.array([1.0, 0.0]), wbar)
            d_sum += np.where(inside, ggx(n @ hh, 0.1), 0.0)
            count += inside
        return d_sum, count

    expected = quadrature_render(design, view, stack, n=32)
    spec = BoardRenderer(design, scratches).render(view, 1024)
    err = relative_l2(spec.image, expected)
    assert err < 0.005 + 3 * spec.noise, (err, spec.noise)
    # The pointwise signed sum (no per-footprint clamp) is visibly darker there.
    mi = use_variant("llvm")
    signed = mi.load_dict(board_bsdf(design, scratches, "signed", "all"))
    scene = mi.load_dict(scene_dict(design, scratches, view, 256, bsdf=signed))
    plain = np.array(mi.render(scene, spp=256, seed=1)).reshape(expected.shape)
    assert relative_l2(plain, expected) > 10 * err


def test_eval_is_the_pointwise_density_of_each_lobe_choice():
    mi = use_variant("llvm")
    import drjit as dr

    alpha, f0 = 0.2, 0.91
    # Two crossing scratches through the origin; the sample point lies in both.
    p0 = np.array([[-2.0, -0.03], [0.02, -2.0]])
    p1 = np.array([[2.0, 0.05], [-0.04, 2.0]])
    width = np.array([0.3, 0.2])
    depth = np.array([0.02, 0.03])
    design = one_view_design(position=(0.0, 0.0, 300.0), size=10.0, roughness=alpha)
    scratches = ScratchSet(p0, p1, width, depth)
    points = np.array([[0.01, 0.02], [0.05, 0.3], [3.0, 3.0]])
    cam_dir = np.array([-0.3, 0.1, 0.9])
    light_dir = np.array([0.2, 0.4, 0.8])
    cam_dir /= np.linalg.norm(cam_dir)
    light_dir /= np.linalg.norm(light_dir)
    h = (cam_dir + light_dir) / np.linalg.norm(cam_dir + light_dir)
    wbar = solve_wbar(width, depth)
    d_sum = np.zeros(3)
    count = np.zeros(3)
    for i in range(2):
        u = (p1[i] - p0[i]) / np.linalg.norm(p1[i] - p0[i])
        e = np.array([-u[1], u[0]])
        rel = points - p0[i]
        x = rel @ e
        inside = (np.abs(x) <= width[i] / 2) & (rel @ u >= 0) & (rel @ u <= 4.0)
        d_sum += np.where(inside, ggx(profile_normal(x, e, wbar[i]) @ h, alpha), 0.0)
        count += inside
    assert list(count) == [2, 1, 0]
    scale = schlick(h @ light_dir, f0) / (4 * cam_dir[2])
    d_flat = ggx(np.array(h[2]), alpha)
    cases = (
        ("signed", "all", d_sum + (1 - count) * d_flat),
        ("clamped", "all", d_sum + np.maximum(1 - count, 0) * d_flat),
        ("signed", "scratches", d_sum),
        ("signed", "flat", (1 - count) * d_flat),
    )
    for rule, lobes, ndf in cases:
        bsdf = mi.load_dict(board_bsdf(design, scratches, rule, lobes))
        si = dr.zeros(mi.SurfaceInteraction3f, 3)
        si.p = mi.Point3f(points[:, 0], points[:, 1], np.zeros(3))
        si.n = mi.Normal3f(0, 0, 1)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        si.wi = si.to_local(mi.Vector3f(*map(float, cam_dir)))
        wo = si.to_local(mi.Vector3f(*map(float, light_dir)))
        value = np.array(bsdf.eval(mi.BSDFContext(), si, wo)).reshape(-1)
        np.testing.assert_allclose(value, scale * ndf, rtol=2e-4, err_msg=f"{rule} {lobes}")


def test_sampling_agrees_with_eval_and_pdf():
    """Weights equal eval/pdf, the pdf integrates to the accepted fraction, E[weight] = albedo."""
    mi = use_variant("llvm")
    import drjit as dr

    alpha = 0.3
    design = one_view_design(position=(0.0, 0.0, 300.0), size=10.0, roughness=alpha)
    scratches = ScratchSet.from_arrays(
        np.array([[-2.0, 0.0], [0.0, -2.0]]), np.array([[2.0, 0.0], [0.0, 2.0]]), 0.4, 0.03
    )
    bsdf = mi.load_dict(board_bsdf(design, scratches, "clamped"))
    ctx = mi.BSDFContext()
    n = 400_000
    rng = np.random.default_rng(5)
    for point, cam in (((0.05, 0.02), (0.3, -0.2, 0.9)), ((0.1, 1.0), (-0.5, 0.1, 0.6))):
        cam = np.array(cam) / np.linalg.norm(cam)

        def interaction(count, point=point, cam=cam):
            si = dr.zeros(mi.SurfaceInteraction3f, count)
            si.p = mi.Point3f(float(point[0]), float(point[1]), 0.0)
            si.n = mi.Normal3f(0, 0, 1)
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            si.wi = si.to_local(mi.Vector3f(*map(float, cam)))
            return si

        si = interaction(n)
        bs, weight = bsdf.sample(
            ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))
        )
        value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
        w = np.array(weight).reshape(-1)
        ok = np.array(bs.pdf) > 0
        np.testing.assert_allclose(np.array(bs.pdf)[ok], np.array(pdf)[ok], rtol=1e-4)
        np.testing.assert_allclose(
            w[ok], np.array(value).reshape(-1)[ok] / np.array(pdf)[ok], rtol=1e-4
        )
        # Uniform hemisphere quadrature of pdf and eval (independent of the sampler).
        z = rng.random(n)
        phi = 2 * np.pi * rng.random(n)
        r = np.sqrt(1 - z * z)
        si = interaction(n)
        wo = mi.Vector3f(r * np.cos(phi), r * np.sin(phi), z)
        value, pdf = bsdf.eval_pdf(ctx, si, si.to_local(wo))
        pdf_mass = 2 * np.pi * np.mean(np.array(pdf))
        albedo = 2 * np.pi * np.mean(np.array(value).reshape(-1))
        accepted = ok.mean()
        assert abs(pdf_mass - accepted) < 0.02
        assert abs(w.mean() - albedo) < 0.03 * albedo


def test_sky_emitter_is_scaled_to_the_requested_irradiance():
    mi = use_variant("llvm", color=True)
    import drjit as dr

    design = one_view_design(position=(0.0, 0.0, 300.0))
    for strength in (0.5, 2.0):
        emitter = mi.load_dict(sky_emitter(design, Sky(strength=strength)))
        n = 1 << 18
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(11, n)
        it = dr.zeros(mi.Interaction3f, n)
        ds, weight = emitter.sample_direction(it, sampler.next_2d())
        lum = np.array(mi.luminance(weight))
        irradiance = np.mean(lum * np.maximum(np.array(ds.d.z), 0))
        light = np.array(design.light.position_mm)
        expected = strength * light[2] / np.linalg.norm(light) ** 3
        assert irradiance == pytest.approx(expected, rel=0.03)
    # The sky stands over the wall: +y is its zenith, below the horizon (y < 0) is dark,
    # and the sun is where it was asked to be.
    rng = np.random.default_rng(3)
    d = rng.normal(size=(100_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = -mi.Vector3f(d[:, 0], d[:, 1], d[:, 2])
    radiance = np.array(mi.luminance(emitter.eval(si)))
    assert np.all(radiance[d[:, 1] < -1e-3] == 0) and np.all(radiance[d[:, 1] > 0.05] > 0)
    sun = np.array(Sky().sun_direction) / np.linalg.norm(Sky().sun_direction)
    assert d[np.argmax(radiance)] @ sun > 0.999


def test_sky_render_lights_the_board_beyond_the_design_light():
    design = one_view_design(position=(-120.0, 0.0, 300.0), size=12.0, resolution=16)
    view = design.views[0]
    empty = ScratchSet.from_arrays(np.zeros((0, 2)), np.zeros((0, 2)), 0.1, 0.01)
    plain = BoardRenderer(design, empty).render(view, 64).image
    sky = BoardRenderer(design, empty, sky=Sky(strength=1.0), mode="physical")
    lit = sky.render(view, 64).image
    assert np.all(np.isfinite(lit))
    assert lit.mean() > plain.mean() * 1.5
    scene = scene_dict(design, empty, view, 4, sky=Sky())
    assert scene["integrator"]["bsdf_samples"] == 1
