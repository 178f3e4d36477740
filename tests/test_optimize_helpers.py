"""A small two-target test board and job folder for the optimize tests (no design stage)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from scratchfab.model.camera import Camera
from scratchfab.model.design import Design, View
from scratchfab.model.scratches import ScratchSet

__all__ = ["board_functions", "warp", "make_layout", "make_job", "cross_of"]


def board_functions(size_mm: float) -> dict[str, object]:
    """Two painted-board images as functions of board (x, y): a disc and two bars."""

    def disc(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return ((x**2 + y**2) < (0.3 * size_mm) ** 2) * 0.9 + 0.05

    def bars(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return (np.abs(np.abs(x) - 0.22 * size_mm) < 0.09 * size_mm) * 0.9 + 0.05

    return {"left": disc, "right": bars}


def warp(design: Design, f: object, view: View, n: int = 4) -> np.ndarray:
    """Pixel averages (n x n samples) of a board function seen by ``view``; NaN off board."""
    cam = Camera.from_view(view)
    H, W = view.height, view.width
    o = (np.arange(n) + 0.5) / n
    t = (np.arange(H)[:, None, None, None] + o[None, None, :, None]) * np.ones((1, W, n, n))
    s = (np.arange(W)[None, :, None, None] + o[None, None, None, :]) * np.ones((H, 1, n, 1))
    pts, ok = cam.board_hits(s, t)
    hw, hh = design.board.half_extent
    on = ok & (np.abs(pts[..., 0]) <= hw) & (np.abs(pts[..., 1]) <= hh)
    v = np.where(on, f(pts[..., 0], pts[..., 1]), 0.0).mean(axis=(2, 3))  # type: ignore[operator]
    c, okc = cam.center_grid()
    onc = okc & (np.abs(c[..., 0]) <= hw) & (np.abs(c[..., 1]) <= hh)
    return np.where(onc, v, np.nan)


def cross_of(design: Design) -> tuple[dict[str, np.ndarray], dict[tuple[str, str], np.ndarray]]:
    """(targets T_k, cross targets T_j->k keyed (k, j)) of the test board."""
    funcs = board_functions(design.board.width_mm)
    targets = {v.name: warp(design, funcs[v.name], v) for v in design.views}
    cross = {
        (k.name, j.name): warp(design, funcs[j.name], k) for k in design.views for j in design.views
    }
    return targets, cross


def make_layout(design: Design, count: int, seed: int) -> ScratchSet:
    """Uniformly placed scratches, alternately turned to reflect into each view."""
    rng = np.random.default_rng(seed)
    hw = design.board.half_extent[0] - design.board.margin_mm - 3.0
    c = rng.uniform(-hw, hw, (count, 2))
    length = rng.uniform(2.0, 5.0, count)
    theta = np.empty(count)
    for k, v in enumerate(design.views):
        sel = np.arange(count) % len(design.views) == k
        p = np.concatenate([c[sel], np.zeros((int(sel.sum()), 1))], 1)
        wi = design.light_for(v) - p
        wi /= np.linalg.norm(wi, axis=1)[:, None]
        wo = v.camera_position - p
        wo /= np.linalg.norm(wo, axis=1)[:, None]
        h = wi + wo
        theta[sel] = np.arctan2(h[:, 1], h[:, 0]) + np.pi / 2
    u = np.stack([np.cos(theta), np.sin(theta)], 1) * length[:, None] / 2
    return ScratchSet.from_arrays(c - u, c + u, design.scratch.width_mm, design.scratch.depth_mm)


def _srgb(v: np.ndarray) -> np.ndarray:
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.clip(v, 0, None) ** (1 / 2.4) - 0.055)


def make_job(root: Path, design: Design, count: int = 300, seed: int = 3) -> Path:
    """A job folder as the design stage leaves it: design.toml, targets, scratches.csv."""
    folder = root / "design"
    (folder / "targets").mkdir(parents=True)
    funcs = board_functions(design.board.width_mm)
    views = []
    size = 256
    hw, hh = design.board.half_extent
    xs = (np.arange(size) + 0.5) / size * 2 * hw - hw
    ys = hh - (np.arange(size) + 0.5) / size * 2 * hh
    for v in design.views:
        img = funcs[v.name](xs[None, :], ys[:, None])  # type: ignore[operator]
        png = folder / "targets" / f"{v.name}_board.png"
        Image.fromarray(np.round(_srgb(img) * 65535).astype(np.uint16)).save(png)
        views.append(type(v)(**{**v.__dict__, "target": str(png)}))
    design = design.with_views(tuple(views))
    design.save(folder / "design.toml")
    targets, _ = cross_of(design)
    for name, t in targets.items():
        np.save(folder / "targets" / f"{name}.npy", t.astype(np.float32))
    make_layout(design, count, seed).save(folder / "scratches.csv", design.scratch)
    return root


def stopped_at_three_of_four(job: Path) -> None:
    """Optimize ``job`` 2 steps (the CLI), then extend it to 4 and stop it after step 3."""
    from scratchfab.cli import main
    from scratchfab.optimize.options import OptimizeOptions
    from scratchfab.optimize.stage import run_optimize

    main(["optimize", str(job), "--iterations", "2"])
    steps: list[int] = []
    run_optimize(
        job,
        OptimizeOptions(iterations=4, resume=True),
        progress=lambda p: steps.append(p.iteration) if not p.message else None,
        should_stop=lambda: True,
    )
    assert steps == [3]
