"""Frozen steps (dr.freeze) against traced ones, and the touch masks against brute force.

Every value a frozen step reads must reach the recording as an argument or a key, or a
replay silently reuses the value it was recorded with. The table below changes, between
steps of one run, everything that a run or a caller can change; frozen and traced runs
must then agree bit for bit (one thread: atomics add in thread order).
"""

from __future__ import annotations

import dataclasses
import gc
import math
from collections.abc import Callable
from typing import Any

import drjit as dr
import numpy as np
import pytest
from conftest import make_design
from test_optimize_helpers import cross_of, make_layout

from scratchfab.model.scratches import ScratchSet
from scratchfab.optimize.optimizer import LayoutOptimizer, NonFiniteError, Settings
from scratchfab.optimize.params import KEYS, endpoints
from scratchfab.render.renderer import pair_footprints, render_pairs

LR = {"cx": 0.03, "cy": 0.03, "theta": math.radians(0.25), "length": 0.03}
FAST = {"cx": 0.12, "cy": 0.12, "theta": math.radians(1.5), "length": 0.12}

Hook = Callable[[LayoutOptimizer, int, dict[int, dict[str, np.ndarray]]], None]


@pytest.fixture(scope="module")
def board() -> tuple[Any, dict[str, np.ndarray]]:
    design = make_design(resolution=20, size_mm=30.0)
    targets, _ = cross_of(design)
    return design, targets


@pytest.fixture
def one_thread() -> Any:
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(threads)


def _edge_layout(design: Any, count: int, seed: int) -> ScratchSet:
    """Random scratches, a quarter of them pushed against the board's margin line."""
    base = make_layout(design, count, seed)
    c = 0.5 * (base.p0 + base.p1)
    half = 0.5 * (base.p1 - base.p0)
    edge = design.board.half_extent[0] - design.board.margin_mm
    push = np.arange(count) % 4 == 0
    c[push, 0] = np.sign(c[push, 0]) * edge  # projection clamps them onto the margin line
    return ScratchSet.from_arrays(c - half, c + half, base.width, base.depth)


def _sparse_layout(design: Any) -> ScratchSet:
    """Six scratches far apart: merge candidates never exist."""
    c = np.array([[-9.0, -9.0], [0.0, -9.0], [9.0, -9.0], [-9.0, 9.0], [0.0, 9.0], [9.0, 9.0]])
    half = np.array([[1.5, 0.4]] * 3 + [[0.3, 1.5]] * 3)
    return ScratchSet.from_arrays(c - half, c + half, 0.1, 0.01)


def _snapshot(opt: LayoutOptimizer, result: Any) -> dict[str, Any]:
    return {
        "loss": result.loss,
        "errors": result.view_errors,
        "renders": result.renders,
        "state": opt.state(),
        "ends": opt.ends.copy(),
        "active": None if opt.active is None else [np.array(a, copy=True) for a in opt.active],
    }


def _run(
    design: Any,
    targets: Any,
    layout: ScratchSet,
    settings: Settings,
    m: Any,
    freeze: bool,
    steps: int,
    hook: Hook | None,
) -> tuple[list[dict[str, Any]], LayoutOptimizer]:
    opt = LayoutOptimizer(design, targets, layout, settings, m, freeze=freeze)
    saved: dict[int, dict[str, np.ndarray]] = {}
    out = []
    for i in range(steps):
        if hook is not None:
            hook(opt, i, saved)
        out.append(_snapshot(opt, opt.step()))
    return out, opt


def _same(a: Any, b: Any, where: str) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and np.array_equal(a, b), where
    else:
        assert a == b, where


# -- hooks: what a caller may change between steps of one optimizer


def _resume_into_new(at: int) -> Hook:
    """Marker hook: the driver below splits the run at ``at`` into a new optimizer."""

    def hook(opt: LayoutOptimizer, i: int, saved: dict[int, dict[str, np.ndarray]]) -> None:
        return None

    hook.resume_at = at  # type: ignore[attr-defined]
    return hook


def _rewind(save_at: int, load_at: int) -> Hook:
    """Save the state before step ``save_at``, load it again before step ``load_at``."""

    def hook(opt: LayoutOptimizer, i: int, saved: dict[int, dict[str, np.ndarray]]) -> None:
        if i == save_at:
            saved[i] = opt.state()
        if i == load_at:
            opt.load_state(saved[save_at])

    return hook


def _decay_lr(at: int, factor: float) -> Hook:
    """A learning-rate schedule: every rate times ``factor`` before step ``at``."""

    def hook(opt: LayoutOptimizer, i: int, saved: dict[int, dict[str, np.ndarray]]) -> None:
        if i == at:
            opt.opt.set_learning_rate({k: float(opt.settings.lr[k]) * factor for k in KEYS})

    return hook


def _change_settings(at: int, **changes: Any) -> Hook:
    """Settings (space, weights) replaced before step ``at``, as a schedule would."""

    def hook(opt: LayoutOptimizer, i: int, saved: dict[int, dict[str, np.ndarray]]) -> None:
        if i == at:
            opt.settings = dataclasses.replace(opt.settings, **changes)

    return hook


CASES: dict[str, tuple[str, dict[str, Any], int, Hook | None]] = {
    # name: (layout, settings, steps, hook)
    "linear-merge-K3": ("random", {"refresh_every": 3, "merge_weight": 1.0}, 7, None),
    "perceptual-K4": ("random", {"refresh_every": 4, "space": "perceptual"}, 6, None),
    "merge-off-K2": ("random", {"refresh_every": 2, "merge_weight": 0.0}, 5, None),
    "refresh-every-step": ("random", {"refresh_every": 1}, 4, None),
    "no-merge-candidates": ("sparse", {"refresh_every": 3, "merge_weight": 1.0}, 5, None),
    "board-edge-fast": ("edge", {"refresh_every": 5, "lr": FAST}, 6, None),
    "resume-mid-period": ("random", {"refresh_every": 4}, 7, _resume_into_new(2)),
    "rewind-same-optimizer": ("random", {"refresh_every": 3}, 7, _rewind(1, 5)),
    "lr-decay-mid-run": ("random", {"refresh_every": 4}, 10, _decay_lr(2, 0.5)),
    "settings-change-mid-run": (
        "random",
        {"refresh_every": 4, "merge_weight": 1.0},
        6,
        _change_settings(2, merge_weight=3.0, bound_weight=5.0, space="perceptual"),
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_frozen_run_equals_traced_run(m, board, one_thread, case) -> None:
    """Frozen and traced optimizers take the same steps, bit for bit, in every case."""
    design, targets = board
    kind, changes, steps, hook = CASES[case]
    layout = {
        "random": lambda: make_layout(design, 60, seed=11),
        "edge": lambda: _edge_layout(design, 60, seed=12),
        "sparse": lambda: _sparse_layout(design),
    }[kind]()
    settings = Settings(**{"lr": LR, **changes})
    resume_at = getattr(hook, "resume_at", None)
    if resume_at is None:
        frozen, opt = _run(design, targets, layout, settings, m, True, steps, hook)
    else:
        # the stage's resume: a fresh (frozen) optimizer loads the checkpoint mid-period
        head, first = _run(design, targets, layout, settings, m, True, resume_at, None)
        opt = LayoutOptimizer(design, targets, layout, settings, m, freeze=True)
        opt.load_state(first.state())
        frozen = head + [_snapshot(opt, opt.step()) for _ in range(steps - resume_at)]
    traced, _ = _run(design, targets, layout, settings, m, False, steps, hook)
    for i, (a, b) in enumerate(zip(frozen, traced, strict=True)):
        _same(a, b, f"step {i}")
    assert opt._train_step.n_recordings >= 1  # type: ignore[attr-defined]
    # the run really replayed: fewer recordings than steps
    assert opt._train_step.n_recordings < steps  # type: ignore[attr-defined]


# ---------------------------------------------------------------- touch masks


def _brute_pairs(
    opt: LayoutOptimizer, ends: list[np.ndarray], m: Any
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per view, every on-board (pixel, scratch) pair (all pixels x all scratches) with the
    largest of |NDF|, |covered area| and |their derivative along random endpoint moves|.

    One forward-mode pass with random weights per endpoint coordinate: a pair whose
    derivative along one coordinate is not zero has a non-zero directional derivative
    (but for a measure-zero set of weights).
    """
    F, U = m.Float64, m.UInt32
    rng = np.random.default_rng(5)
    n = len(ends[0])
    out = []
    for r in opt.renderers:
        ok = np.flatnonzero(r.pixel_ok).astype(np.uint32)
        pix_np = np.repeat(ok, n)
        sc_np = np.tile(np.arange(n, dtype=np.uint32), len(ok))
        pix, sc = U(pix_np), U(sc_np)
        e = [F(x) for x in ends]
        for x in e:
            dr.enable_grad(x)
        ndf, covered = pair_footprints(r.state, r.alpha, *e, opt._half_width, opt._wbar, pix, sc)
        for x in e:
            dr.set_grad(x, F(rng.uniform(0.5, 1.5, n)))
        g_ndf, g_cov = dr.forward_to(ndf, covered)
        size = np.max(
            np.abs(
                [
                    np.asarray(dr.detach(ndf)),
                    np.asarray(dr.detach(covered)),
                    np.asarray(g_ndf),
                    np.asarray(g_cov),
                ]
            ),
            axis=0,
        )
        out.append((pix_np, sc_np, size))
    return out


def _active_sets(opt: LayoutOptimizer) -> list[set[tuple[int, int]]]:
    assert opt.active is not None
    out = []
    for pairs, keep in zip(opt.pairs, opt.active, strict=True):
        k = np.asarray(keep, dtype=np.int64)
        out.append(set(zip(pairs.pixel_np[k].tolist(), pairs.scratch_np[k].tolist(), strict=True)))
    return out


def test_frozen_touch_masks_keep_every_contributing_pair(m, board) -> None:
    """Scratches moving fast (up to the pair margin) and at the board's edge.

    At every step, brute force (all pixels x all scratches) at the endpoints the next
    step renders: every pair the frozen step's mask dropped adds exactly 0.0 with
    exactly 0.0 derivatives, and every pair outside the pairs in use (the refresh's
    margin) adds nothing above rounding (footprints past a scratch's far end cancel only
    to rounding, see :meth:`LayoutOptimizer._touching`).
    """
    design, targets = board
    layout = _edge_layout(design, 40, seed=21)
    opt = LayoutOptimizer(design, targets, layout, Settings(lr=FAST, refresh_every=6), m)
    start = opt.ends.copy()
    dropped = kept = 0
    for i in range(5):
        opt.step()
        assert opt.active is not None, i
        with dr.suspend_grad():
            rendered_next = np.stack([np.asarray(e) for e in _projected_ends(opt)], axis=1)
        assert np.array_equal(rendered_next, opt.ends)
        brute = _brute_pairs(opt, [rendered_next[:, k] for k in range(4)], m)
        for (pix, sc, size), pairs, active in zip(brute, opt.pairs, _active_sets(opt), strict=True):
            n = int(sc.max()) + 1
            key = pix.astype(np.int64) * n + sc
            in_use = np.isin(key, pairs.pixel_np.astype(np.int64) * n + pairs.scratch_np)
            act = np.array(
                [(p, s) in active for p, s in zip(pix.tolist(), sc.tolist(), strict=True)]
            )
            assert not np.any(act & ~in_use)
            masked = in_use & ~act
            assert not np.any(size[masked]), (i, np.flatnonzero(size[masked])[:5])
            assert np.all(size[~in_use] <= 1e-12 * size.max()), (i, size[~in_use].max())
            dropped += int(masked.sum())
            kept += int(act.sum())
    moved = np.abs(opt.ends - start).max()
    assert moved > 0.5 * 5 * FAST["cx"]  # the scratches did move (clipped Adam: <= lr a step)
    assert kept > 200 and dropped > 0


def _projected_ends(opt: LayoutOptimizer) -> tuple[Any, ...]:
    return endpoints(*opt._projected())


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_touch_mask_keeps_every_contributing_pair_of_odd_layouts(m, board, seed) -> None:
    """Zero-length scratches, scratches on the board's edge and random ones: the pairs
    :meth:`_touching` drops (out of all pixels x all scratches) contribute nothing, and the
    kept pairs alone render the images and gradients of all pairs."""
    design, targets = board
    rng = np.random.default_rng(seed)
    n = 24
    edge = design.board.half_extent[0] - design.board.margin_mm
    c = rng.uniform(-edge, edge, (n, 2))
    c[:4, 0] = np.array([-edge, edge, -edge, edge])  # centres on the margin line
    theta = rng.uniform(-math.pi, math.pi, n)
    length = rng.uniform(0.5, 6.0, n)
    length[4:8] = 0.0  # zero length
    length[8] = 1e-9
    u = np.stack([np.cos(theta), np.sin(theta)], 1) * length[:, None] / 2
    p0, p1 = c - u, c + u
    layout = ScratchSet.from_arrays(p0 + 0.1, p1 + 0.1, 0.1, 0.01)  # any start
    opt = LayoutOptimizer(design, targets, layout, Settings(lr=LR), m)
    F, U = m.Float64, m.UInt32
    ends = [p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1]]
    brute = _brute_pairs(opt, ends, m)
    ctx = opt._context()
    ctx["pairs"] = [(U(p), U(s)) for p, s, _size in brute]
    masks = opt._touching(tuple(F(e) for e in ends), ctx)
    dr.eval(masks)
    all_pairs = [(p, s) for p, s, _size in brute]
    kept_total = 0
    for (_pix, _sc, size), mask in zip(brute, masks, strict=True):
        keep = np.asarray(mask, dtype=bool)
        # what the mask drops is exactly zero, value and derivatives
        assert not np.any(size[~keep]), np.flatnonzero(size[~keep])[:5]
        assert 0 < keep.sum() < len(keep)
        kept_total += int(keep.sum())
    assert kept_total > 0

    # renders and gradients: kept pairs alone against every pair
    def render(use_mask: bool) -> tuple[list[np.ndarray], list[np.ndarray]]:
        e = [F(x) for x in ends]
        for x in e:
            dr.enable_grad(x)
        imgs = []
        total = F(0.0)
        for r, (pix, sc), mask in zip(opt.renderers, all_pairs, masks, strict=True):
            sel = np.asarray(mask, dtype=bool) if use_mask else np.ones(len(pix), bool)
            img = render_pairs(
                r.state, r.alpha, r.pixel_count, *e, opt._half_width, opt._wbar,
                U(pix[sel]), U(sc[sel]),
            )  # fmt: skip
            imgs.append(img)
            total = total + dr.sum(img * F(np.linspace(0.5, 1.5, r.pixel_count)))
        dr.backward(total)
        return [np.asarray(i) for i in imgs], [np.asarray(dr.grad(x)) for x in e]

    imgs_k, grads_k = render(True)
    imgs_a, grads_a = render(False)
    for a, b in zip(imgs_k, imgs_a, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13 * float(np.abs(b).max()))
    scale = max(float(np.abs(g).max()) for g in grads_a)
    assert scale > 0
    for a, b in zip(grads_k, grads_a, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * scale)


def test_frozen_step_that_fails_leaves_the_state_before_it(m, board, one_thread) -> None:
    """NonFiniteError restores the parameters and moments from before the step.

    A frozen replay writes its new values into the optimizer's own array objects, so
    the step must keep the old state in other objects; checked after the recordings
    exist (the step that fails is a replay), against the state before the step and a
    traced run.
    """
    design, targets = board
    layout = make_layout(design, 60, seed=13)
    settings = Settings(lr=LR, refresh_every=4)
    states = []
    for freeze in (True, False):
        opt = LayoutOptimizer(design, targets, layout, settings, m, freeze=freeze)
        for _ in range(5):
            opt.step()
        if freeze:
            count = opt._train_step.n_recordings  # type: ignore[attr-defined]
        before = opt.state()
        keep = opt.renderers[0]._factor
        opt.renderers[0]._factor = keep * math.nan  # data, so a replay sees it too
        with pytest.raises(NonFiniteError, match="iteration 5"):
            opt.step()
        opt.renderers[0]._factor = keep
        _same(opt.state(), before, "restored")
        opt.step()  # and the run can go on from there
        states.append(opt.state())
        if freeze:
            assert opt._train_step.n_recordings == count  # type: ignore[attr-defined]
    # as a fresh optimizer that never saw the failed step (no gradient left over from it)
    clean = LayoutOptimizer(design, targets, layout, settings, m)
    clean.load_state(before)
    clean.step()
    _same(states[0], clean.state(), "frozen against clean")
    _same(states[1], clean.state(), "traced against clean")


@pytest.mark.parametrize("caller_collects", [True, False])
def test_step_turns_the_cycle_collector_off_only_during_the_step(m, board, caller_collects) -> None:
    """The frozen step runs without Python's cycle collector (a collection inside a
    recording can abort Dr.Jit); the caller's setting comes back after a step, a
    NonFiniteError and an interrupt inside the step, and one that was off stays off."""
    design, targets = board
    layout = make_layout(design, 40, seed=17)
    opt = LayoutOptimizer(design, targets, layout, Settings(lr=LR, refresh_every=4), m)
    frozen = opt._train_step
    seen: list[bool] = []
    interrupt = [False]

    def watched(*args: Any) -> Any:
        seen.append(gc.isenabled())
        if interrupt[0]:
            raise KeyboardInterrupt
        return frozen(*args)

    opt._train_step = watched
    was = gc.isenabled()
    (gc.enable if caller_collects else gc.disable)()
    try:
        opt.step()
        assert gc.isenabled() == caller_collects
        keep = opt.renderers[0]._factor
        opt.renderers[0]._factor = keep * math.nan
        with pytest.raises(NonFiniteError):
            opt.step()
        opt.renderers[0]._factor = keep
        assert gc.isenabled() == caller_collects
        interrupt[0] = True
        with pytest.raises(KeyboardInterrupt):
            opt.step()
        assert gc.isenabled() == caller_collects
        interrupt[0] = False
        opt.step()  # and the run goes on
        assert gc.isenabled() == caller_collects
    finally:
        (gc.enable if was else gc.disable)()
    assert seen == [False] * 4
