"""The bare board's glint is left out of the optimizer's image error (s_k and E_k).

A small two-view board whose left view sees the light's mirror image in a corner (3.6 %
of the board glints, as in a maker's 200 mm copy of the demo); the right view has none.
References: half-vectors computed here from the camera's pixel centres and the light,
the design check's glint share, the image error in numpy over the pixels left, and
finite differences.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import drjit as dr
import numpy as np
import pytest
from PIL import Image
from test_optimize_helpers import cross_of, make_job, make_layout

import scratchfab.optimize.optimizer as optimizer_module
from scratchfab import metrics
from scratchfab.design.feasibility import check_feasibility, design_glint_deg, glint_limit_deg
from scratchfab.model.camera import Camera
from scratchfab.model.design import Design, design_from_mapping
from scratchfab.optimize.glint import GLINT_RGB, ViewGlint
from scratchfab.optimize.loss import view_error
from scratchfab.optimize.optimizer import LayoutOptimizer, Settings
from scratchfab.optimize.progress import message_text, progress_printer
from scratchfab.optimize.stage import Progress

LR = {"cx": 0.12, "cy": 0.12, "theta": math.radians(1.0), "length": 0.12}


def glint_design(resolution: int = 32, count: int = 800) -> Design:
    """40 mm board; the light's mirror image for the left camera at the corner (-30, 30)."""
    tables = {
        "board": {"width_mm": 40.0, "height_mm": 40.0, "roughness": 0.05, "margin_mm": 1.0},
        "light": {"position_mm": [0.0, 60.0, 300.0]},
        "scratch": {
            "width_mm": 0.1,
            "depth_mm": 0.01,
            "count": count,
            "min_length_mm": 1.0,
            "max_length_mm": 6.0,
        },
        "views": [
            {"name": name, "position_mm": pos, "fov_deg": "auto", "resolution": [resolution] * 2}
            for name, pos in [("left", [-60.0, 0.0, 300.0]), ("right", [120.0, 0.0, 300.0])]
        ],
    }
    return design_from_mapping(tables, "<glint test design>", Path("."))


def reference_glint(design: Design, name: str) -> np.ndarray:
    """Pixels on the board whose centre's half-vector tilts below the glint limit (numpy)."""
    view = next(v for v in design.views if v.name == name)
    cam = Camera.from_view(view)
    c, ok = cam.center_grid()
    hw, hh = design.board.half_extent
    p = np.concatenate([c, np.zeros(c.shape[:-1] + (1,))], axis=-1)
    wi = np.asarray(design.light.position_mm, dtype=np.float64) - p
    wo = np.asarray(view.position_mm, dtype=np.float64) - p
    h = wi / np.linalg.norm(wi, axis=-1, keepdims=True) + wo / np.linalg.norm(
        wo, axis=-1, keepdims=True
    )
    tilt = np.degrees(np.arccos(h[..., 2] / np.linalg.norm(h, axis=-1)))
    tool = design.scratch
    limit = glint_limit_deg(tool.width_mm, tool.depth_mm, design.board.roughness)
    inside = ok & (np.abs(c[..., 0]) < hw) & (np.abs(c[..., 1]) < hh)
    return inside & (tilt < limit)


@pytest.fixture(scope="module")
def small() -> tuple[Design, dict[str, np.ndarray]]:
    design = glint_design()
    targets, _ = cross_of(design)
    return design, targets


def test_the_mask_is_the_design_checks_glint(m, small) -> None:
    """The left view's mask: the reference pixels, about the check's share of the board."""
    design, targets = small
    opt = LayoutOptimizer(design, targets, make_layout(design, 50, seed=1), Settings(lr=LR), m)
    left, right = opt.glint
    ref = reference_glint(design, "left")
    assert ref.any() and np.array_equal(left.mask, ref)
    assert not right.mask.any() and right.note() == ""
    share = check_feasibility(design).views["left"].glint_fraction
    assert share == pytest.approx(0.036, abs=0.005)
    assert left.board_share == pytest.approx(share, abs=0.01)  # 32 px against a 96 grid
    # the target the error sees: NaN there, the given target elsewhere
    t = opt.target_np["left"]
    assert np.all(np.isnan(t[ref]))
    np.testing.assert_array_equal(t[~ref], targets["left"][~ref])


def test_image_error_leaves_the_glint_out(m, small) -> None:
    """E_k of the optimizer equals the numpy error over the pixels off the glint."""
    design, targets = small
    layout = make_layout(design, 300, seed=2)
    opt = LayoutOptimizer(design, targets, layout, Settings(lr=LR), m)
    result = opt.evaluate(layout)
    ref = reference_glint(design, "left")
    for name, skip in (("left", ref), ("right", np.zeros_like(ref))):
        r = result.renders[name].astype(np.float64)
        t = np.where(skip, np.nan, targets[name])
        ok = np.isfinite(t)
        s = metrics.exposure(r, t)
        expected = np.sum((s * r[ok] - t[ok]) ** 2) / np.sum(t[ok] ** 2)
        # the renders come back as float32
        assert result.view_errors[name] == pytest.approx(expected, rel=1e-5), name
    # what counting the glint would give differs by far more
    r, t = result.renders["left"].astype(np.float64), targets["left"]
    ok = np.isfinite(t)
    s = metrics.exposure(r, t)
    whole = np.sum((s * r[ok] - t[ok]) ** 2) / np.sum(t[ok] ** 2)
    assert abs(whole - result.view_errors["left"]) > 0.05


@pytest.mark.parametrize("space", ["linear", "perceptual"])
def test_masked_view_error_gradient_matches_finite_differences(m, rng, space) -> None:
    """d E_k / d R_k with glint-like holes in the mask: zero there, finite differences elsewhere."""
    n = 200
    r = rng.uniform(0.05, 2.0, n)
    t = rng.uniform(0.0, 1.0, n)
    mask = np.ones(n)
    mask[20:40] = 0.0  # the glint
    mask[::17] = 0.0
    r[20:40] *= 50.0  # far brighter than the rest: it would set the exposure
    F = m.Float64

    def enc(v: np.ndarray) -> np.ndarray:
        return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.maximum(v, 0) ** (1 / 2.4) - 0.055)

    def reference(rr: np.ndarray) -> float:
        ok = mask > 0
        s = float(rr[ok] @ t[ok]) / float(rr[ok] @ rr[ok])
        g = (lambda v: v) if space == "linear" else enc
        return float(np.sum((g(s * rr[ok]) - g(t[ok])) ** 2) / np.sum(g(t[ok]) ** 2))

    render = F(r)
    dr.enable_grad(render)
    err, _s = view_error(render, F(t * mask), F(mask), space)  # type: ignore[arg-type]
    dr.backward(err)
    grad = np.asarray(dr.grad(render), dtype=np.float64)
    assert float(err[0]) == pytest.approx(reference(r), rel=1e-10)
    assert np.all(grad[mask == 0] == 0.0)
    h = 1e-6
    for i in np.flatnonzero(mask > 0)[::7]:
        plus, minus = r.copy(), r.copy()
        plus[i] += h
        minus[i] -= h
        fd = (reference(plus) - reference(minus)) / (2 * h)
        assert grad[i] == pytest.approx(fd, rel=1e-5, abs=1e-9), i


def test_leaving_the_glint_out_shows_the_image_around_it(m, small, monkeypatch) -> None:
    """100 steps: outside the glint the left view correlates clearly better with its target
    than when the glint is counted (the limit set to 0 deg: no glint, the earlier error)."""
    design, targets = small
    layout = make_layout(design, 800, seed=5)
    ref = reference_glint(design, "left")
    outside = np.where(ref, np.nan, targets["left"])

    def run() -> tuple[float, float]:
        opt = LayoutOptimizer(design, targets, layout, Settings(lr=LR, refresh_every=4), m)
        for _ in range(100):
            opt.step()
        final = opt.evaluate()
        return (
            metrics.pearson(final.renders["left"], outside),
            metrics.pearson(final.renders["right"], targets["right"]),
        )

    left_out, right_out = run()
    monkeypatch.setattr(optimizer_module, "design_glint_deg", lambda design: 0.0)
    counted, right_counted = run()
    assert left_out > counted + 0.05, (left_out, counted)
    assert right_out == pytest.approx(right_counted, abs=0.02)  # no glint there


def test_a_design_without_glint_keeps_every_pixel(m) -> None:
    """The demo-like small design: no pixel glints, the targets are the ones given."""
    from conftest import make_design

    design = make_design(resolution=24, size_mm=30.0)
    targets, _ = cross_of(design)
    opt = LayoutOptimizer(design, targets, make_layout(design, 40, seed=3), Settings(lr=LR), m)
    assert all(not g.mask.any() for g in opt.glint) and opt.glint_notes() == []
    for name, t in targets.items():
        np.testing.assert_array_equal(opt.target_np[name], t)
    assert check_feasibility(design).views["left"].glint_fraction == 0.0
    assert design_glint_deg(design) > 0


def test_the_note_names_the_view_and_its_share_and_prints_as_is(m, small) -> None:
    design, targets = small
    opt = LayoutOptimizer(design, targets, make_layout(design, 50, seed=1), Settings(lr=LR), m)
    (note,) = opt.glint_notes()
    share = opt.glint[0].board_share
    assert note.startswith(f"view 'left': the bare board glints on {100 * share:.1f}% of the")
    assert "left out of the image error" in note and note.endswith(".")
    whole = ViewGlint("top", np.ones((2, 2), bool), 1.0, 1.0).note()
    assert whole.startswith("view 'top': the bare board glints on all of the board")
    lines: list[str] = []
    report = progress_printer(lines.append)
    report(Progress(0, 10, math.nan, 0.0, math.nan, note))
    report(Progress(0, 10, math.nan, 0.0, math.nan, "compiling kernels"))
    assert lines == [note, "compiling kernels..."]
    assert message_text("pruning") == "pruning..."


def test_a_view_that_glints_everywhere_adds_no_error_and_no_nan(m) -> None:
    """A forced design whose camera sees the light's mirror image over the whole board:
    the view is left out whole (error 0), the other view still optimizes."""
    tables = {
        "board": {"width_mm": 12.0, "height_mm": 12.0, "roughness": 0.05, "margin_mm": 1.0},
        "light": {"position_mm": [0.0, 60.0, 300.0]},
        "scratch": {"width_mm": 0.1, "depth_mm": 0.01, "count": 60},
        "views": [
            {"name": name, "position_mm": pos, "fov_deg": "auto", "resolution": [16, 16]}
            for name, pos in [("left", [0.0, -60.0, 300.0]), ("right", [120.0, 0.0, 300.0])]
        ],
    }
    design = design_from_mapping(tables, "<all glint>", Path("."))
    targets, _ = cross_of(design)
    opt = LayoutOptimizer(design, targets, make_layout(design, 60, seed=4), Settings(lr=LR), m)
    assert opt.glint[0].mask[np.isfinite(targets["left"])].all()
    assert np.isnan(opt.target_np["left"]).all()
    assert opt.glint_notes()[0].startswith("view 'left': the bare board glints on all of")
    first = opt.step()
    for _ in range(3):
        last = opt.step()
    assert first.view_errors["left"] == 0.0 and last.view_errors["left"] == 0.0
    assert math.isfinite(last.loss) and last.view_errors["right"] < first.view_errors["right"]


def test_a_glinting_run_says_so_and_an_earlier_checkpoint_of_it_does_not_resume(
    tmp_path: Path,
) -> None:
    """The stage prints the note and records the share; a checkpoint made while the glint
    still counted (no ``image_error`` in its fingerprint) followed another objective."""
    from scratchfab.optimize.checkpoint import load_checkpoint, save_checkpoint
    from scratchfab.optimize.options import OptimizeOptions
    from scratchfab.optimize.stage import ResumeRefused, run_optimize

    design = glint_design(resolution=24)
    job = make_job(tmp_path / "job", design, count=100)
    said: list[str] = []
    run_optimize(job, OptimizeOptions(iterations=2), progress=lambda p: said.append(p.message))
    (note,) = [s for s in said if "glint" in s]
    assert note.startswith("view 'left': the bare board glints on ")
    summary = json.loads((job / "optimize" / "summary.json").read_text())
    share = check_feasibility(design).views["left"].glint_fraction
    assert list(summary["glint_left_out"]) == ["left"]
    assert summary["glint_left_out"]["left"] == pytest.approx(share, abs=0.02)
    picture = np.asarray(Image.open(job / "optimize" / "side_by_side.png").convert("RGB"))
    assert (picture == GLINT_RGB).all(axis=-1).sum() > 0, "side_by_side.png outlines the glint"
    ckpt = job / "optimize" / "checkpoint.npz"
    run_optimize(job, OptimizeOptions(iterations=3, resume=True))  # its own: resumes
    state, meta, rows = load_checkpoint(ckpt)
    limit = round(design_glint_deg(design), 6)
    assert meta["fingerprint"].pop("image_error") == {
        "glint_limit_deg": limit,
        "glint_left_out": True,
    }
    save_checkpoint(ckpt, state, meta, rows)
    with pytest.raises(ResumeRefused) as info:
        run_optimize(job, OptimizeOptions(iterations=4, resume=True))
    assert info.value.changed == ["image_error"]
    assert info.value.reasons() == (
        "made by an earlier scratchfab, whose image error counted the bare board's glint "
        "(this one leaves it out)"
    )


def test_the_cli_says_its_final_figures_count_the_glint(tmp_path: Path, capsys) -> None:
    """optimize's closing figures are over every pixel: a glinting view says so, with the
    share the summary records; a view without glint says nothing of it."""
    from scratchfab.cli import main

    job = make_job(tmp_path / "job", glint_design(resolution=24), count=100)
    main(["optimize", str(job), "--iterations", "2"])
    out = capsys.readouterr().out.splitlines()
    share = json.loads((job / "optimize" / "summary.json").read_text())["glint_left_out"]
    (left,) = [line for line in out if line.startswith("left: ")]
    assert left.endswith(
        f" (over every pixel, its glint on {100 * share['left']:.1f}% of the board too, which "
        "optimize left out)"
    )
    (right,) = [line for line in out if line.startswith("right: ")]
    assert "glint" not in right
