"""Tests of the optimize stage: bounds, pairs, loss, checkpoints, resume, prune, CLI."""

from __future__ import annotations

import csv
import json
import math
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import drjit as dr
import numpy as np
import pytest
from conftest import FULL, make_design, pasted_words
from test_optimize_helpers import cross_of, make_job, make_layout, stopped_at_three_of_four

from scratchfab.backend import jit_array
from scratchfab.bundled import bundled_dir
from scratchfab.cli import main
from scratchfab.errors import ScratchfabError
from scratchfab.metrics import exposure, quality_report
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.optimize.checkpoint import load_checkpoint, save_checkpoint
from scratchfab.optimize.loss import neighbour_pairs, segment_distance_np, view_error
from scratchfab.optimize.optimizer import LayoutOptimizer, NonFiniteError, Settings
from scratchfab.optimize.params import (
    KEYS,
    BoundedAdam,
    Bounds,
    endpoints,
    max_step_mm,
    project,
    project_np,
)
from scratchfab.optimize.stage import OptimizeOptions, run_optimize
from scratchfab.render.renderer import pair_footprints

LR = {"cx": 0.03, "cy": 0.03, "theta": math.radians(0.25), "length": 0.03}


def _ends(m, params, bounds):  # type: ignore[no-untyped-def]
    F = m.Float64
    arrs = [F(params[k]) for k in KEYS]
    return np.stack([np.asarray(e) for e in endpoints(*project(*arrs, bounds))], axis=1)


# ---------------------------------------------------------------- parametrisation


def test_projection_is_feasible_idempotent_and_matches_numpy(m, rng) -> None:
    bounds = Bounds(half_x=19.0, half_y=14.0, min_length=1.0, max_length=6.0)
    n = 5000
    raw = {
        "cx": rng.uniform(-30, 30, n),
        "cy": rng.uniform(-30, 30, n),
        "theta": rng.uniform(-7, 7, n),
        "length": rng.uniform(-2, 10, n),
    }
    F = m.Float64
    proj = project(*(F(raw[k]) for k in KEYS), bounds)
    again = project(*proj, bounds)
    for a, b in zip(proj, again, strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    ref = project_np(raw, bounds)
    for k, a in zip(KEYS, proj, strict=True):
        np.testing.assert_allclose(np.asarray(a), ref[k], rtol=0, atol=1e-12)
    e = np.stack([np.asarray(v) for v in endpoints(*proj)], axis=1)
    assert np.all(np.abs(e[:, [0, 2]]) <= bounds.half_x + 1e-9)
    assert np.all(np.abs(e[:, [1, 3]]) <= bounds.half_y + 1e-9)
    length = np.hypot(e[:, 2] - e[:, 0], e[:, 3] - e[:, 1])
    assert np.all((length >= 1.0 - 1e-9) & (length <= 6.0 + 1e-9))


def test_endpoint_motion_per_step_is_bounded(m, rng) -> None:
    """Any raw step within lr per coordinate moves projected endpoints <= max_step_mm."""
    bounds = Bounds(half_x=10.0, half_y=10.0, min_length=1.0, max_length=6.0)
    n = 20000
    raw = {
        "cx": rng.uniform(-12, 12, n),
        "cy": rng.uniform(-12, 12, n),
        "theta": rng.uniform(-4, 4, n),
        "length": rng.uniform(0, 8, n),
    }
    # worst cases: steps at the full learning rate in every coordinate, random signs
    moved = {k: raw[k] + LR[k] * rng.choice([-1.0, 1.0], n) for k in KEYS}
    a = _ends(m, raw, bounds)
    b = _ends(m, moved, bounds)
    shift = np.maximum(np.hypot(*(b[:, 0:2] - a[:, 0:2]).T), np.hypot(*(b[:, 2:4] - a[:, 2:4]).T))
    bound = max_step_mm(LR, bounds.max_length)
    assert shift.max() <= bound
    assert shift.max() > 0.5 * bound  # the bound is not vacuous


def test_bounded_adam_clips_each_step_to_lr(m) -> None:
    """A gradient burst after a quiet spell: plain Adam steps past lr, ours never."""
    lr = 0.1
    plain = dr.opt.Adam(lr=lr)
    ours = BoundedAdam(lr=lr)
    for opt in (plain, ours):
        opt["x"] = m.Float64([0.0, 0.0])
    steps: dict[int, list[float]] = {0: [], 1: []}
    for it in range(60):
        g = 1e-6 if it < 50 else 1e3
        for k, opt in enumerate((plain, ours)):
            x = opt["x"]
            before = np.asarray(x).copy()
            dr.backward(dr.sum(x * m.Float64([g, -g])))
            opt.step()
            steps[k].append(float(np.abs(np.asarray(opt["x"]) - before).max()))
    assert max(steps[0]) > 1.3 * lr
    assert max(steps[1]) <= lr * (1 + 1e-12)


# ---------------------------------------------------------------- pairs


@pytest.fixture(scope="module")
def board() -> tuple:  # type: ignore[type-arg]
    design = make_design(resolution=24, size_mm=30.0)
    targets, cross = cross_of(design)
    return design, targets, cross


def _pair_set(pairs) -> set[tuple[int, int]]:  # type: ignore[no-untyped-def]
    return set(zip(pairs.pixel_np.tolist(), pairs.scratch_np.tolist(), strict=True))


def test_pairs_are_never_missed_between_refreshes(m, board) -> None:
    """Fresh exact pairs at every step are a subset of the pairs in use (K = 6)."""
    design, targets, _ = board
    layout = make_layout(design, 120, seed=5)
    lr = {"cx": 0.08, "cy": 0.08, "theta": math.radians(1.0), "length": 0.08}
    opt = LayoutOptimizer(design, targets, layout, Settings(lr=lr, refresh_every=6), m)
    missed_without_margin = 0
    for _ in range(18):
        opt.step()
        current = opt.scratches()
        stale = opt.refresh_ends.astype(np.float64)
        for r, used in zip(opt.renderers, opt.pairs, strict=True):
            fresh = r.find_pairs(current.p0, current.p1, current.width / 2, 0.0)
            assert _pair_set(fresh) <= _pair_set(used)
            old = r.find_pairs(stale[:, 0:2], stale[:, 2:4], current.width / 2, 0.0)
            missed_without_margin += len(_pair_set(fresh) - _pair_set(old))
    # the margin is needed: pairs found without it do go stale
    assert missed_without_margin > 0


@pytest.mark.parametrize(("spacing", "strip_points"), [(1.0, 5000), (0.0, 37), (3.0, 200)])
def test_neighbour_pairs_match_brute_force(rng, spacing, strip_points) -> None:
    """Any sample spacing and any strip size find the same pairs: those brute force finds."""
    n = 400
    c = rng.uniform(-10, 10, (n, 2))
    theta = rng.choice([0.0, 0.1, 1.2], n) + rng.normal(0, 0.05, n)
    half = (rng.uniform(1, 4, n) / 2)[:, None] * np.stack([np.cos(theta), np.sin(theta)], 1)
    p0, p1 = c - half, c + half
    reach = 0.4
    i, j = neighbour_pairs(p0, p1, reach, spacing=spacing, strip_points=strip_points)
    assert np.all(np.diff(i * n + j) > 0)  # sorted by (i, j), no repeats
    got = set(zip(i.tolist(), j.tolist(), strict=True))
    ii, jj = np.triu_indices(n, 1)
    d = segment_distance_np(p0, p1, ii, jj)
    u = p1 - p0
    cos = (
        np.abs(np.sum(u[ii] * u[jj], 1))
        / np.linalg.norm(u[ii], axis=1)
        / np.linalg.norm(u[jj], axis=1)
    )
    want = set(
        zip(
            ii[(d < reach) & (cos >= math.cos(math.radians(35)))].tolist(),
            jj[(d < reach) & (cos >= math.cos(math.radians(35)))].tolist(),
            strict=True,
        )
    )
    assert want and got == want


# ---------------------------------------------------------------- loss


def test_view_error_uses_the_closed_form_exposure(m, rng) -> None:
    n = 500
    r = rng.uniform(0, 2, n)
    t = rng.uniform(0, 1, n)
    mask = (rng.uniform(0, 1, n) > 0.2).astype(np.float64)
    F = m.Float64
    err, s = view_error(F(r), F(t * mask), F(mask), "linear")
    target = np.where(mask > 0, t, np.nan)
    s_ref = exposure(r, target)
    ok = mask > 0
    e_ref = np.sum((s_ref * r[ok] - t[ok]) ** 2) / np.sum(t[ok] ** 2)
    assert float(s[0]) == pytest.approx(s_ref, rel=1e-12)
    assert float(err[0]) == pytest.approx(e_ref, rel=1e-10)
    # perceptual: the sRGB-encoded difference, same exposure
    perr, _ = view_error(F(r), F(t * mask), F(mask), "perceptual")

    def enc(v: np.ndarray) -> np.ndarray:
        return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)

    p_ref = np.sum((enc(s_ref * r[ok]) - enc(t[ok])) ** 2) / np.sum(enc(t[ok]) ** 2)
    assert float(perr[0]) == pytest.approx(p_ref, rel=1e-10)


def test_view_error_of_a_dim_render_is_that_of_the_render_scaled_up(m, rng) -> None:
    """The exposure (SPEC section 7) makes E scale-free: a float32 render of energy below 1e-30 (a
    dim light the design accepts) must give the error of the same render at scale 1, and
    an all-zero render E = 1 with exposure 0 (not 0/0)."""
    n = 400
    r = rng.uniform(0.5, 1, n)  # (1e-18 r)^2 stays a normal float32
    t = rng.uniform(0, 1, n)
    mask = np.ones(n)
    F = m.Float
    err_1, s_1 = view_error(F(r), F(t), F(mask), "linear")
    err_dim, s_dim = view_error(F(r * 1e-18), F(t), F(mask), "linear")
    assert float(err_dim[0]) == pytest.approx(float(err_1[0]), rel=1e-4)
    assert float(s_dim[0]) == pytest.approx(float(s_1[0]) * 1e18, rel=1e-4)
    err_0, s_0 = view_error(F(np.zeros(n)), F(t), F(mask), "linear")
    assert float(s_0[0]) == 0.0 and float(err_0[0]) == pytest.approx(1.0, rel=1e-6)


def test_merge_penalty_pushes_close_parallel_scratches_apart(m, board) -> None:
    design, targets, _ = board
    base = np.array([[-2.0, 0.0], [2.0, 0.0]])
    layout = ScratchSet.from_arrays(
        np.stack([base[0], base[0] + [0, 0.04]]),
        np.stack([base[1], base[1] + [0, 0.04]]),
        0.1,
        0.01,
    )

    def gaps(merge_weight: float) -> list[float]:
        opt = LayoutOptimizer(
            design, targets, layout, Settings(lr=LR, merge_weight=merge_weight), m
        )
        out = []
        for _ in range(10):
            opt.step()
            s = opt.scratches()
            out.append(float(segment_distance_np(s.p0, s.p1, np.array([0]), np.array([1]))[0]))
        return out

    image_only = gaps(0.0)
    merged = gaps(1e3)
    assert merged[-1] > 0.1 + 0.04  # apart by more than a tool width after 10 steps
    # and faster than the image term alone takes them apart (the penalty pushes hardest
    # while they overlap most: by step 10 the image term has nearly caught up)
    assert merged[1] > image_only[1] + 0.02  # step 2: 0.139 against 0.112


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("targets", r"the targets \(elsewhere\) name none of the views \(left, right\)"),
        ("lr", r"Settings\.lr: missing theta, length"),
    ],
)
def test_the_optimizer_refuses_targets_of_no_view_and_missing_rates(
    m, board, change: str, message: str
) -> None:
    """A library user's slips are named before the first step, not a Dr.Jit error in it."""
    design, targets, _ = board
    layout = make_layout(design, 20, seed=1)
    lr = dict(LR)
    if change == "targets":
        targets = {"elsewhere": next(iter(targets.values()))}
    else:
        del lr["theta"], lr["length"]
    with pytest.raises(ScratchfabError, match=message):
        LayoutOptimizer(design, targets, layout, Settings(lr=lr), m)


def test_pairs_the_step_skips_add_exact_zeros(m, board) -> None:
    """Every pair that the touch test drops contributes 0.0, with 0.0 derivatives.

    Checked against the renderer's own closed form evaluated on the dropped pairs alone,
    part way through a refresh period (the masks of the step's own evaluation).
    """
    design, targets, _ = board
    layout = make_layout(design, 300, seed=3)
    opt = LayoutOptimizer(design, targets, layout, Settings(lr=LR, refresh_every=8), m)
    for _ in range(3):
        opt.step()
    assert opt.active is not None
    F, U = m.Float64, m.UInt32
    ends = [F(opt.ends[:, k]) for k in range(4)]
    for e in ends:
        dr.enable_grad(e)
    masks = opt._touching(tuple(ends), opt._context())
    dropped_total = kept_total = 0
    for r, pairs, mask, active in zip(opt.renderers, opt.pairs, masks, opt.active, strict=True):
        keep = np.asarray(mask, dtype=bool)
        # the step renders exactly the pairs that the mask keeps, in order
        assert np.array_equal(np.asarray(active), np.flatnonzero(keep))
        drop = np.flatnonzero(~keep)
        dropped_total += len(drop)
        kept_total += int(keep.sum())
        pix, sc = (jit_array(U, x[drop], np.uint32) for x in (pairs.pixel_np, pairs.scratch_np))
        ndf, covered = pair_footprints(r.state, r.alpha, *ends, opt._half_width, opt._wbar, pix, sc)
        dr.eval(ndf, covered)  # one kernel
        assert not np.any(np.asarray(ndf)) and not np.any(np.asarray(covered))
        dr.backward(dr.sum(ndf) + dr.sum(covered))
        grads = [dr.grad(e) for e in ends]
        dr.eval(grads)  # one kernel
        for g in grads:
            assert not np.any(np.asarray(g))
    # the margin makes most pairs idle: the test drops a real share of them
    assert dropped_total > 0.3 * (dropped_total + kept_total)


def test_touching_pairs_give_the_loss_and_gradient_of_all_pairs(m, board) -> None:
    """Rendering only touching pairs changes the sums' grouping, nothing more."""
    design, targets, _ = board
    layout = make_layout(design, 300, seed=4)
    opt = LayoutOptimizer(design, targets, layout, Settings(lr=LR, merge_weight=1.0), m)
    for _ in range(5):
        opt.step()
    assert opt.active is not None
    assert sum(opt.active_counts()) < 0.7 * sum(opt.pair_counts())

    def run(active):  # type: ignore[no-untyped-def]
        raw = [jit_array(m.Float64, opt.opt[k]) for k in KEYS]
        for a in raw:
            dr.enable_grad(a)
        loss, _errors, renders, _ = opt._forward(raw, active=active)
        dr.backward(loss)
        grads = [dr.grad(a) for a in raw]
        dr.eval(loss, renders, grads)  # one kernel
        return (
            float(loss[0]),
            [np.asarray(x) for x in renders],
            np.stack([np.asarray(g) for g in grads]),
        )

    loss_a, renders_a, grad_a = run(opt.active)
    loss_b, renders_b, grad_b = run(None)
    assert loss_a == pytest.approx(loss_b, rel=1e-13)
    for a, b in zip(renders_a, renders_b, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13 * float(np.abs(b).max()))
    np.testing.assert_allclose(grad_a, grad_b, rtol=0, atol=1e-11 * float(np.abs(grad_b).max()))
    # a view that no scratch touches shows the flat board
    _loss, flat, _grad = run([m.UInt32() for _ in opt.views])
    for r, img in zip(opt.renderers, flat, strict=True):
        # SPEC section 4 with no scratch: L = factor |P ∩ B| D(h_z) (factor holds 1/|P|)
        expected = (r.factor * r.area_on_board * r.d_flat).ravel()
        np.testing.assert_allclose(img, expected, rtol=1e-12, atol=0)


def test_frozen_steps_replay_the_traced_trajectory_bit_for_bit(m, board) -> None:
    """dr.freeze replays the kernels that tracing makes: same losses, renders and state."""
    design, targets, _ = board
    layout = make_layout(design, 200, seed=6)
    settings = Settings(lr=LR, refresh_every=3, merge_weight=1.0)
    runs = [LayoutOptimizer(design, targets, layout, settings, m, freeze=f) for f in (True, False)]
    threads = dr.thread_count()
    dr.set_thread_count(1)  # atomics add in thread order: one thread, as the stage's default
    try:
        steps = [[opt.step() for opt in runs] for _ in range(8)]  # refreshes at 0, 3, 6
    finally:
        dr.set_thread_count(threads)
    for frozen, traced in steps:
        assert frozen.loss == traced.loss
        for name, img in frozen.renders.items():
            assert np.array_equal(img, traced.renders[name])
    assert runs[0]._train_step.n_recordings >= 2  # type: ignore[attr-defined]
    a, b = (opt.state() for opt in runs)
    assert a.keys() == b.keys()
    for key in a:
        assert np.array_equal(a[key], b[key]), key


@pytest.mark.parametrize("space", ["linear", "perceptual"])
def test_objective_gradient_matches_finite_differences(m, space) -> None:
    """Adam follows d(loss)/d(raw parameters): image terms, merge and bound penalties."""
    design = make_design(resolution=24, size_mm=30.0)
    targets, _ = cross_of(design)
    layout = make_layout(design, 40, seed=5)
    # scratch 1 close beside scratch 0 and nearly parallel (exactly parallel, the four
    # endpoint distances tie and the distance has a kink): the merge penalty is active
    p0, p1 = layout.p0.copy(), layout.p1.copy()
    half = (p1[0] - p0[0]) / 2
    turn = np.array([[np.cos(0.05), -np.sin(0.05)], [np.sin(0.05), np.cos(0.05)]])
    centre = (p0[0] + p1[0]) / 2 + 0.06 * np.array([-half[1], half[0]]) / np.linalg.norm(half)
    p0[1], p1[1] = centre - turn @ half, centre + turn @ half
    layout = ScratchSet.from_arrays(p0, p1, layout.width, layout.depth)
    opt = LayoutOptimizer(
        design, targets, layout, Settings(lr=LR, space=space, merge_weight=1.0), m
    )
    opt._refresh(opt.ends)
    assert opt._neighbour_count > 0
    base = [np.array(opt.opt[k], dtype=np.float64, copy=True) for k in KEYS]
    base[0][2] = 30.0  # far off the board: the bound penalty is active
    raw = [jit_array(m.Float64, b) for b in base]
    for a in raw:
        dr.enable_grad(a)
    # the step's path: only the pairs that touch at these parameters (the differences
    # below use every pair)
    with dr.suspend_grad():
        ends = endpoints(*project(*(jit_array(m.Float64, b) for b in base), opt.bounds))
        masks = opt._touching(ends, opt._context())
    dr.eval(masks)
    loss, *_ = opt._forward(raw, active=opt._compress(masks))
    dr.backward(loss)
    grads = [dr.grad(a) for a in raw]
    dr.eval(grads)  # one kernel
    grad = [np.array(g, dtype=np.float64) for g in grads]

    def loss_at(values: list[np.ndarray]) -> float:
        with dr.suspend_grad():
            return float(np.asarray(opt._forward([jit_array(m.Float64, v) for v in values])[0])[0])

    h = 1e-6
    scale = max(float(np.abs(g).max()) for g in grad)
    checked = 0
    for c in range(len(KEYS)):
        for k in (0, 1, 2, 7, 19, 33):
            plus = [b.copy() for b in base]
            plus[c][k] += h
            minus = [b.copy() for b in base]
            minus[c][k] -= h
            fd = (loss_at(plus) - loss_at(minus)) / (2 * h)
            if abs(fd) > 1e-3 * scale:
                checked += 1
                assert grad[c][k] == pytest.approx(fd, rel=1e-4), (KEYS[c], k)
    assert checked >= 12


# ---------------------------------------------------------------- the stage


@pytest.fixture
def job(tmp_path: Path) -> Path:
    return make_job(tmp_path / "job", make_design(resolution=24, size_mm=30.0), count=150)


def test_cli_writes_every_output(job: Path, capsys: pytest.CaptureFixture[str]) -> None:
    main(["optimize", str(job), "--iterations", "12", "--checkpoint-every", "5"])
    err = capsys.readouterr().err.splitlines()  # not a terminal: a log of progress lines
    assert err[0] == "compiling kernels..." and "writing outputs..." in err
    assert any(line.startswith(f"[{'#' * 30}] 12/12 loss ") for line in err)
    out = job / "optimize"
    for name in (
        "scratches.csv",
        "log.csv",
        "loss.png",
        "side_by_side.png",
        "checkpoint.npz",
        "renders/left.npy",
        "renders/left.png",
        "renders/right.npy",
        "summary.json",
    ):
        assert (out / name).is_file(), name
    with open(out / "log.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["iteration"]) for r in rows] == list(range(13))
    assert {"loss", "psnr_left", "rho_right", "x_left_right", "x_right_left"} <= set(rows[0])
    assert float(rows[-2]["loss"]) < float(rows[0]["loss"])
    design_csv = load_scratches(job / "design" / "scratches.csv", make_design().scratch)
    from scratchfab.model.design import load_design

    design = load_design(job / "design" / "design.toml")
    final = load_scratches(out / "scratches.csv", design.scratch, design.board)
    assert len(final) == len(design_csv)
    b = Bounds.from_design(design)
    assert np.all(np.abs(np.concatenate([final.p0[:, 0], final.p1[:, 0]])) <= b.half_x + 1e-9)
    assert np.all((final.lengths >= b.min_length - 1e-9) & (final.lengths <= b.max_length + 1e-9))
    # the render layout shows the final layout (checked against a fresh render)
    from scratchfab.render.renderer import render_scratches

    fresh = render_scratches(design, final)
    np.testing.assert_allclose(
        np.load(out / "renders" / "left.npy"), fresh["left"], rtol=1e-5, atol=1e-7
    )
    # Rerunning design afterwards leaves this layout behind: toolpath and render say so.
    from scratchfab.model.job import stale_layout_warning
    from scratchfab.toolpath.stage import job_toolpath_inputs

    assert stale_layout_warning(job) is None and job_toolpath_inputs(job)[2] is None
    toml = job / "design" / "design.toml"
    toml.write_text(toml.read_text() + "\n# edited\n")  # a comment: nothing optimize uses
    assert job_toolpath_inputs(job)[2] is None
    assert "roughness = 0.05\n" in toml.read_text()
    toml.write_text(toml.read_text().replace("roughness = 0.05\n", "roughness = 0.08\n"))
    note = job_toolpath_inputs(job)[2]
    assert note is not None and "(design/design.toml changed since)" in note
    capsys.readouterr()
    main(["render", str(job)])
    assert "rerun `scratchfab optimize" in capsys.readouterr().err
    # toolpath refuses to plan it (a maker may miss a warning and cut the earlier board),
    # writes nothing, and plans it as it is under --force.
    with pytest.raises(SystemExit) as info:
        main(["toolpath", str(job), "--machine", "grbl-3018-diamond"])
    said = capsys.readouterr().err
    assert info.value.code == 2 and "Traceback" not in said
    assert "was optimized from an earlier design (design/design.toml changed since)" in said
    assert "or give --force to plan it as it is; nothing written" in said
    assert not (job / "toolpath").exists()
    main(["toolpath", str(job), "--machine", "grbl-3018-diamond", "--force"])
    assert "warning:" in capsys.readouterr().err
    assert (job / "toolpath" / "toolpath.json").is_file()


def _run_cli(job: Path, *args: str) -> subprocess.Popen[bytes]:
    code = "import sys; from scratchfab.cli import main; main(sys.argv[1:])"
    return subprocess.Popen(
        [sys.executable, "-c", code, "optimize", str(job), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def test_resume_after_kill_9_matches_uninterrupted(tmp_path: Path) -> None:
    design = make_design(resolution=24, size_mm=30.0)
    a = make_job(tmp_path / "a", design, count=150)
    b = make_job(tmp_path / "b", design, count=150)
    # enough steps past the 14th that a poller delayed by a busy machine still kills it
    # midway (30 were all done once before the poll saw 14)
    args = ["--iterations", "150", "--checkpoint-every", "7", "--seed", "4"]
    ref = _run_cli(a, *args)
    assert ref.wait(timeout=300) == 0, ref.stderr.read() if ref.stderr else ""  # type: ignore[union-attr]
    victim = _run_cli(b, *args)
    ckpt = b / "optimize" / "checkpoint.npz"
    deadline = time.time() + 300
    while time.time() < deadline:
        if ckpt.exists():
            state, _, _ = load_checkpoint(ckpt)
            if int(state["iteration"]) >= 14:
                break
        time.sleep(0.05)
    victim.send_signal(signal.SIGKILL)
    victim.wait()
    state, _, _ = load_checkpoint(ckpt)
    assert 14 <= int(state["iteration"]) < 150
    assert not (b / "optimize" / "scratches.csv").exists()
    resumed = _run_cli(b, *args, "--resume")
    assert resumed.wait(timeout=300) == 0
    ref_text = (a / "optimize" / "scratches.csv").read_bytes()
    assert (b / "optimize" / "scratches.csv").read_bytes() == ref_text
    log_a = (a / "optimize" / "log.csv").read_text().splitlines()
    log_b = (b / "optimize" / "log.csv").read_text().splitlines()
    strip = [lambda line: line.split(",")[:2] + line.split(",")[3:]][0]
    assert [strip(x) for x in log_a] == [strip(x) for x in log_b]


def test_ctrl_c_stops_after_the_step_with_outputs(job: Path) -> None:
    proc = _run_cli(job, "--iterations", "500", "--checkpoint-every", "1000")
    log = job / "optimize" / "log.csv"
    deadline = time.time() + 300
    # wait until stepping (the first checkpoint is the Ctrl-C one, so watch stderr progress)
    assert proc.stderr is not None
    os.set_blocking(proc.stderr.fileno(), False)
    seen = b""
    while time.time() < deadline and not any(int(n) >= 3 for n in re.findall(rb" (\d+)/500", seen)):
        chunk = proc.stderr.read() or b""
        seen += chunk
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=120) == 130  # a shell's `optimize && toolpath` stops here
    out = proc.stdout.read().decode() if proc.stdout else ""
    assert "iterations (interrupted)" in out
    err = proc.stderr.read().decode()
    found = re.search(r"`(.*)` continues it", err)
    assert found
    again = shlex.split(found.group(1))  # the options given, which the resume must repeat
    assert again == [
        *("scratchfab", "optimize", str(job)),
        *("--iterations", "500", "--checkpoint-every", "1000", "--resume"),
    ]
    assert "Traceback" not in err and "error" not in err
    state, _, rows = load_checkpoint(job / "optimize" / "checkpoint.npz")
    n = int(state["iteration"])
    assert 3 <= n < 500 and len(rows) == n
    assert (job / "optimize" / "scratches.csv").exists() and log.exists()
    resumed = _run_cli(job, *again[3:])  # the advice, followed, resumes to the end
    assert resumed.wait(timeout=300) == 0, resumed.stderr.read() if resumed.stderr else ""  # type: ignore[union-attr]
    assert json.loads((job / "optimize" / "summary.json").read_text())["iterations"] == 500


def test_non_finite_loss_stops_with_message_and_keeps_checkpoint(
    job: Path, monkeypatch, capsys
) -> None:
    original = LayoutOptimizer.step

    def poisoned(self):  # type: ignore[no-untyped-def]
        if self.iteration == 8:  # the renders turn NaN (data, so frozen steps see it too)
            for r in self.renderers:
                r._factor = r._factor * math.nan
        return original(self)

    monkeypatch.setattr(LayoutOptimizer, "step", poisoned)
    with pytest.raises(SystemExit) as exc:
        main(["optimize", str(job), "--iterations", "20", "--checkpoint-every", "5"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "error: non-finite render of view '" in err and "at iteration 8" in err
    assert "checkpoint" in err and "learning rates" not in err  # the render, not the step size
    state, _, _ = load_checkpoint(job / "optimize" / "checkpoint.npz")
    assert int(state["iteration"]) == 5
    for k in KEYS:
        assert np.all(np.isfinite(state[f"raw_{k}"]))


def test_resume_refuses_other_settings_and_missing_checkpoint(job: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        main(["optimize", str(job), "--iterations", "2", "--resume"])
    assert "no checkpoint to resume from" in capsys.readouterr().err
    main(["optimize", str(job), "--iterations", "2"])
    with pytest.raises(SystemExit):
        main(["optimize", str(job), "--iterations", "4", "--resume", "--seed", "9"])
    err = capsys.readouterr().err
    assert "different settings" in err and "seed" in err


def test_resume_refuses_a_checkpoint_of_the_earlier_merge_penalty(job: Path, capsys) -> None:
    """A checkpoint's fingerprint without the penalty's form was made under the earlier
    one (scratch ends, cos^16): same options, another loss, so it does not resume."""
    main(["optimize", str(job), "--iterations", "2"])
    ckpt = job / "optimize" / "checkpoint.npz"
    state, meta, log_rows = load_checkpoint(ckpt)
    assert meta["fingerprint"].pop("merge_penalty") == "length cut twice"
    save_checkpoint(ckpt, state, meta, log_rows)
    with pytest.raises(SystemExit):
        main(["optimize", str(job), "--iterations", "4", "--resume"])
    err = capsys.readouterr().err
    assert (
        "made by an earlier scratchfab, whose merge penalty had another form; "
        "run without --resume to start over"
    ) in " ".join(err.split())
    assert "merge_penalty" not in err and "different settings" not in err


@pytest.mark.parametrize("option", ["--time-budget", "--prune"])
@pytest.mark.parametrize("value", ["nan", "inf"])
def test_option_values_that_are_not_finite_numbers_are_refused(
    job: Path, capsys, option: str, value: str
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["optimize", str(job), "--iterations", "1", option, value])
    assert exc.value.code == 2
    assert f"'{option}': '{value}' is not a finite number" in capsys.readouterr().err
    assert not (job / "optimize").exists()


@pytest.mark.parametrize("broken", ["empty layout", "missing target"])
def test_broken_design_stage_is_one_line_error_naming_the_file(
    job: Path, capsys, broken: str
) -> None:
    if broken == "empty layout":
        path = job / "design" / "scratches.csv"
        path.write_text(path.read_text().splitlines()[0] + "\n")
        message = f"{path}: no scratches to optimize"
    else:
        path = sorted((job / "design" / "targets").glob("*.npy"))[0]
        path.unlink()
        message = f"{path}: file not found (view '{path.stem}' has a target picture"
    with pytest.raises(SystemExit) as exc:
        main(["optimize", str(job), "--iterations", "1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (job / "optimize").exists()


def test_missing_job_is_one_line_error(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["optimize", str(tmp_path / "nope")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "design.toml: file not found" in err[0]


def test_prune_drops_invisible_scratches_and_reports_savings(m, board) -> None:
    from scratchfab.optimize.prune import prune

    design, targets, _ = board
    layout = make_layout(design, 120, seed=8)
    # 15 extra scratches turned 90 degrees from a view's reflecting direction: no view sees them
    extra = make_layout(design, 30, seed=9).subset(np.arange(0, 30, 2))
    c = 0.5 * (extra.p0 + extra.p1)
    d = 0.5 * (extra.p1 - extra.p0)
    rot = np.stack([-d[:, 1], d[:, 0]], 1)
    hidden = ScratchSet.from_arrays(c - rot, c + rot, 0.1, 0.01)
    full = ScratchSet.from_arrays(
        np.concatenate([layout.p0, hidden.p0]), np.concatenate([layout.p1, hidden.p1]), 0.1, 0.01
    )
    opt = LayoutOptimizer(design, targets, full, Settings(lr=LR), m)
    before = opt.evaluate(full).loss
    report = prune(opt, full, 0.001, feed_mm_min=300.0, stroke_overhead_s=2.0)
    assert report.removed >= 10
    assert report.loss_after <= before * 1.001 + 1e-15
    assert opt.evaluate(report.kept).loss == pytest.approx(report.loss_after, rel=1e-9)
    assert len(report.kept) == len(full) - report.removed
    removed_len = full.lengths.sum() - report.kept.lengths.sum()
    assert report.length_saved_mm == pytest.approx(removed_len)
    assert report.time_saved_s == pytest.approx(removed_len / 300 * 60 + 2.0 * report.removed)


# ---------------------------------------------------------------- acceptance


@pytest.mark.slow
def test_acceptance_test_board_checked_with_reference_renderer(tmp_path: Path) -> None:
    """rho_kk >= 0.8 and x_kj <= 0.2 by the independent brute-force renderer."""
    from reference_render import reference_render

    res, count, iters = (48, 700, 150) if FULL else (32, 300, 100)
    design = make_design(resolution=res, size_mm=40.0)
    job = make_job(tmp_path / "job", design, count=count)
    result = run_optimize(job, OptimizeOptions(iterations=iters, threads=0))
    from scratchfab.model.design import load_design

    design = load_design(job / "design" / "design.toml")
    targets, cross = cross_of(design)
    ref = reference_render(
        design, result.scratches, samples_per_pixel=64, across=24, along_step_mm=0.05
    )
    q = quality_report(ref, targets, cross)
    for k, v in q["views"].items():
        assert v["rho"] >= 0.8, (k, v)
        for j, x in v["crosstalk"].items():
            assert x <= 0.2, (k, j, x)
    own = quality_report(
        result.quality and {k: np.load(job / "optimize" / "renders" / f"{k}.npy") for k in targets},
        targets,
        cross,
    )
    for k in targets:
        assert abs(own["views"][k]["rho"] - q["views"][k]["rho"]) < 0.05


def test_non_finite_error_is_a_user_error() -> None:
    assert issubclass(NonFiniteError, ScratchfabError)


@pytest.mark.slow
def test_acceptance_demo_checked_with_reference_renderer(tmp_path: Path) -> None:
    """The bundled demo: rho_kk >= 0.8, x_kj <= 0.2 by the brute-force renderer."""
    from reference_render import reference_render

    from scratchfab.design.targets import cross_targets
    from scratchfab.model.design import load_design

    job = tmp_path / "demo"
    main(["design", str(bundled_dir("pipelines") / "demo.toml"), "--out", str(job)])
    result = run_optimize(job, OptimizeOptions(iterations=150 if FULL else 20, threads=0))
    design = load_design(job / "design" / "design.toml")
    targets = {v.name: np.load(job / "design" / "targets" / f"{v.name}.npy") for v in design.views}
    ref = reference_render(
        design, result.scratches, samples_per_pixel=64, across=24, along_step_mm=0.05
    )
    q = quality_report(ref, targets, cross_targets(design))
    for k, v in q["views"].items():
        assert v["rho"] >= 0.8, (k, v)
        for j, x in v["crosstalk"].items():
            assert x <= 0.2, (k, j, x)


# ---------------------------------------------------------------- coverage of user-facing paths


def _csv_segments(path: Path) -> np.ndarray:
    """(N, 4) x0, y0, x1, y1 of a scratches.csv, read with the csv module alone."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return np.array([[float(r[k]) for k in ("x0", "y0", "x1", "y1")] for r in rows])


@pytest.mark.parametrize("damage", ["checkpoint", "target"])
@pytest.mark.parametrize("content", [b"garbage", b""])
def test_garbage_numpy_file_is_one_line_naming_it(
    job: Path, capsys, damage: str, content: bytes
) -> None:
    """Not numpy's 'load it unsafely using allow_pickle=' advice: what the file is not."""
    if damage == "checkpoint":
        main(["optimize", str(job), "--iterations", "1"])
        path = job / "optimize" / "checkpoint.npz"
        args = ["--resume"]
    else:
        path = sorted((job / "design" / "targets").glob("*.npy"))[0]
        args = []
    path.write_bytes(content)
    before = {p: p.read_bytes() for p in (job / "optimize").glob("*.csv")}
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(["optimize", str(job), "--iterations", "2", *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    seen = "it is empty" if not content else "it begins with b'garbage'"
    assert err.splitlines()[-1] == f"error: {path}: not a NumPy {path.suffix} file ({seen})"
    assert "Traceback" not in err and "allow_pickle" not in err
    assert path.read_bytes() == content  # nothing rewritten
    assert {p: p.read_bytes() for p in (job / "optimize").glob("*.csv")} == before


def test_time_budget_stops_after_one_step_with_every_output(job: Path, capsys) -> None:
    main(["optimize", str(job), "--iterations", "50", "--time-budget", "0.001"])
    out = capsys.readouterr().out
    assert "1 iterations (time budget), loss " in out
    folder = job / "optimize"
    for name in ("scratches.csv", "log.csv", "loss.png", "side_by_side.png", "summary.json"):
        assert (folder / name).is_file(), name
    with open(folder / "log.csv", newline="") as fh:
        iterations = [int(r["iteration"]) for r in csv.DictReader(fh)]
    assert iterations == [0, 1]  # the step taken, then the final layout's row
    state, _, rows = load_checkpoint(folder / "checkpoint.npz")
    assert int(state["iteration"]) == 1 and len(rows) == 1
    import json

    summary = json.loads((folder / "summary.json").read_text())
    assert summary["stopped"] == "time budget" and summary["iterations"] == 1
    assert len(_csv_segments(folder / "scratches.csv")) == len(
        _csv_segments(job / "design" / "scratches.csv")
    )


def test_prune_cli_reports_what_it_dropped(job: Path, capsys) -> None:
    main(["optimize", str(job), "--iterations", "4", "--prune", "0.05"])
    out = capsys.readouterr().out
    found = re.search(r"pruned (\d+) scratches: (\d+) mm of cutting, about (.+) of machining", out)
    assert found, out
    folder = job / "optimize"
    before = _csv_segments(folder / "scratches_unpruned.csv")
    after = _csv_segments(folder / "scratches.csv")
    assert len(before) == len(_csv_segments(job / "design" / "scratches.csv"))
    removed = len(before) - len(after)
    assert removed > 0 and int(found.group(1)) == removed
    # The kept scratches are a subset of the unpruned ones, and the length is theirs.
    kept = {tuple(np.round(r, 9)) for r in after}
    assert kept <= {tuple(np.round(r, 9)) for r in before}
    length = lambda s: np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]).sum()  # noqa: E731
    assert int(found.group(2)) == round(length(before) - length(after))
    import json

    assert json.loads((folder / "summary.json").read_text())["scratches"] == len(after)


def test_jitter_turns_each_scratch_about_its_centre(tmp_path: Path) -> None:
    design = make_design(resolution=16, size_mm=30.0)
    runs = {}
    for jitter in (0.0, 4.0):
        job = make_job(tmp_path / f"j{jitter:g}", design, count=150)
        run_optimize(job, OptimizeOptions(iterations=0, jitter_deg=jitter, seed=5))
        runs[jitter] = _csv_segments(job / "optimize" / "scratches.csv")
    plain, turned = runs[0.0], runs[4.0]
    np.testing.assert_allclose(plain, _csv_segments(tmp_path / "j0" / "design" / "scratches.csv"))
    centre = lambda s: 0.5 * (s[:, :2] + s[:, 2:])  # noqa: E731
    length = lambda s: np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1])  # noqa: E731
    np.testing.assert_allclose(centre(turned), centre(plain), atol=1e-9)
    np.testing.assert_allclose(length(turned), length(plain), rtol=1e-9)
    angle = lambda s: np.arctan2(s[:, 3] - s[:, 1], s[:, 2] - s[:, 0])  # noqa: E731
    turn = np.degrees(np.angle(np.exp(1j * (angle(turned) - angle(plain)))))
    assert np.all(np.abs(turn) > 0)
    # 150 draws of N(0, 4 deg): the sample deviation is within 20 % with room to spare.
    assert 3.2 < float(np.std(turn)) < 4.8


@pytest.mark.skipif(os.name == "nt", reason="the POSIX shell's quoting")
def test_interrupted_resume_command_pastes_as_the_job_folder(tmp_path, monkeypatch, capsys):
    from types import SimpleNamespace

    job = tmp_path / "job $(touch PWNED) 'it's' `touch PWNED2`"
    stopped = SimpleNamespace(
        quality={"views": {}},
        prune=None,
        iterations=3,
        stopped="interrupted",
        loss=0.5,
        out_dir=job / "optimize",
    )
    monkeypatch.setattr("scratchfab.cli.optimize_cmd.run_optimize", lambda *a, **k: stopped)
    with pytest.raises(SystemExit) as info:
        main(["optimize", str(job), "--iterations", "9", "--no-prune"])
    assert info.value.code == 130
    err = capsys.readouterr().err
    found = re.search(r"^interrupted after 3 of 9 iterations; `(.*)` continues it$", err.strip())
    assert found
    words = shlex.split(found.group(1))  # an independent reader of the quoting
    assert words == [
        *("scratchfab", "optimize", str(job), "--iterations", "9", "--no-prune", "--resume")
    ]  # a flag without its value
    assert pasted_words(found.group(1), tmp_path) == words  # and the shell agrees
    assert not list(tmp_path.rglob("PWNED*"))  # nothing ran


def test_non_finite_names_the_render_then_the_loss_then_the_gradient() -> None:
    """What a non-finite step is blamed on, and the advice, follow the first bad quantity."""
    from scratchfab.optimize.optimizer import _non_finite

    ok = np.ones((4, 5), np.float32)
    bad = ok.copy()
    bad[1, 2:4] = (math.inf, math.nan)
    grads = {k: np.zeros(6) for k in KEYS}
    assert _non_finite(0.5, {"a": ok, "b": ok}, grads) is None
    what, advice = _non_finite(math.nan, {"a": ok, "b": bad}, grads)  # type: ignore[misc]
    assert what == "non-finite render of view 'b' (2 of 20 pixels)" and "light" in advice
    what, advice = _non_finite(math.inf, {"a": ok}, grads)  # type: ignore[misc]
    assert what == "non-finite loss" and "learning rates" in advice
    grads["theta"][[3, 5]] = (math.nan, -math.inf)
    what, advice = _non_finite(0.5, {"a": ok}, grads)  # type: ignore[misc]
    assert what == "non-finite gradient of theta for 2 scratches (first: row 4)"
    assert "learning rates" in advice


def test_resume_goes_on_to_the_runs_own_total_and_a_finished_run_has_nothing_to_do(
    job: Path, capsys
) -> None:
    """`--resume` alone continues to the total the run was given (not the default 300);
    on a finished run it says so and neither compiles nor rewrites anything; a larger
    --iterations extends it."""
    folder = job / "optimize"
    main(["optimize", str(job), "--iterations", "5", "--time-budget", "0.001"])
    assert json.loads((folder / "summary.json").read_text())["iterations"] == 1
    capsys.readouterr()
    main(["optimize", str(job), "--resume"])
    assert "5 iterations (done)" in capsys.readouterr().out
    assert json.loads((folder / "summary.json").read_text())["iterations"] == 5

    def outputs() -> dict[Path, tuple[bytes, int]]:
        files = sorted(p for p in folder.rglob("*") if p.is_file())
        return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files}

    for total in (5, 7):
        before = outputs()
        main(["optimize", str(job), "--resume"])
        said = capsys.readouterr()
        assert said.out.startswith(f"nothing to do: the run had done its {total} iterations")
        assert f"give --iterations N (more than {total}) with --resume" in said.out
        assert "compiling kernels" not in said.err
        assert outputs() == before
        if total == 5:
            main(["optimize", str(job), "--resume", "--iterations", "7"])
            assert "7 iterations (done)" in capsys.readouterr().out
            state, _, rows = load_checkpoint(folder / "checkpoint.npz")
            assert int(state["iteration"]) == 7 and len(rows) == 7


def test_resume_of_a_run_killed_while_writing_its_outputs_writes_them_over_another_runs(
    job: Path,
) -> None:
    """A finished run's summary does not stand for another run of the same total that
    was killed after its last checkpoint and before its own summary: resuming that one
    writes its outputs (a stale summary of the same iteration count is not 'nothing to do')."""
    csv_file = job / "optimize" / "scratches.csv"
    run_optimize(job, OptimizeOptions(iterations=3, seed=0, jitter_deg=2.0))
    tool = make_design().scratch
    old = load_scratches(csv_file, tool)

    def killed(p) -> None:  # type: ignore[no-untyped-def]
        if p.message == "writing outputs":  # after the last checkpoint
            raise KeyboardInterrupt

    other = OptimizeOptions(iterations=3, seed=1, jitter_deg=2.0)
    with pytest.raises(KeyboardInterrupt):
        run_optimize(job, other, progress=killed)
    assert load_scratches(csv_file, tool).p0.tolist() == old.p0.tolist()  # seed 0's still
    result = run_optimize(job, replace(other, resume=True))
    assert result.stopped == "done"
    made = load_scratches(csv_file, tool)
    assert not np.allclose(made.p0, old.p0)  # seed 1's layout, not seed 0's
    np.testing.assert_allclose(made.p0, result.scratches.p0, atol=1e-5)


def test_resume_of_a_finished_run_with_a_damaged_summary_writes_the_outputs_again(
    job: Path,
) -> None:
    """A summary too deeply nested for Python's parser (RecursionError, not a ValueError)
    is damage like any other: the resume writes the outputs again instead of failing."""
    run_optimize(job, OptimizeOptions(iterations=2, seed=0, jitter_deg=2.0))
    summary = job / "optimize" / "summary.json"
    summary.write_text("[" * 100_000 + "]" * 100_000)
    result = run_optimize(job, OptimizeOptions(iterations=2, seed=0, jitter_deg=2.0, resume=True))
    assert result.stopped == "done"
    assert json.loads(summary.read_text())["iterations"] == 2


def test_resume_alone_of_a_pruned_run_keeps_its_prune(job: Path, capsys) -> None:
    """`--resume` alone goes on with the run's own --prune as with its own total: on a
    finished pruned run there is nothing to do (it rewrote the layout unpruned), and an
    extension prunes again; a run of --iterations 0 has its own total too."""
    folder = job / "optimize"
    main(["optimize", str(job), "--iterations", "2", "--prune", "0.5"])
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["prune"]["removed"] > 0
    pruned = (folder / "scratches.csv").read_bytes()
    capsys.readouterr()
    main(["optimize", str(job), "--resume"])
    assert capsys.readouterr().out.startswith("nothing to do: the run had done its 2 iterations")
    assert (folder / "scratches.csv").read_bytes() == pruned
    main(["optimize", str(job), "--resume", "--iterations", "3"])
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["iterations"] == 3 and summary["options"]["prune_tolerance"] == 0.5
    assert "prune" in summary
    main(["optimize", str(job), "--iterations", "0"])
    capsys.readouterr()
    main(["optimize", str(job), "--resume"])
    assert capsys.readouterr().out.startswith("nothing to do: the run had done its 0 iterations")


def _edit_design(job: Path, **tables: Any) -> None:
    """Rewrite ``JOB/design/design.toml`` with some of its tables' keys changed.

    ``board={"roughness": 0.08}``; ``views={"left": {"position_mm": ...}}``.
    """
    from scratchfab.model.job import load_job_design

    file = job / "design" / "design.toml"
    design = load_job_design(file)
    views = tables.pop("views", {})
    design = replace(
        design,
        **{name: replace(getattr(design, name), **keys) for name, keys in tables.items()},
        views=tuple(replace(v, **views.get(v.name, {})) for v in design.views),
    )
    design.save(file)


@pytest.mark.parametrize(
    ("edit", "said"),
    [
        ({"board": {"roughness": 0.08}}, "[board] roughness 0.05 -> 0.08"),
        ({"light": {"intensity": 2.0}}, "[light] intensity 1 -> 2"),
        (
            {"views": {"left": {"position_mm": (-100.0, 0.0, 300.0)}}},
            "[[views]] 'left' position_mm [-120, 0, 300] -> [-100, 0, 300]",
        ),
    ],
)
def test_resume_refuses_a_design_changed_since_its_checkpoint_naming_the_keys(
    job: Path, capsys, edit: dict[str, Any], said: str
) -> None:
    """A design change that leaves the layout and targets alone (the board's finish, the
    light, a camera) changes the renders the steps follow: the resume names it and its
    values then and now (make_design's), and a pipeline's resume starts over."""
    main(["optimize", str(job), "--iterations", "2"])
    _edit_design(job, **edit)
    with pytest.raises(SystemExit) as info:
        main(["optimize", str(job), "--iterations", "3", "--resume"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    toml = job / "design" / "design.toml"
    assert f"{toml} changed since it was made ({said}): its steps so far fit the old design" in err
    assert err.rstrip().endswith("; run without --resume to start over")
    assert "different settings" not in err and "give that" not in err
    main(["optimize", str(job), "--iterations", "3"])  # what it says to do works
    assert "3 iterations (done)" in capsys.readouterr().out


def test_resume_names_options_and_design_changed_together(job: Path) -> None:
    """Both kinds of change are named; no options can resume it then."""
    from scratchfab.optimize.stage import ResumeRefused

    run_optimize(job, OptimizeOptions(iterations=2))
    _edit_design(job, board={"f0": 0.5}, views={"right": {"fov_deg": 10.0}})
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=2, seed=3, resume=True))
    exc = info.value
    assert exc.made_with is None
    assert exc.changed == ["seed", "[board] f0", "[[views]] 'right' fov_deg"]
    assert exc.design["[board] f0"] == "0.91 -> 0.5"
    assert str(exc).startswith(
        f"{job / 'optimize' / 'checkpoint.npz'}: made with different settings (seed); "
        f"{job / 'design' / 'design.toml'} changed since it was made ([board] f0 0.91 -> 0.5, "
        "[[views]] 'right' fov_deg "
    )


def test_a_checkpoint_that_records_no_design_resumes_as_an_unbroken_run(tmp_path: Path) -> None:
    """A checkpoint of the scratchfab before (no design in its fingerprint) resumes, in a
    job moved since too (its pictures' paths differ), on the trajectory of a run that was
    not stopped; the checkpoint it writes records the design."""
    design = make_design(resolution=24, size_mm=30.0)
    a = make_job(tmp_path / "a", design, count=150)
    b = make_job(tmp_path / "b", design, count=150)
    options = OptimizeOptions(iterations=4, seed=2)
    run_optimize(a, options)
    steps: list[int] = []
    run_optimize(
        b,
        options,
        progress=lambda p: steps.append(p.iteration) if not p.message else None,
        should_stop=lambda: len(steps) == 2,
    )
    ckpt = b / "optimize" / "checkpoint.npz"
    state, meta, rows = load_checkpoint(ckpt)
    del meta["fingerprint"]["design"]
    save_checkpoint(ckpt, state, meta, rows)
    moved = b.rename(tmp_path / "moved")
    result = run_optimize(moved, replace(options, resume=True))
    assert steps == [1, 2] and result.stopped == "done"
    done = (moved / "optimize" / "scratches.csv").read_bytes()
    assert done == (a / "optimize" / "scratches.csv").read_bytes()
    _, meta, _ = load_checkpoint(moved / "optimize" / "checkpoint.npz")
    assert meta["fingerprint"]["design"]["board"]["roughness"] == design.board.roughness


def test_resume_alone_of_an_extended_run_goes_on_to_its_extended_total(job: Path, capsys) -> None:
    """A run of 2 steps extended to 4 and stopped at 3 goes on to 4, also from a checkpoint
    of the scratchfab before (that kept no total: its schedule's is 2), which takes the total
    from the summary written from it; without that summary the total is not known."""
    from scratchfab.optimize.stage import checkpoint_request

    stopped_at_three_of_four(job)
    ckpt = job / "optimize" / "checkpoint.npz"
    state, meta, rows = load_checkpoint(ckpt)
    assert meta["fingerprint"]["lr_schedule"]["iterations"] == 2
    assert checkpoint_request(job) == {"iterations": 4, "prune_tolerance": None}
    del meta["iterations"], meta["prune_tolerance"]  # as the scratchfab before wrote it
    save_checkpoint(ckpt, state, meta, rows)
    assert checkpoint_request(job) == {"iterations": 4, "prune_tolerance": None}
    summary = (job / "optimize" / "summary.json").read_bytes()
    (job / "optimize" / "summary.json").unlink()  # killed, not stopped: no summary of it
    assert checkpoint_request(job) == {}
    (job / "optimize" / "summary.json").write_bytes(summary)
    capsys.readouterr()
    main(["optimize", str(job), "--resume"])
    assert "4 iterations (done)" in capsys.readouterr().out


def test_resume_with_no_prune_drops_the_runs_prune(job: Path, capsys) -> None:
    """Pruning follows the steps, so a resume may drop it: a finished pruned run's outputs
    are written again unpruned, the layout the pruned run kept as its layout before
    pruning; a bare resume then has nothing to do. --prune with --no-prune is refused."""
    folder = job / "optimize"
    main(["optimize", str(job), "--iterations", "2", "--prune", "0.5"])
    unpruned = (folder / "scratches_unpruned.csv").read_bytes()
    assert unpruned != (folder / "scratches.csv").read_bytes()
    capsys.readouterr()
    main(["optimize", str(job), "--resume", "--no-prune"])
    out = capsys.readouterr().out
    assert out.startswith(
        "--no-prune: the run's own --prune 0.5 is dropped; its outputs are written without "
        "pruning\n"
    )
    assert "2 iterations (done)" in out and "pruned" not in out
    assert (folder / "scratches.csv").read_bytes() == unpruned
    assert not (folder / "scratches_unpruned.csv").exists()
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["options"]["prune_tolerance"] is None and "prune" not in summary
    main(["optimize", str(job), "--resume"])
    assert capsys.readouterr().out.startswith("nothing to do: the run had done its 2 iterations")
    with pytest.raises(SystemExit) as info:
        main(["optimize", str(job), "--resume", "--prune", "0.1", "--no-prune"])
    assert info.value.code == 2
    assert "give --prune or --no-prune, not both" in capsys.readouterr().err


def test_resume_after_a_design_rerun_says_so_in_the_users_terms(job: Path, capsys) -> None:
    """A changed target (as a design rerun writes) is named as the design's outputs, not
    as the fingerprint's digest key, by optimize and by the pipeline's restart line."""
    from scratchfab.optimize.stage import ResumeRefused

    main(["optimize", str(job), "--iterations", "2"])
    target = sorted((job / "design" / "targets").glob("*.npy"))[0]
    np.save(target, np.load(target) * 0.5)
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=2, resume=True))
    assert info.value.changed == ["inputs_sha256"]
    assert "inputs_sha256" not in str(info.value)
    assert info.value.reasons() == (
        f"design/targets/{target.name} changed since it was made: design was rerun"
    )


def test_resume_refuses_views_given_in_another_order(job: Path) -> None:
    """The views' order sets the order of the loss's terms and of log.csv's columns: a
    checkpoint's steps (and its log rows) follow its own order, so reordered views are named
    as a change; a checkpoint that records no order (made before it was kept) is refused
    too, its order read from its log's columns."""
    from scratchfab.model.job import load_job_design
    from scratchfab.optimize.stage import ResumeRefused

    run_optimize(job, OptimizeOptions(iterations=2))
    file = job / "design" / "design.toml"
    design = load_job_design(file)
    names = [v.name for v in design.views]
    replace(design, views=design.views[::-1]).save(file)
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=3, resume=True))
    first, second = names
    assert info.value.design == {"[[views]] order": f"[{first}, {second}] -> [{second}, {first}]"}
    ckpt = job / "optimize" / "checkpoint.npz"
    state, meta, rows = load_checkpoint(ckpt)
    del meta["fingerprint"]["design"]["view_order"]
    save_checkpoint(ckpt, state, meta, rows)
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=3, resume=True))
    assert info.value.design == {"[[views]] order": f"[{first}, {second}] -> [{second}, {first}]"}


def test_a_time_budget_stop_says_the_budget_counts_the_whole_run_and_how_to_go_on(
    job: Path, capsys
) -> None:
    """A --time-budget counts the run's optimizing in all, earlier sessions included, so a
    resume given the spent budget again takes no step: both stops say so, and the command
    they name, run as written, goes on to the run's total."""
    main(["optimize", str(job), "--iterations", "5", "--time-budget", "0.001"])
    out = capsys.readouterr().out
    assert "1 iterations (time budget)" in out
    said = out.splitlines()[-1]
    assert "its earlier sessions' too" in said, out
    command = said.split("`")[1]
    assert command == f"scratchfab optimize {job} --resume"
    main(["optimize", str(job), "--resume", "--time-budget", "0.001"])
    out = capsys.readouterr().out
    assert "1 iterations (time budget)" in out and out.splitlines()[-1] == said
    main(shlex.split(command)[1:])
    assert "5 iterations (done)" in capsys.readouterr().out
