"""The ``scratch_board`` Mitsuba BSDF: GGX over SPEC's scratch profile, point by point.

It checks the renderer's closed forms (footprint clipping, Green's theorem, pair
finding, camera) by another route, not SPEC's model itself: like SPEC section 4 it
weights the profile normals by board area, not by the tilted walls' own area (1/n_z
more), which makes lit walls a few per cent brighter on a real board.

Each shading point p on the board looks up its grid cell (:mod:`.index`) and tests the
listed scratches exactly: p is covered by scratch i when |x_i| <= w_i and
0 <= y_i <= L_i in the scratch's frame (SPEC section 3). There the surface normal is the
profile normal n_i(x_i) (the supplement's eqs. 2 and 6); elsewhere it is the flat +z.

Pointwise NDF. SPEC section 4 sums overlapping scratches "as if each were alone" and
gives the flat board what area is left, ``max(0, |P n B| - sum_i |P n S_i|)``. The
point density

    D_p(h) = sum_{i covers p} D(h . n_i(p)) + (1 - k(p)) D(h_z),

k(p) the number of covering scratches, integrates over a footprint P to exactly that sum
without the clamp at zero; the clamp is a rule about the whole footprint that no
pointwise density can express. The plugin therefore offers its two parts separately,
``lobes = "scratches"`` (the sum) and ``lobes = "flat"`` (the signed flat remainder,
negative where scratches overlap), and verification renders both and clamps the flat
image per pixel (:class:`scratchfab.verify.verify.BoardRenderer`), which is SPEC
section 4 exactly in expectation. ``lobes = "all"`` with ``flat_weight = "clamped"``
(``max(0, 1 - k(p))``) is a non-negative, physically plausible board for renders under
other light (``--sky``, sweeps); ``flat_weight = "signed"`` is the plain sum above.

Radiometry. With Mitsuba's ``wi`` toward the camera and ``wo`` toward the light,
``eval`` returns the cosine-weighted BRDF F(wo . h) D_p(h) / (4 wi_z) (Cook-Torrance with
G = 1: f = F D / (4 cos_i cos_o) times cos toward the light), so a point light of
intensity I at distance r gives the radiance I F D_p / (4 r^2 wo_z) of SPEC section 4.

Sampling picks one lobe uniformly among the flat normal and the covering scratches'
normals (one reservoir pass), samples the GGX normal distribution about it and
reflects; the pdf is the mixture over all k + 1 lobes, so environment light works.

Import this module only after :func:`scratchfab.backend.ensure_llvm_path` (done by
:func:`use_variant`).
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from scratchfab.verify.dent import solve_wbar
from scratchfab.verify.index import build_grid

PLUGIN_NAME = "scratch_board"
FLAT_WEIGHTS = ("signed", "clamped")
LOBES = ("all", "scratches", "flat")

_registered: set[str] = set()


def ggx(cos: Any, alpha: float) -> Any:
    """GGX NDF D(c) = alpha^2 / (pi (1 + (alpha^2 - 1) c^2)^2) for c > 0, else 0 (SPEC 4)."""
    a2 = alpha * alpha
    t = 1.0 + (a2 - 1.0) * cos * cos
    return dr.select(cos > 0, a2 / (dr.pi * t * t), 0.0)


def schlick(cos: Any, f0: float) -> Any:
    """Schlick's Fresnel F = f0 + (1 - f0) (1 - c)^5."""
    m = dr.clip(1.0 - cos, 0.0, 1.0)
    m2 = m * m
    return f0 + (1.0 - f0) * m2 * m2 * m


class ScratchKernel:
    """The plugin's state and Dr.Jit kernels (the plugin class wraps one per instance)."""

    def __init__(self, props: Any) -> None:
        self.alpha = float(props.get("alpha", 0.05))
        self.f0 = float(props.get("f0", 0.91))
        mode = str(props.get("flat_weight", "signed"))
        if mode not in FLAT_WEIGHTS:
            raise ValueError(f"scratch_board: flat_weight must be one of {FLAT_WEIGHTS}")
        self.signed = mode == "signed"
        lobes = str(props.get("lobes", "all"))
        if lobes not in LOBES:
            raise ValueError(f"scratch_board: lobes must be one of {LOBES}")
        self.scratch_weight = 0.0 if lobes == "flat" else 1.0
        self.flat_on = lobes != "scratches"
        extent = (0.5 * float(props["board_width"]), 0.5 * float(props["board_height"]))
        if "p0" in props:
            p0 = np.array(props["p0"], dtype=np.float64).reshape(-1, 2)
            p1 = np.array(props["p1"], dtype=np.float64).reshape(-1, 2)
            width = np.array(props["width"], dtype=np.float64).reshape(-1)
            depth = np.array(props["depth"], dtype=np.float64).reshape(-1)
        else:
            p0 = p1 = np.zeros((0, 2))
            width = depth = np.zeros(0)
        cell = float(props["cell_mm"]) if "cell_mm" in props else None
        half = 0.5 * width
        grid = build_grid(p0, p1, half, extent, cell)
        seg = p1 - p0
        length = np.linalg.norm(seg, axis=1)
        unit = seg / np.maximum(length, 1e-300)[:, None]
        wbar = solve_wbar(width, depth) if len(width) else np.zeros(0)
        # One unused trailing entry keeps every gather source non-empty.
        table = np.zeros((len(p0) + 1, 7))
        table[:-1] = np.column_stack([p0, unit, length, half, wbar])
        self.count = len(p0)
        self.grid = grid
        self.max_count = max(grid.max_count, 1)
        self.origin = grid.origin
        self.inv_cell = 1.0 / grid.cell
        self.nx, self.ny = grid.nx, grid.ny
        self.starts = mi.UInt32(grid.starts)
        self.items = mi.UInt32(np.append(grid.items, 0).astype(np.uint32))
        cols = table.T.astype(np.float32)
        self.ox, self.oy, self.ux, self.uy, self.length, self.half, self.wbar = (
            mi.Float(c) for c in cols
        )

    def _cell(self, x: Any, y: Any) -> Any:
        ix = dr.clip(mi.Int32(dr.floor((x - self.origin[0]) * self.inv_cell)), 0, self.nx - 1)
        iy = dr.clip(mi.Int32(dr.floor((y - self.origin[1]) * self.inv_cell)), 0, self.ny - 1)
        return mi.UInt32(iy * self.nx + ix)

    def _scratch(self, s: Any, x: Any, y: Any) -> tuple[Any, Any, Any, Any, Any]:
        """Across coordinate, coverage, across axis (ex, ey) and wbar of scratch ``s`` at (x, y)."""
        ox = dr.gather(mi.Float, self.ox, s)
        oy = dr.gather(mi.Float, self.oy, s)
        ux = dr.gather(mi.Float, self.ux, s)
        uy = dr.gather(mi.Float, self.uy, s)
        length = dr.gather(mi.Float, self.length, s)
        half = dr.gather(mi.Float, self.half, s)
        wbar = dr.gather(mi.Float, self.wbar, s)
        dx = x - ox
        dy = y - oy
        along = dx * ux + dy * uy
        # Across axis e = (-uy, ux); the profile is symmetric, so its sign is immaterial.
        across = dy * ux - dx * uy
        inside = (dr.abs(across) <= half) & (along >= 0) & (along <= length)
        return across, inside, -uy, ux, wbar

    @staticmethod
    def _normal(across: Any, ex: Any, ey: Any, wbar: Any) -> Any:
        """Profile normal n(x) = (-4 wbar x e + (wbar^2 - 4x^2) z) / (wbar^2 + 4x^2) (SPEC 3)."""
        x2 = 4.0 * across * across
        inv = dr.rcp(wbar * wbar + x2)
        tilt = -4.0 * wbar * across * inv
        return mi.Vector3f(tilt * ex, tilt * ey, (wbar * wbar - x2) * inv)

    @dr.syntax
    def _scan(self, x: Any, y: Any, h: Any, active: Any) -> tuple[Any, Any, Any]:
        """Over the scratches covering (x, y): sum D(h.n_i), sum D(h.n_i)(h.n_i), count."""
        cell = self._cell(x, y)
        i = dr.gather(mi.UInt32, self.starts, cell, active)
        end = dr.gather(mi.UInt32, self.starts, cell + 1, active)
        sum_d = mi.Float(0.0)
        sum_dc = mi.Float(0.0)
        count = mi.Float(0.0)
        while dr.hint(i < end, max_iterations=self.max_count, label="scratch_board_eval"):
            s = dr.gather(mi.UInt32, self.items, i)
            across, inside, ex, ey, wbar = self._scratch(s, x, y)
            c = dr.dot(h, self._normal(across, ex, ey, wbar))
            d = ggx(c, self.alpha)
            sum_d += dr.select(inside, d, 0.0)
            sum_dc += dr.select(inside, d * c, 0.0)
            count += dr.select(inside, 1.0, 0.0)
            i += 1
        return sum_d, sum_dc, count

    @dr.syntax
    def _pick(self, x: Any, y: Any, u: Any, active: Any) -> tuple[Any, Any]:
        """One lobe normal, uniform among the flat one and the covering scratches' (reservoir)."""
        cell = self._cell(x, y)
        i = dr.gather(mi.UInt32, self.starts, cell, active)
        end = dr.gather(mi.UInt32, self.starts, cell + 1, active)
        normal = mi.Vector3f(0.0, 0.0, 1.0)
        seen = mi.Float(1.0)
        while dr.hint(i < end, max_iterations=self.max_count, label="scratch_board_pick"):
            s = dr.gather(mi.UInt32, self.items, i)
            across, inside, ex, ey, wbar = self._scratch(s, x, y)
            seen += dr.select(inside, 1.0, 0.0)
            take = inside & (u * seen < 1.0)
            normal = dr.select(take, self._normal(across, ex, ey, wbar), normal)
            # Rescale u so that it stays uniform for the next candidate.
            u = dr.select(
                inside,
                dr.select(take, u * seen, (u * seen - 1.0) * dr.rcp(dr.maximum(seen - 1.0, 1.0))),
                u,
            )
            i += 1
        return normal, seen

    def _eval_pdf(self, si: Any, wo_local: Any, active: Any) -> tuple[Any, Any]:
        """Cosine-weighted BSDF value and sampling pdf (solid angle) toward ``wo_local``."""
        cos_cam = si.wi.z
        cos_light = wo_local.z
        active = active & (cos_cam > 0) & (cos_light > 0)
        wi = si.to_world(si.wi)
        wo = si.to_world(wo_local)
        h = dr.normalize(wi + wo)
        sum_d, sum_dc, count = self._scan(si.p.x, si.p.y, h, active)
        d_flat = ggx(h.z, self.alpha)
        flat = 1.0 - count if self.signed else dr.maximum(1.0 - count, 0.0)
        if not self.flat_on:
            flat = mi.Float(0.0)
        cos_h = dr.dot(wi, h)
        ndf = self.scratch_weight * sum_d + flat * d_flat
        value = schlick(cos_h, self.f0) * ndf / (4.0 * cos_cam)
        pdf = (sum_dc + d_flat * h.z) / ((count + 1.0) * 4.0 * dr.maximum(cos_h, 1e-12))
        return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    def _sample(self, si: Any, sample1: Any, sample2: Any, active: Any) -> tuple[Any, Any]:
        active = active & (si.wi.z > 0)
        normal, _ = self._pick(si.p.x, si.p.y, sample1, active)
        a2 = self.alpha * self.alpha
        tan2 = a2 * sample2.x / dr.maximum(1.0 - sample2.x, 1e-12)
        cos_t = dr.rsqrt(1.0 + tan2)
        sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
        sin_p, cos_p = dr.sincos(2.0 * dr.pi * sample2.y)
        h = mi.Frame3f(normal).to_world(mi.Vector3f(sin_t * cos_p, sin_t * sin_p, cos_t))
        wi = si.to_world(si.wi)
        cos_h = dr.dot(wi, h)
        wo_local = si.to_local(2.0 * cos_h * h - wi)
        active = active & (cos_h > 0) & (wo_local.z > 0)
        value, pdf = self._eval_pdf(si, wo_local, active)
        active = active & (pdf > 0)
        bs: Any = dr.zeros(mi.BSDFSample3f)
        bs.wo = wo_local
        bs.pdf = dr.select(active, pdf, 0.0)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
        bs.sampled_component = mi.UInt32(0)
        weight = dr.select(active, value * dr.rcp(dr.maximum(pdf, 1e-30)), 0.0)
        return bs, weight


def _plugin_class() -> type:
    """The plugin class for the current variant (``mi.BSDF`` differs per variant)."""

    class ScratchBoard(mi.BSDF):  # type: ignore[misc,name-defined]
        """GGX microfacet board with scratch profiles (see the module docstring)."""

        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            self.kernel = ScratchKernel(props)
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [flags]
            self.m_flags = flags

        def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            """Cosine-weighted BSDF toward ``wo``."""
            return mi.Spectrum(self.kernel._eval_pdf(si, wo, mi.Bool(active))[0])

        def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            """Solid-angle pdf of :meth:`sample` producing ``wo``."""
            return self.kernel._eval_pdf(si, wo, mi.Bool(active))[1]

        def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            """Both of the above in one pass over the covering scratches."""
            value, pdf = self.kernel._eval_pdf(si, wo, mi.Bool(active))
            return mi.Spectrum(value), pdf

        def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> Any:
            """Sample a reflected direction; returns (BSDFSample3f, value / pdf)."""
            bs, weight = self.kernel._sample(si, sample1, sample2, mi.Bool(active))
            return bs, mi.Spectrum(weight)

        def traverse(self, callback: Any) -> None:
            """No differentiable parameters."""

        def to_string(self) -> str:
            """Short description."""
            k = self.kernel
            return f"ScratchBoard[{k.count} scratches, alpha={k.alpha}, f0={k.f0}]"

    return ScratchBoard


def register() -> None:
    """Register ``scratch_board`` with Mitsuba for the current variant (once per variant)."""
    variant = str(mi.variant())
    if variant in _registered:
        return
    cls = _plugin_class()
    mi.register_bsdf(PLUGIN_NAME, lambda props: cls(props))
    _registered.add(variant)
