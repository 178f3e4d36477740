"""The analytic renderer: image formation of SPEC section 4 in Dr.Jit.

Per view, :class:`ViewRenderer` precomputes in numpy float64 everything that depends only
on the camera and light: each pixel's footprint quadrilateral P (the four corner rays on
z = 0), its area |P| and on-board area |P ∩ B| (exact polygon clip), the centre point c,
the half-vector h, the radiometric factor ``I F(wi . h) / (4 |light - c|^2 wo_z) / |P|``
and the flat-board NDF D(h_z). :meth:`ViewRenderer.render` then evaluates the closed-form
footprint NDF for every (pixel, scratch) pair, sums the pairs per pixel with a
scatter-add and adds the flat remainder ``max(0, |P ∩ B| - sum_i |P ∩ S_i|) D(h_z)``.
It is differentiable with respect to the scratch endpoints (and widths via ``wbar``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from types import ModuleType
from typing import Any

import drjit as dr
import numpy as np
import shapely

from scratchfab.backend import BackendName, array_module, jit_array
from scratchfab.model.camera import Camera, polygon_area
from scratchfab.model.design import Design, View
from scratchfab.model.scratches import ScratchSet
from scratchfab.render.ndf import scratch_footprint_ndf
from scratchfab.render.pairs import Pairs, raster_pairs, scratch_rectangles
from scratchfab.render.profile import solve_wbar

__all__ = ["ViewRenderer", "render_pairs", "render_scratches", "onboard_area", "ggx_d"]


def ggx_d(c: np.ndarray, alpha: float) -> np.ndarray:
    """GGX NDF D(c) of SPEC section 4 for c = h . n (zero where c <= 0)."""
    a2 = alpha * alpha
    q = 1.0 + (a2 - 1.0) * c * c
    return np.where(c > 0, a2 / (math.pi * q * q), 0.0)


def onboard_area(quads: np.ndarray, half_w: float, half_h: float) -> np.ndarray:
    """Exact area of each convex quad (..., 4, 2) inside the board |x| <= half_w, |y| <= half_h."""
    flat = quads.reshape(-1, 4, 2)
    area = np.abs(polygon_area(flat))
    x, y = flat[..., 0], flat[..., 1]
    inside = np.all((np.abs(x) <= half_w) & (np.abs(y) <= half_h), axis=1)
    outside = (
        np.all(x >= half_w, axis=1)
        | np.all(x <= -half_w, axis=1)
        | np.all(y >= half_h, axis=1)
        | np.all(y <= -half_h, axis=1)
    )
    result = np.where(inside, area, 0.0)
    cut = np.flatnonzero(~inside & ~outside & np.all(np.isfinite(flat), axis=(1, 2)))
    if len(cut):
        polys = shapely.polygons(flat[cut])
        board = shapely.box(-half_w, -half_h, half_w, half_h)
        result[cut] = shapely.area(shapely.intersection(polys, board))
    return result.reshape(quads.shape[:-2])


class ViewRenderer:
    """Renders one view of a design for any scratch layout (SPEC section 4).

    Args:
        design: The resolved design.
        view: One of its views.
        m: The Dr.Jit array namespace (:func:`scratchfab.backend.array_module`).

    Attributes:
        width: W in pixels.
        height: H in pixels.
        camera: The view's :class:`Camera`.
        quads: (H, W, 4, 2) footprint corners on the board (mm).
        valid: (H, W) bool, pixels whose footprint lies on the board plane and has area.
        area: (H, W) |P| in mm^2.
        area_on_board: (H, W) |P ∩ B| in mm^2.
        center: (H, W, 2) centre points c.
        half_vector: (H, W, 3) unit h.
        factor: (H, W) ``I F(wi . h) / (4 |light - c|^2 wo_z) / |P|`` (0 where invalid).
        d_flat: (H, W) D(h_z).
    """

    def __init__(self, design: Design, view: View, m: ModuleType) -> None:
        self.design = design
        self.view = view
        self.m = m
        # float64 throughout: the closed form needs it (scratchfab.render.ndf, "Precision").
        self.Float = m.Float64
        self.alpha = float(design.board.roughness)
        cam = Camera.from_view(view)
        self.camera = cam
        self.width, self.height = cam.width, cam.height
        hw, hh = design.board.half_extent

        quads, quad_ok = cam.footprints()
        centers, center_ok = cam.center_grid()
        finite = np.all(np.isfinite(quads), axis=(2, 3))
        quads = np.where((quad_ok & finite)[..., None, None], quads, 0.0)
        area = np.abs(polygon_area(quads))
        valid = quad_ok & center_ok & finite & (area > 0)
        on_board = np.where(valid, onboard_area(quads, hw, hh), 0.0)

        light = design.light_for(view)
        c3 = np.concatenate([centers, np.zeros(centers.shape[:-1] + (1,))], axis=-1)
        to_light = light - c3
        dist2 = np.sum(to_light**2, axis=-1)
        wi = to_light / np.sqrt(dist2)[..., None]
        wo = cam.position - c3
        wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        f0 = design.board.f0
        fresnel = f0 + (1 - f0) * (1 - np.sum(wi * h, axis=-1)) ** 5
        safe = np.where(valid, area * wo[..., 2], 1.0)
        factor = np.where(valid, design.light.intensity * fresnel / (4 * dist2 * safe), 0.0)

        self.quads = quads
        self.valid = valid
        self.area = area
        self.area_on_board = on_board
        self.center = centers
        self.half_vector = h
        self.factor = factor
        self.d_flat = ggx_d(h[..., 2], self.alpha)
        self.pixel_ok = (valid & (on_board > 0)).ravel()

        F = self.Float
        flat_quads = quads.reshape(-1, 4, 2)
        self._qx = [jit_array(F, flat_quads[:, k, 0]) for k in range(4)]
        self._qy = [jit_array(F, flat_quads[:, k, 1]) for k in range(4)]
        flat_h = h.reshape(-1, 3)
        self._h = [jit_array(F, flat_h[:, k]) for k in range(3)]
        self._factor = jit_array(F, factor)
        self._d_flat = jit_array(F, self.d_flat)
        self._on_board = jit_array(F, on_board)

    @property
    def pixel_count(self) -> int:
        """H * W."""
        return self.width * self.height

    def find_pairs(
        self,
        p0: np.ndarray,
        p1: np.ndarray,
        half_width: np.ndarray | float,
        margin_mm: float = 0.0,
    ) -> Pairs:
        """Every (pixel, scratch) pair whose footprint may touch a scratch grown by a margin.

        Args:
            p0: (N, 2) start points (mm).
            p1: (N, 2) end points (mm).
            half_width: (N,) or scalar half widths w (mm).
            margin_mm: Growth of each scratch rectangle on every side, so the pairs stay
                complete while the optimizer moves endpoints by up to this much.
        """
        corners = scratch_rectangles(p0, p1, half_width, margin_mm)
        pixel, scratch = raster_pairs(self.camera, corners, self.pixel_ok)
        pixel_np = np.asarray(pixel, dtype=np.uint32)
        scratch_np = np.asarray(scratch, dtype=np.uint32)
        pixel_np.flags.writeable = False
        scratch_np.flags.writeable = False
        return Pairs(
            jit_array(self.m.UInt32, pixel_np, np.uint32),
            jit_array(self.m.UInt32, scratch_np, np.uint32),
            pixel_np,
            scratch_np,
        )

    @property
    def state(self) -> dict[str, Any]:
        """The view's Dr.Jit arrays as a PyTree, for :func:`render_pairs`.

        Pass this (not the renderer) into a ``@dr.freeze`` function: a frozen function
        must receive every Dr.Jit array it reads as an argument.
        """
        return {
            "qx": self._qx,
            "qy": self._qy,
            "h": self._h,
            "factor": self._factor,
            "on_board": self._on_board,
            "d_flat": self._d_flat,
        }

    def render(
        self,
        p0x: Any,
        p0y: Any,
        p1x: Any,
        p1y: Any,
        half_width: Any,
        wbar: Any,
        pairs: Pairs,
    ) -> Any:
        """Linear radiance of every pixel, (H * W,) row-major, differentiable.

        Args:
            p0x: Scratch start x (Dr.Jit Float64, N; all scratch arrays are Float64).
            p0y: Scratch start y.
            p1x: Scratch end x.
            p1y: Scratch end y.
            half_width: Half widths w.
            wbar: Profile parameters (SPEC section 3).
            pairs: From :meth:`find_pairs` with the same scratch indexing.

        Returns:
            Dr.Jit Float64 of size H * W (not evaluated; the caller decides when).
        """
        if len(pairs) == 0:
            return self._factor * self._on_board * self._d_flat
        return render_pairs(
            self.state,
            self.alpha,
            self.pixel_count,
            p0x,
            p0y,
            p1x,
            p1y,
            half_width,
            wbar,
            pairs.pixel,
            pairs.scratch,
        )

    def scratch_arrays(self, scratches: ScratchSet) -> tuple[Any, Any, Any, Any, Any, Any]:
        """(p0x, p0y, p1x, p1y, half_width, wbar) of a scratch set as Dr.Jit arrays."""
        F = self.Float
        wbar = solve_wbar(scratches.width, scratches.depth)
        return (
            jit_array(F, scratches.p0[:, 0]),
            jit_array(F, scratches.p0[:, 1]),
            jit_array(F, scratches.p1[:, 0]),
            jit_array(F, scratches.p1[:, 1]),
            jit_array(F, scratches.width / 2),
            jit_array(F, wbar),
        )


def pair_footprints(
    state: dict[str, Any],
    alpha: float,
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    wbar: Any,
    pixel: Any,
    scratch: Any,
) -> tuple[Any, Any]:
    """Each (pixel, scratch) pair's footprint NDF integral and covered area, not yet summed.

    Arguments as for :func:`render_pairs`; the closed form of
    :func:`scratch_footprint_ndf` on the pair's pixel footprint and scratch.
    """
    F = type(state["factor"])
    hx, hy, hz = (dr.gather(F, c, pixel) for c in state["h"])
    return scratch_footprint_ndf(
        [dr.gather(F, q, pixel) for q in state["qx"]],
        [dr.gather(F, q, pixel) for q in state["qy"]],
        dr.gather(F, p0x, scratch),
        dr.gather(F, p0y, scratch),
        dr.gather(F, p1x, scratch),
        dr.gather(F, p1y, scratch),
        dr.gather(F, half_width, scratch),
        dr.gather(F, wbar, scratch),
        hx,
        hy,
        hz,
        alpha,
    )


def render_pairs(
    state: dict[str, Any],
    alpha: float,
    pixel_count: int,
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    wbar: Any,
    pixel: Any,
    scratch: Any,
) -> Any:
    """Image formation of SPEC section 4 for one view: the body of :meth:`ViewRenderer.render`.

    A pure function of Dr.Jit arrays (``state`` from :attr:`ViewRenderer.state`, the
    scratch arrays and the pair indices), so it can run inside ``@dr.freeze``. Every pair
    adds its closed-form footprint NDF and covered area to its pixel by scatter-add; the
    flat board fills the rest, ``max(0, |P ∩ B| - sum_i |P ∩ S_i|) D(h_z)``.

    Returns:
        Dr.Jit Float64 (pixel_count,) linear radiance.
    """
    F = type(state["factor"])
    ndf, covered = pair_footprints(
        state, alpha, p0x, p0y, p1x, p1y, half_width, wbar, pixel, scratch
    )
    ndf_sum = dr.zeros(F, pixel_count)
    covered_sum = dr.zeros(F, pixel_count)
    dr.scatter_reduce(dr.ReduceOp.Add, ndf_sum, ndf, pixel)
    dr.scatter_reduce(dr.ReduceOp.Add, covered_sum, covered, pixel)
    remainder = dr.maximum(0.0, state["on_board"] - covered_sum) * state["d_flat"]
    return state["factor"] * (ndf_sum + remainder)


def render_scratches(
    design: Design,
    scratches: ScratchSet,
    backend: BackendName = "llvm",
    progress: Callable[[str], None] | None = None,
) -> dict[str, np.ndarray]:
    """Render every view of ``design`` for ``scratches``.

    Args:
        design: The resolved design.
        scratches: The layout.
        backend: ``"llvm"`` (CPU) or ``"cuda"``.
        progress: Called with one line per finished view.

    Returns:
        ``{view name: float32 (H, W) linear radiance}``.
    """
    m = array_module(backend)
    images: dict[str, np.ndarray] = {}
    for view in design.views:
        start = time.perf_counter()
        vr = ViewRenderer(design, view, m)
        pairs = vr.find_pairs(scratches.p0, scratches.p1, scratches.width / 2)
        with dr.suspend_grad():
            image = vr.render(*vr.scratch_arrays(scratches), pairs)
            values = np.asarray(image, dtype=np.float64)
        images[view.name] = values.reshape(vr.height, vr.width).astype(np.float32)
        if progress is not None:
            progress(
                f"view {view.name}: {vr.width}x{vr.height} px, {len(pairs)} pairs, "
                f"{time.perf_counter() - start:.2f} s"
            )
    return images
