"""Brute-force reference renderer for tests (SPEC sections 2-4), written without the renderer.

Everything here is point sampling in numpy float64: its own pinhole camera (SPEC section 2),
its own profile root (bisection), the profile normal evaluated point by point (SPEC
section 3) and the GGX D of SPEC section 4. No closed form, no Green's theorem, no polygon
clipping, no code shared with ``scratchfab.render``.

How it estimates the footprint NDF of SPEC section 4 for every pixel of a view:

* Scratch terms ``sum_i integral over P ∩ S_i of D(h . n_i(x)) dA``. By Fubini this is a
  sum over scratches of integrals over S_i of the indicator of P. Each scratch rectangle
  is supersampled on a jittered stratified grid in its own frame (``across`` strata over
  the width, strata of ``along_step_mm`` along the length); every sample is projected into
  the view and lands in exactly one pixel footprint (the projective map is a bijection
  between the pixel square and its footprint), where it adds ``D(h_pixel . n(x)) dA`` and
  ``dA`` to |P ∩ S_i|. Sampling the scratch rather than the footprint matters: at
  roughness 0.05 a wall's highlight is a band ~0.01 mm wide, which uniform samples over a
  1 mm footprint would need ~10^6 points per pixel to resolve to 1%.
* |P ∩ B|: the pixel square is supersampled (``samples_per_pixel``, jittered stratified),
  every sample mapped to the board and weighted by the Jacobian of the image-to-board map
  (dA = C_z^2 / |q_z|^3 da db for ray direction q with f . q = 1), so the board-coverage
  fraction is a uniform-area average over the footprint. |P| is the shoelace area of the
  four corner hits (the footprint is a quadrilateral exactly).
* Flat remainder ``max(0, |P ∩ B| - sum_i |P ∩ S_i|) * D(h_z)`` with the sampled areas,
  then ``L = I F(wi . h) Dhat / (4 |light - c|^2 wo_z)``.

Other areas' tests import :func:`reference_render`; its signature is stable.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["reference_render", "reference_wbar", "ggx_d"]


def ggx_d(c: np.ndarray, alpha: float) -> np.ndarray:
    """GGX NDF of SPEC section 4 as a function of c = h . n (zero for c <= 0)."""
    a2 = alpha * alpha
    denom = 1.0 + (a2 - 1.0) * c * c
    return np.where(c > 0, a2 / (math.pi * denom * denom), 0.0)


def reference_wbar(width_mm: np.ndarray, depth_mm: np.ndarray) -> np.ndarray:
    """The profile parameter wbar of SPEC section 3 by plain bisection (float64).

    Solves -(wbar/2) ln(1 - 4 w^2 / wbar^2) = d with w = width/2; the left side falls
    monotonically from +inf at wbar = 2w to 0 as wbar grows.
    """
    w = np.asarray(width_mm, dtype=np.float64) / 2
    d = np.asarray(depth_mm, dtype=np.float64)

    def depth_of(wbar: np.ndarray) -> np.ndarray:
        return -(wbar / 2) * np.log1p(-4 * w * w / (wbar * wbar))

    lo = 2 * w * (1 + 1e-15)
    hi = 2 * w * 2.0
    while True:
        short = depth_of(hi) > d
        if not np.any(short):
            break
        hi = np.where(short, hi * 2, hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        deeper = depth_of(mid) > d
        lo = np.where(deeper, mid, lo)
        hi = np.where(deeper, hi, mid)
    return 0.5 * (lo + hi)


class _Cam:
    """A SPEC section 2 pinhole camera (independent of scratchfab.model.camera)."""

    def __init__(self, view: Any) -> None:
        self.pos = np.asarray(view.position_mm, dtype=np.float64)
        f = np.asarray(view.look_at_mm, dtype=np.float64) - self.pos
        self.f = f / np.linalg.norm(f)
        r = np.cross(self.f, np.asarray(view.up, dtype=np.float64))
        self.r = r / np.linalg.norm(r)
        self.u = np.cross(self.r, self.f)
        self.W, self.H = int(view.resolution[0]), int(view.resolution[1])
        self.ty = math.tan(math.radians(float(view.fov_deg)) / 2)
        self.tx = self.ty * self.W / self.H

    def ray(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        a = (2 * s / self.W - 1) * self.tx
        b = (1 - 2 * t / self.H) * self.ty
        return self.f + a[..., None] * self.r + b[..., None] * self.u

    def hit(self, s: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Board points (..., 2), ray z components and validity of rays through (s, t)."""
        q = self.ray(s, t)
        qz = q[..., 2]
        ok = qz < 0
        lam = -self.pos[2] / np.where(ok, qz, -1.0)
        return self.pos[:2] + lam[..., None] * q[..., :2], qz, ok

    def to_image(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rel = np.concatenate([xy, np.zeros(xy.shape[:-1] + (1,))], axis=-1) - self.pos
        depth = rel @ self.f
        front = depth > 0
        depth = np.where(front, depth, 1.0)
        s = ((rel @ self.r) / depth / self.tx + 1) * self.W / 2
        t = (1 - (rel @ self.u) / depth / self.ty) * self.H / 2
        return s, t, front


def _stratified(n: int, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` sets of n x n jittered stratified points in the unit square: (count, n*n) each."""
    g = (np.arange(n) + 0.0)[None, :]
    u = (g[:, :, None] + rng.random((count, n, n))) / n
    v = (g[:, None, :] + rng.random((count, n, n))) / n
    return u.reshape(count, -1), v.reshape(count, -1)


def _view_reference(
    design: Any,
    view: Any,
    p0: np.ndarray,
    p1: np.ndarray,
    width: np.ndarray,
    wbar: np.ndarray,
    n_pix: int,
    across: int,
    along_step_mm: float,
    rng: np.random.Generator,
) -> np.ndarray:
    cam = _Cam(view)
    W, H = cam.W, cam.H
    alpha = float(design.board.roughness)
    light = np.asarray(
        view.light_position_mm if view.light_position_mm is not None else design.light.position_mm,
        dtype=np.float64,
    )
    hw, hh = design.board.width_mm / 2, design.board.height_mm / 2

    jj, ii = np.meshgrid(
        np.arange(H, dtype=np.float64), np.arange(W, dtype=np.float64), indexing="ij"
    )
    ii, jj = ii.ravel(), jj.ravel()
    npx = W * H

    # |P|: shoelace of the four corner hits; validity: all four corner rays hit z = 0.
    cs = np.stack([ii, ii, ii + 1, ii + 1], axis=1)
    ct = np.stack([jj, jj + 1, jj + 1, jj], axis=1)
    corners, _, cok = cam.hit(cs, ct)
    valid = np.all(cok, axis=1)
    x, y = corners[..., 0], corners[..., 1]
    area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))

    # |P ∩ B| = |P| * (Jacobian-weighted fraction of stratified samples on the board).
    onboard = np.zeros(npx)
    chunk = max(1, 2_000_000 // (n_pix * n_pix))
    for start in range(0, npx, chunk):
        sl = slice(start, min(npx, start + chunk))
        u, v = _stratified(n_pix, rng, sl.stop - sl.start)
        pts, qz, ok = cam.hit(ii[sl, None] + u, jj[sl, None] + v)
        jac = np.where(ok, 1.0 / np.abs(np.where(ok, qz, -1.0)) ** 3, 0.0)
        inside = (np.abs(pts[..., 0]) <= hw) & (np.abs(pts[..., 1]) <= hh) & ok
        frac = np.sum(jac * inside, axis=1) / np.maximum(np.sum(jac, axis=1), 1e-300)
        onboard[sl] = frac * area[sl]

    # Per-pixel centre point, directions, half-vector, radiometry.
    c, _, _ = cam.hit(ii + 0.5, jj + 0.5)
    c3 = np.concatenate([c, np.zeros((npx, 1))], axis=1)
    to_light = light - c3
    dist2 = np.sum(to_light * to_light, axis=1)
    wi = to_light / np.sqrt(dist2)[:, None]
    wo = cam.pos - c3
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    h = wi + wo
    h /= np.linalg.norm(h, axis=1)[:, None]

    # Scratch supersampling, binned into pixels by projection.
    ndf = np.zeros(npx)
    covered = np.zeros(npx)
    d = p1 - p0
    length = np.linalg.norm(d, axis=1)
    along_dir = d / length[:, None]
    across_dir = np.stack([-along_dir[:, 1], along_dir[:, 0]], axis=1)
    for k in range(len(p0)):
        n_along = max(1, int(math.ceil(length[k] / along_step_mm)))
        w = width[k] / 2
        gx = (np.arange(across)[:, None] + rng.random((across, n_along))) / across
        gy = (np.arange(n_along)[None, :] + rng.random((across, n_along))) / n_along
        xl = (2 * gx - 1).ravel() * w
        yl = gy.ravel() * length[k]
        pts = p0[k] + yl[:, None] * along_dir[k] + xl[:, None] * across_dir[k]
        s, t, front = cam.to_image(pts)
        i = np.floor(s).astype(np.int64)
        j = np.floor(t).astype(np.int64)
        keep = front & (i >= 0) & (i < W) & (j >= 0) & (j < H)
        pix = (j * W + i)[keep]
        keep_pix = valid[pix]
        pix = pix[keep_pix]
        xl = xl[keep][keep_pix]
        wb = wbar[k]
        den = wb * wb + 4 * xl * xl
        n_across = -4 * wb * xl / den
        n_z = (wb * wb - 4 * xl * xl) / den
        hp = h[pix]
        cosine = (hp[:, 0] * across_dir[k, 0] + hp[:, 1] * across_dir[k, 1]) * n_across + hp[
            :, 2
        ] * n_z
        dA = 2 * w * length[k] / (across * n_along)
        ndf += np.bincount(pix, weights=ggx_d(cosine, alpha) * dA, minlength=npx)
        covered += np.bincount(pix, minlength=npx) * dA

    flat = np.maximum(0.0, onboard - covered) * ggx_d(h[:, 2], alpha)
    safe_area = np.where(valid & (area > 0), area, 1.0)
    dhat = np.where(valid & (area > 0), (ndf + flat) / safe_area, 0.0)
    f0 = float(design.board.f0)
    cos_ih = np.sum(wi * h, axis=1)
    fresnel = f0 + (1 - f0) * (1 - cos_ih) ** 5
    radiance = design.light.intensity * fresnel * dhat / (4 * dist2 * wo[:, 2])
    return radiance.reshape(H, W)


def reference_render(
    design: Any,
    scratches: Any,
    samples_per_pixel: int = 1024,
    seed: int = 0,
    across: int = 96,
    along_step_mm: float = 0.02,
) -> dict[str, np.ndarray]:
    """Brute-force render of every view of ``design`` (see the module docstring).

    Args:
        design: A resolved :class:`scratchfab.model.design.Design`.
        scratches: A :class:`scratchfab.model.scratches.ScratchSet` (mm).
        samples_per_pixel: Stratified samples per pixel square for |P ∩ B| (rounded
            down to a square number).
        seed: Seed of the jitter (the result is deterministic given it).
        across: Strata across each scratch's width.
        along_step_mm: Stratum length along each scratch.

    Returns:
        ``{view name: (H, W) float64 linear radiance}``, row-major like the renderer.
    """
    rng = np.random.default_rng(seed)
    n_pix = max(1, int(math.isqrt(int(samples_per_pixel))))
    p0 = np.asarray(scratches.p0, dtype=np.float64).reshape(-1, 2)
    p1 = np.asarray(scratches.p1, dtype=np.float64).reshape(-1, 2)
    width = np.asarray(scratches.width, dtype=np.float64).reshape(-1)
    depth = np.asarray(scratches.depth, dtype=np.float64).reshape(-1)
    wbar = reference_wbar(width, depth) if len(width) else width
    return {
        view.name: _view_reference(
            design, view, p0, p1, width, wbar, n_pix, across, along_step_mm, rng
        )
        for view in design.views
    }
