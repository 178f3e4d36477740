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
from scratchfab.errors import ScratchfabError
from scratchfab.model.camera import Camera, polygon_area
from scratchfab.model.design import Design, View
from scratchfab.model.scratches import ScratchSet
from scratchfab.render.ndf import (
    EDGE_SLOTS,
    edge_piece_masks,
    quad_orientation,
    scratch_edges_ndf,
    scratch_footprint_ndf,
)
from scratchfab.render.pairs import Pairs, raster_pairs, scratch_rectangles
from scratchfab.render.profile import solve_wbar

__all__ = [
    "ViewRenderer",
    "render_pairs",
    "render_classes",
    "piece_codes",
    "sort_classes",
    "render_scratches",
    "onboard_area",
    "ggx_d",
]


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
        self._orient = F(quad_orientation(self._qx, self._qy))
        # the corners again, pixel-major (4 j + k): the class kernels gather them by edge
        self._qx4 = jit_array(F, flat_quads[:, :, 0].ravel())
        self._qy4 = jit_array(F, flat_quads[:, :, 1].ravel())
        dr.eval(self._orient)
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
            "orient": self._orient,
            "qx4": self._qx4,
            "qy4": self._qy4,
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
    return _radiance(state, *_pixel_sums(F, pixel_count, pixel, ndf, covered))


def _pixel_sums(F: Any, pixel_count: int, pixel: Any, ndf: Any, covered: Any) -> tuple[Any, Any]:
    """Per-pixel sums of the pairs' NDF integrals and covered areas (scatter-add by pixel)."""
    ndf_sum = dr.zeros(F, pixel_count)
    covered_sum = dr.zeros(F, pixel_count)
    dr.scatter_reduce(dr.ReduceOp.Add, ndf_sum, ndf, pixel)
    dr.scatter_reduce(dr.ReduceOp.Add, covered_sum, covered, pixel)
    return ndf_sum, covered_sum


def _radiance(state: dict[str, Any], ndf_sum: Any, covered_sum: Any) -> Any:
    """SPEC section 4's radiance from the per-pixel sums of the pairs' NDF and covered area."""
    remainder = dr.maximum(0.0, state["on_board"] - covered_sum) * state["d_flat"]
    return state["factor"] * (ndf_sum + remainder)


#: Term counts of the classes of :func:`render_classes`: a pair with at most 2, 3 or 4 terms
#: that may not be 0 (:func:`piece_codes`) is rendered by the kernel of that many terms,
#: any other by the kernel of all 8.
CLASS_SIZES = (2, 3, 4)

#: A :func:`piece_codes` code that marks a padding entry of a class: it adds exactly 0.
NULL_CODE = 0xFFFFFFFF

#: Per class (:data:`CLASS_SIZES`, then the full kernel), the positions of its pairs among
#: those of :func:`render_classes` and their codes (:func:`piece_codes` or
#: :data:`NULL_CODE`), Dr.Jit UInt32; or None for an empty class.
ClassPairs = list[tuple[Any, Any] | None]


def piece_codes(
    state: dict[str, Any],
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    pixel: Any,
    scratch: Any,
    slack: float,
) -> tuple[Any, Any]:
    """(count, code) of each (pixel, scratch) pair: which of its 8 terms to evaluate.

    :func:`scratchfab.render.ndf.edge_piece_masks` marks the terms that may not be
    exactly 0; ``count`` is their number and ``code`` lists every slot 0..7 in 3 bits each,
    lowest first: those terms, then the others. The first ``n >= count`` slots of the code
    therefore give the pair's footprint integrals (the others add exact zeros, with exactly
    zero derivatives).
    """
    F = type(state["factor"])
    U = type(pixel)
    masks = edge_piece_masks(
        [dr.gather(F, q, pixel) for q in state["qx"]],
        [dr.gather(F, q, pixel) for q in state["qy"]],
        dr.gather(F, p0x, scratch),
        dr.gather(F, p0y, scratch),
        dr.gather(F, p1x, scratch),
        dr.gather(F, p1y, scratch),
        dr.gather(F, half_width, scratch),
        slack,
    )
    count = U(0)
    code = U(0)
    for slot, mask in enumerate(masks):
        code = code | dr.select(mask, U(slot) << (3 * count), 0)
        count = count + dr.select(mask, U(1), U(0))
    at = U(count)
    for slot, mask in enumerate(masks):
        code = code | dr.select(mask, 0, U(slot) << (3 * at))
        at = at + dr.select(mask, U(0), U(1))
    return count, code


def sort_classes(count: Any, code: Any, pad: int = 1, first_residue: int = 0) -> ClassPairs:
    """:data:`ClassPairs` of pairs with :func:`piece_codes` ``(count, code)`` (evaluated).

    Each pair goes to the first class of :data:`CLASS_SIZES` that holds its count, or to
    the full kernel; pairs with count 0 (all terms exact zeros) to none. With ``pad`` > 1,
    class ``c`` is padded with :data:`NULL_CODE` entries (which add nothing) to a size of
    residue ``first_residue + c`` modulo ``pad`` (a dr.freeze replay needs the pattern of
    equal input sizes to stay the same).
    """
    U = type(count)
    classes: ClassPairs = []
    low = 1
    for c, size in enumerate([*CLASS_SIZES, EDGE_SLOTS]):
        idx: Any = dr.compress((count >= low) & (count <= size))
        low = size + 1
        n = dr.width(idx)
        if n == 0:
            classes.append(None)
            continue
        padded = n + (first_residue + c - n) % pad
        at = dr.arange(U, padded)
        idx = dr.gather(U, idx, dr.minimum(at, n - 1))
        classes.append((idx, dr.select(at >= n, NULL_CODE, dr.gather(U, code, idx))))
    dr.eval(classes)
    return classes


def class_footprints(
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
    code: Any,
    terms: int,
) -> tuple[Any, Any]:
    """The first ``terms`` terms of each pair's :func:`piece_codes` code, not yet summed.

    Arguments as :func:`pair_footprints`; equal to it (to rounding) where ``terms`` is at
    least the pair's count. Differentiable with respect to the scratch endpoints (the
    closed form's written-out derivative, ``custom_derivative`` of
    :func:`scratch_edges_ndf`); the widths, profiles and the view carry none.
    """
    F = type(state["factor"])
    U = type(pixel)
    hx, hy, hz = (dr.gather(F, c, pixel) for c in state["h"])
    base = pixel * 4
    edges = []
    for n in range(terms):
        slot = (code >> (3 * n)) & 7
        first = base + (slot >> 1)
        second = base + (((slot >> 1) + 1) & 3)
        edges.append(
            (
                dr.gather(F, state["qx4"], first),
                dr.gather(F, state["qy4"], first),
                dr.gather(F, state["qx4"], second),
                dr.gather(F, state["qy4"], second),
                (slot & 1) == U(1),
            )
        )
    return scratch_edges_ndf(
        edges,
        dr.gather(F, state["orient"], pixel),
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
        custom_derivative=True,
    )


def render_classes(
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
    classes: ClassPairs,
) -> Any:
    """:func:`render_pairs` of the pairs that ``classes`` lists, each class by its own kernel.

    The pairs of class ``c`` (of :data:`CLASS_SIZES`) must have a :func:`piece_codes`
    count of at most ``CLASS_SIZES[c]``; their kernel evaluates only that many of the 8
    terms, which gives the image (and derivatives) of :func:`render_pairs` to rounding.
    Entries with code :data:`NULL_CODE` add nothing (padding, see
    :meth:`scratchfab.optimize.optimizer.LayoutOptimizer._classes`). Pairs that no
    class lists are not rendered.

    Each class adds its pairs into pixel buffers of its own, and reads the scratch
    arrays through its own AD node (``x + 0.0``), so that the backward pass adds its
    derivatives into a buffer of its own too; the sums over classes are then formed in
    a fixed order. Scatter-adds of several kernels into one buffer would add in the order
    the kernels run, which a dr.freeze replay takes from its recording and tracing from
    the current sizes, so frozen and traced steps would differ in the last bits.

    Args:
        state: :attr:`ViewRenderer.state`.
        alpha: GGX roughness.
        pixel_count: H * W.
        p0x: Scratch start x (Float64), and the other scratch arrays as :func:`render_pairs`.
        p0y: see p0x.
        p1x: see p0x.
        p1y: see p0x.
        half_width: see p0x.
        wbar: see p0x.
        pixel: (pixel, scratch) pairs: pixel indices (UInt32).
        scratch: Their scratch indices.
        classes: :data:`ClassPairs` into those pairs, one entry per class and one for the
            full kernel.

    Returns:
        Dr.Jit Float64 (pixel_count,) linear radiance.
    """
    if len(classes) != len(CLASS_SIZES) + 1:
        raise ValueError(f"render_classes takes {len(CLASS_SIZES) + 1} classes, got {len(classes)}")
    F = type(state["factor"])
    U = type(pixel)
    ndf_sum = dr.zeros(F, pixel_count)
    covered_sum = dr.zeros(F, pixel_count)
    for c, spec in enumerate(classes):
        if spec is None:
            continue
        at, code = spec
        pix, sc = dr.gather(U, pixel, at), dr.gather(U, scratch, at)
        x0, y0, x1, y1 = (e + 0.0 for e in (p0x, p0y, p1x, p1y))
        terms = CLASS_SIZES[c] if c < len(CLASS_SIZES) else EDGE_SLOTS
        ndf, covered = class_footprints(
            state, alpha, x0, y0, x1, y1, half_width, wbar, pix, sc, code, terms
        )
        null = code == NULL_CODE
        ndf, covered = dr.select(null, 0.0, ndf), dr.select(null, 0.0, covered)
        ndf_class, covered_class = _pixel_sums(F, pixel_count, pix, ndf, covered)
        ndf_sum = ndf_sum + ndf_class
        covered_sum = covered_sum + covered_class
    return _radiance(state, ndf_sum, covered_sum)


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

    Raises:
        ScratchfabError: A scratch's end, width or depth is not a finite number, or its
            width or depth is not positive (naming the first such scratch).
        BackendError: The backend cannot run here.
    """
    ends = np.hstack(
        [scratches.p0, scratches.p1, scratches.width[:, None], scratches.depth[:, None]]
    )
    sizes = np.stack([scratches.width, scratches.depth], axis=1)
    bad = np.flatnonzero(~np.all(np.isfinite(ends), axis=1) | np.any(sizes <= 0, axis=1))
    if len(bad):
        row = int(bad[0])
        raise ScratchfabError(
            f"scratch {row + 1} (line {row + 2}) is not drawable: ends "
            f"{ends[row, :4].tolist()}, width {ends[row, 4]:g}, depth {ends[row, 5]:g} mm "
            f"({len(bad)} scratches)"
        )
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
