"""The optimizer's fast path: only the footprint terms that are not exact zeros, by class.

:func:`scratch_edges_ndf` on the terms that :func:`edge_piece_masks` keeps against the
independent quadrature of test_ndf and finite differences of it; every dropped term
exactly 0 with exactly zero derivatives; :func:`render_classes` against
:func:`render_pairs`, the brute-force reference renderer and finite differences, and
frozen against traced.
"""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest
import shapely
from conftest import FULL, make_design
from reference_render import reference_render
from test_ndf import case_arrays, check_against_differences, lit_cases, random_case, reference
from test_render import random_scratches, rel_l2

from scratchfab.backend import jit_array
from scratchfab.model.scratches import ScratchSet
from scratchfab.render.ndf import (
    EDGE_SLOTS,
    edge_piece_masks,
    scratch_edges_ndf,
    scratch_footprint_ndf,
)
from scratchfab.render.renderer import (
    CLASS_SIZES,
    NULL_CODE,
    ViewRenderer,
    piece_codes,
    render_classes,
    render_pairs,
    sort_classes,
)

SLACK = 1e-8


def _columns(m, cases):
    """Dr.Jit arrays of the cases: corner lists, then the scalar arguments in order."""
    return np.stack([c["quad"] for c in cases]), *case_arrays(m.Float64, cases)


def _orient(quad):
    x, y = quad[..., 0], quad[..., 1]
    signed = np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)
    return np.where(signed < 0, -1.0, 1.0)


def _kept(m, cases):
    """(N, 8) bool: the terms edge_piece_masks keeps for each case."""
    _quad, qx, qy, rest = _columns(m, cases)
    masks = edge_piece_masks(qx, qy, *rest[:5], SLACK)
    dr.eval(masks)
    return np.stack([np.asarray(k, dtype=bool) for k in masks], axis=1)


def _terms(m, cases, slots, rest=None, custom=False):
    """scratch_edges_ndf of the terms ``slots`` (N, S) of each case (slot 2 i + far)."""
    F = m.Float64
    quad, _qx, _qy, default = _columns(m, cases)
    rest = default if rest is None else rest
    lanes = np.arange(len(cases))
    edges = []
    for n in range(slots.shape[1]):
        i, far = slots[:, n] // 2, slots[:, n] % 2
        a, b = quad[lanes, i], quad[lanes, (i + 1) % 4]
        corners = (jit_array(F, x) for x in (a[:, 0], a[:, 1], b[:, 0], b[:, 1]))
        edges.append((*corners, jit_array(m.Bool, far == 1, bool)))
    orient = jit_array(F, _orient(quad))
    return scratch_edges_ndf(edges, orient, *rest, custom_derivative=custom)


def _kept_first(kept):
    """Per case the kept slots first, then the dropped ones (as piece_codes orders them)."""
    return np.argsort(~kept, axis=1, kind="stable")


def _near_band_cases(rng, count):
    """Footprints with a corner within ~SLACK of |x| = w, y = 0 or y = L (both sides)."""
    cases = []
    while len(cases) < count:
        c = random_case(rng)
        p0, p1 = c["p0"], c["p1"]
        length = float(np.hypot(*(p1 - p0)))
        u = (p1 - p0) / length
        across = np.array([u[1], -u[0]])
        k = rng.integers(4)
        rel = c["quad"][k] - p0
        x, y = rel @ across, rel @ u
        target = rng.choice([c["w"], -c["w"], 0.0, length])
        offset = rng.choice([-3.0, -1.0, -0.5, 0.0, 0.5, 1.0, 3.0]) * SLACK
        if abs(target) == c["w"]:
            shift = (target + np.sign(target) * offset - x) * across
        else:
            shift = (target + offset - y) * u
        c["quad"] = c["quad"] + shift  # the whole footprint moves: it stays convex
        cases.append(c)
    return cases


def test_kept_terms_match_quadrature_and_the_full_closed_form(m):
    """The kept terms alone: the integrals of the independent reference and of all 8 terms."""
    rng = np.random.default_rng(20260101)
    cases = [random_case(rng) for _ in range(2000 if FULL else 600)]
    kept = _kept(m, cases)
    count = kept.sum(axis=1)
    order = _kept_first(kept)
    refs = np.array([reference(c) for c in cases])
    scale = np.maximum(refs[:, 2], 1e-300)
    _quad, qx, qy, rest = _columns(m, cases)
    full_ndf, full_area = (np.asarray(x) for x in scratch_footprint_ndf(qx, qy, *rest))
    quad_area = np.array([abs(shapely.Polygon(c["quad"]).area) for c in cases])
    for size in sorted(set(count.tolist())):
        sel = np.flatnonzero(count == size)
        sub = [cases[i] for i in sel]
        if size == 0:  # nothing to evaluate: the whole pair is exactly 0
            assert np.all(full_ndf[sel] == 0) and np.all(full_area[sel] == 0)
            assert np.all(refs[sel, 0] == 0) and np.all(refs[sel, 1] == 0)
            continue
        ndf, area = _terms(m, sub, order[sel, :size])
        ndf, area = np.asarray(ndf), np.asarray(area)
        assert np.all(np.abs(ndf - refs[sel, 0]) <= 1e-5 * scale[sel]), size
        np.testing.assert_allclose(area, refs[sel, 1], rtol=0, atol=1e-12 * quad_area.max())
        # the same terms as the full closed form, summed in another order
        assert np.all(np.abs(ndf - full_ndf[sel]) <= 1e-12 * scale[sel] + 1e-300), size
        np.testing.assert_allclose(area, full_area[sel], rtol=0, atol=1e-14 * quad_area.max())
    # the test has power: footprints of every kind, most of the 8 terms dropped
    assert {0, 1, 2, 3, 4} <= set(count.tolist()) and count.max() >= 5
    assert count[refs[:, 1] > 0].mean() < 4


def test_dropped_terms_are_exact_zeros_with_zero_derivatives(m):
    """Every term the masks drop, alone, in value and in forward-mode derivatives."""
    rng = np.random.default_rng(7)
    cases = [random_case(rng) for _ in range(300)] + _near_band_cases(rng, 300)
    for c in cases[::50]:
        c["p1"] = c["p0"].copy()  # zero-length scratches too
    kept = _kept(m, cases)
    F = m.Float64
    checked = 0
    for slot in range(EDGE_SLOTS):
        sel = np.flatnonzero(~kept[:, slot])
        sub = [cases[i] for i in sel]
        _quad, _qx, _qy, rest = _columns(m, sub)
        moving = [*rest[:4], *rest[6:9]]  # endpoints and the half-vector
        for v in moving:
            dr.enable_grad(v)
        ndf, area = _terms(m, sub, np.full((len(sub), 1), slot), rest)
        for v in moving:
            dr.set_grad(v, jit_array(F, rng.uniform(-1.0, 1.0, len(sub))))
        outputs = (dr.detach(ndf), dr.detach(area), *dr.forward_to(ndf, area))
        dr.eval(outputs)  # one kernel
        for x in outputs:
            assert not np.any(np.asarray(x)), (slot, sel[np.flatnonzero(np.asarray(x))][:5])
        checked += len(sel)
    # and the kept terms are not all zero: the masks are not trivially "keep everything"
    assert checked > 0.5 * EDGE_SLOTS * len(cases)
    near = kept[300:]
    assert 0 < near.sum() < near.size


@pytest.mark.parametrize("custom", [False, True])
def test_kept_term_gradients_match_central_differences(m, custom):
    """d/d(endpoints, h) of the kept terms alone against differences of the reference;
    with the written-out derivative (custom), d/dh_z is not provided: endpoints, h_x, h_y."""
    cases = lit_cases(np.random.default_rng(12), 20)
    kept = _kept(m, cases)
    size = int(kept.sum(axis=1).max())
    _quad, _qx, _qy, rest = _columns(m, cases)
    params = [("p0", 0), ("p0", 1), ("p1", 0), ("p1", 1), ("h", 0), ("h", 1), ("h", 2)]
    variables = [*rest[:4], *rest[6:9]]
    if custom:
        params, variables = params[:-1], variables[:-1]
    for v in variables:
        dr.enable_grad(v)
    ndf, _area = _terms(m, cases, _kept_first(kept)[:, :size], rest, custom)
    dr.backward(ndf)
    grads = [dr.grad(v) for v in variables]
    dr.eval(grads)  # one kernel for all of them
    ad = np.stack([np.asarray(g, dtype=np.float64) for g in grads])
    assert check_against_differences(ad, cases, params, 1e-8, 1e-3) > 50


@pytest.mark.parametrize("mode", ["backward", "forward"])
def test_written_out_derivative_equals_the_traced_one(m, mode):
    """custom_derivative: the same values, bit for bit, and the derivatives of tracing the
    closed form, to its rounding (which grows as 1/alpha^4, module docstring of ndf)."""
    rng = np.random.default_rng(31)
    cases = [random_case(rng) for _ in range(1500 if FULL else 800)]
    kept = _kept(m, cases)
    slots = _kept_first(kept)[:, :4]  # the kept terms, and dropped ones past their count
    F = m.Float64

    def run(custom):
        _quad, _qx, _qy, rest = _columns(m, cases)
        variables = [*rest[:4], *rest[6:8]]  # endpoints, h_x, h_y
        for v in variables:
            dr.enable_grad(v)
        ndf, area = _terms(m, cases, slots, rest, custom)
        if mode == "backward":
            dr.backward(ndf)
            grads = [dr.grad(v) for v in variables]
        else:
            for k, v in enumerate(variables):
                dr.set_grad(v, jit_array(F, np.linspace(0.2, 1.0, len(cases)) * (k + 1)))
            grads = [dr.forward_to(ndf)]
        values = dr.detach(ndf), dr.detach(area)
        dr.eval(values, grads)  # one kernel for the values and all the derivatives
        return (*(np.asarray(x) for x in values), np.stack([np.asarray(g) for g in grads]))

    ndf_t, area_t, grad_t = run(False)
    ndf_c, area_c, grad_c = run(True)
    assert np.array_equal(ndf_t, ndf_c) and np.array_equal(area_t, area_c)
    assert np.all(np.isfinite(grad_c))
    size = np.abs(grad_t).max(axis=0)
    floor = 1e-9 * size.max()
    alpha = np.array([c["alpha"] for c in cases])
    err = np.abs(grad_c - grad_t).max(axis=0) / np.maximum(size, floor)
    assert err[alpha >= 0.01].max() <= 1e-8, err[alpha >= 0.01].max()
    assert err.max() <= 1e-6, err.max()
    assert np.count_nonzero(size > floor) > 0.5 * len(cases)


def test_written_out_derivative_is_not_used_when_width_profile_or_roughness_move(m):
    """custom_derivative gives no derivative for h_z, wbar, alpha: where any of them
    carries one, scratch_edges_ndf traces instead, so none comes back silently zero (the
    half-width enters through the pieces' ends only, which the written-out one covers)."""
    cases = lit_cases(np.random.default_rng(44), 40)
    slots = _kept_first(_kept(m, cases))[:, :EDGE_SLOTS]
    for moving in (4, 5, 8, 9):  # half_width, wbar, h_z, alpha
        grads = []
        for custom in (False, True):
            _quad, _qx, _qy, rest = _columns(m, cases)
            dr.enable_grad(rest[moving])
            ndf, _area = _terms(m, cases, slots, rest, custom)
            dr.backward(ndf)
            grads.append(np.asarray(dr.grad(rest[moving])))
        assert np.count_nonzero(grads[0]) > len(cases) // 2, moving
        if moving == 4:  # the written-out derivative, through the pieces' ends
            np.testing.assert_allclose(grads[1], grads[0], rtol=1e-8, atol=0)
        else:  # traced: the same computation
            np.testing.assert_array_equal(grads[1], grads[0])


# ---------------------------------------------------------------- renderer


def _scene(m, rng, resolution=24, n=120):
    design = make_design(resolution=resolution, size_mm=20.0)
    vr = ViewRenderer(design, design.views[0], m)
    p0, p1 = random_scratches(rng, n, 9.0, lengths=(0.3, 5.0))
    s = ScratchSet.from_arrays(p0, p1, rng.uniform(0.08, 0.3, n), rng.uniform(0.01, 0.04, n))
    return design, vr, s


def _classes(m, vr, arrays, pairs, pad=1):
    count, code = piece_codes(vr.state, *arrays[:5], pairs.pixel, pairs.scratch, SLACK)
    dr.eval(count, code)
    return np.asarray(count), np.asarray(code), sort_classes(count, code, pad=pad)


def test_piece_codes_list_the_kept_terms_first(m, rng):
    """Each code is a permutation of the 8 slots: the kept ones first, in slot order."""
    design, vr, s = _scene(m, rng)
    arrays = vr.scratch_arrays(s)
    pairs = vr.find_pairs(s.p0, s.p1, s.width / 2, margin_mm=0.3)
    count, code, _ = _classes(m, vr, arrays, pairs)
    F = m.Float64
    quads = vr.quads.reshape(-1, 4, 2)[pairs.pixel_np]
    masks = edge_piece_masks(
        [F(quads[:, k, 0]) for k in range(4)],
        [F(quads[:, k, 1]) for k in range(4)],
        *(dr.gather(F, a, pairs.scratch) for a in arrays[:5]),
        SLACK,
    )
    kept = np.stack([np.asarray(k, dtype=bool) for k in masks], axis=1)
    slots = (code[:, None] >> (3 * np.arange(EDGE_SLOTS))) & 7
    np.testing.assert_array_equal(np.sort(slots, axis=1), np.tile(np.arange(8), (len(code), 1)))
    np.testing.assert_array_equal(count, kept.sum(axis=1))
    np.testing.assert_array_equal(slots, _kept_first(kept))
    assert 0 < (count == 0).sum() < len(count)


@pytest.mark.parametrize("pad", [1, 64])
def test_render_classes_matches_render_pairs_reference_and_differences(m, rng, pad):
    """Images and gradients of render_classes against render_pairs (to rounding), the
    brute-force reference renderer and central differences; padding adds nothing."""
    design, vr, s = _scene(m, rng)
    pairs = vr.find_pairs(s.p0, s.p1, s.width / 2, margin_mm=0.2)
    arrays = list(vr.scratch_arrays(s))
    _count, _code, classes = _classes(m, vr, arrays, pairs, pad)
    sizes = [0 if c is None else dr.width(c[0]) for c in classes]
    assert sum(sizes) > 0 and all(sizes[: len(CLASS_SIZES)])
    if pad > 1:
        nulls = sum(0 if c is None else int(np.sum(np.asarray(c[1]) == NULL_CODE)) for c in classes)
        assert nulls > 0
    weights = jit_array(m.Float64, rng.uniform(0.5, 1.5, vr.pixel_count))

    def run(use_classes, values=None):
        if values is None:
            a = [type(x)(x) for x in arrays]
        else:
            a = [jit_array(m.Float64, v) for v in values]
        for x in a[:4]:
            dr.enable_grad(x)
        if use_classes:
            img = render_classes(
                vr.state, vr.alpha, vr.pixel_count, *a, pairs.pixel, pairs.scratch, classes
            )
        else:
            img = render_pairs(vr.state, vr.alpha, vr.pixel_count, *a, pairs.pixel, pairs.scratch)
        loss = dr.sum(img * weights)
        dr.backward(loss)
        return (
            np.asarray(dr.detach(img)),
            float(dr.detach(loss)[0]),
            [np.asarray(dr.grad(x)) for x in a[:4]],
        )

    img_c, _loss, grad_c = run(True)
    img_p, _loss, grad_p = run(False)
    np.testing.assert_allclose(img_c, img_p, rtol=1e-13, atol=1e-13 * np.abs(img_p).max())
    scale = max(np.abs(g).max() for g in grad_p)
    assert scale > 0
    for a, b in zip(grad_c, grad_p, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * scale)
    ref = reference_render(design, s, seed=5, across=64, along_step_mm=0.01)[vr.view.name]
    assert rel_l2(img_c.reshape(ref.shape), ref) < 0.01
    # central differences of the fast path itself (classes fixed: the pairs' terms stay)
    base = [np.array(a, dtype=np.float64, copy=True) for a in arrays]
    step = 1e-6
    checked = 0
    for coord in range(4):
        for k in np.argsort(-np.abs(grad_c[coord]))[:3]:
            plus = [b.copy() for b in base]
            plus[coord][k] += step
            minus = [b.copy() for b in base]
            minus[coord][k] -= step
            fd = (run(True, plus)[1] - run(True, minus)[1]) / (2 * step)
            g = grad_c[coord][k]
            assert abs(fd - g) <= 1e-6 * scale + 1e-4 * abs(g), (coord, k, fd, g)
            checked += abs(g) > 1e-2 * scale
    assert checked >= 4


def test_frozen_render_classes_equals_traced_when_class_sizes_reorder(m, rng):
    """One thread, bit for bit: the class kernels' order changes with their sizes."""
    design, vr, s = _scene(m, rng, n=80)
    pairs = vr.find_pairs(s.p0, s.p1, s.width / 2, margin_mm=0.2)
    arrays = list(vr.scratch_arrays(s))
    count, code, _ = _classes(m, vr, arrays, pairs)
    U = m.UInt32

    def step(state, pixel, scratch, classes, x0, y0, x1, y1, hw, wb):
        for x in (x0, y0, x1, y1):
            dr.enable_grad(x)
        img = render_classes(
            state, vr.alpha, vr.pixel_count, x0, y0, x1, y1, hw, wb, pixel, scratch, classes
        )
        dr.backward(dr.sum(img * img))
        return img, [dr.grad(x) for x in (x0, y0, x1, y1)]

    frozen = dr.freeze(step)
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        seen = set()
        for trial in range(6):
            # every pair in the full kernel's class is exact; move pairs there so that the
            # classes' sizes, and so the order in which their kernels run, change
            moved = rng.random(len(count)) < [0.0, 0.5, 0.9, 0.1, 0.7, 0.3][trial]
            cnt = np.where(moved & (count > 0), EDGE_SLOTS, count).astype(np.uint32)
            classes = sort_classes(U(cnt), U(code))
            sizes = tuple(0 if c is None else dr.width(c[0]) for c in classes)
            seen.add(tuple(np.argsort(sizes)))
            args = (vr.state, pairs.pixel, pairs.scratch, classes, *[type(a)(a) for a in arrays])
            img_f, grad_f = frozen(*args)
            img_t, grad_t = step(*args[:4], *[type(a)(a) for a in arrays])
            assert np.array_equal(np.asarray(img_f), np.asarray(img_t)), trial
            for a, b in zip(grad_f, grad_t, strict=True):
                assert np.array_equal(np.asarray(a), np.asarray(b)), trial
    finally:
        dr.set_thread_count(threads)
    assert len(seen) >= 2  # the kernels did run in different orders
    assert frozen.n_recordings < 6
