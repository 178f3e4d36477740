"""The optimization loop: render every view, one Adam step, one ``dr.eval()`` per step.

:class:`LayoutOptimizer` owns the Dr.Jit state (raw parameters and Adam moments), the
per-view renderers and targets, and the pixel pairs. Pairs are re-found every
``refresh_every`` steps with the margin of :func:`scratchfab.optimize.params.pair_margin`,
which bounds how far any scratch can move before the next refresh, so no (pixel,
scratch) pair that the exact renderer would need is ever missing.

With a step-size schedule (:class:`~scratchfab.optimize.options.StepSchedule`), step t
moves each coordinate by at most scale(t) times its learning rate, so the margin is a
budget of B = max(K, ceil(largest scale)) steps at the learning rates: pairs are
re-found before the step that would take the sum of the scales since the last refresh
past B (:meth:`LayoutOptimizer.refresh_due`). Large early steps refresh more often, small
late ones less; without a schedule that is every K steps, as before.

At any one step, most of those pairs do not touch. The margin is about a millimetre
around a scratch a tenth of a millimetre wide, so about 2/3 of the demo's pairs and 4/5
of the full-size board's lie beside their scratch. There the footprint integral and its
gradient are exactly zero. A step renders only the pairs that :meth:`_touching` keeps;
their closed form is almost all of a step's time. Dropping exact zeros changes no term
of any sum. Dr.Jit's SIMD scatter-add may group the remaining terms differently, which
moves the last bits of the gradients (the tests bound this). The touch masks for the
next step are evaluated together with the step itself. Only a refresh step evaluates
the masks of its fresh pairs beforehand.

Within a touching pair, most of the closed form's terms are exact zeros too: Green's line
integral is a sum over the footprint's 4 edges and the kinks y = 0 and y = L of eight
terms, and only the edges that cross the scratch's narrow band, and only past the far
end for y = L, add anything (2 for about 60 % of the pairs, 3 or 4 for most others).
After the touch masks, :meth:`_classes` sorts the touching pairs by how many terms they
need (:func:`piece_codes`), and the step renders each class with a kernel of that many
terms (:func:`render_classes`); a pair with none is left out. The codes are a second,
small evaluation after the step's (with the compresses that sort the classes); their
kernel reads only the touching pairs.
"""

from __future__ import annotations

import gc
import math
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import astuple, dataclass
from types import ModuleType
from typing import Any

import drjit as dr
import numpy as np

from scratchfab.backend import jit_array
from scratchfab.design.feasibility import design_glint_deg
from scratchfab.errors import ScratchfabError
from scratchfab.model.design import Design
from scratchfab.model.scratches import ScratchSet
from scratchfab.optimize.glint import view_glint
from scratchfab.optimize.loss import Space, merge_penalty, neighbour_pairs, view_error
from scratchfab.optimize.options import OptimizeOptions, StepSchedule
from scratchfab.optimize.params import (
    KEYS,
    BoundedAdam,
    Bounds,
    endpoints,
    from_scratches,
    pair_margin,
    project,
    project_np,
    to_arrays,
)
from scratchfab.render.pairs import Pairs
from scratchfab.render.profile import solve_wbar
from scratchfab.render.renderer import (
    CLASS_SIZES,
    ViewRenderer,
    piece_codes,
    render_classes,
    render_pairs,
    sort_classes,
)

#: Slack (mm) of :meth:`LayoutOptimizer._touching`: a pair is dropped only when its
#: footprint lies this far beyond its scratch's rectangle, a million times the float64
#: rounding of board coordinates (about 1e-14 mm on a 100 mm board).
TOUCH_SLACK_MM = 1e-8

#: The class arrays of :meth:`LayoutOptimizer._classes` have sizes of distinct residues
#: modulo this (at least 2 + the number of views x classes; more are rare, then it only
#: records the frozen step again when sizes happen to match).
CLASS_PAD = 64

#: Per view, the positions among the pairs in use of those a step renders (Dr.Jit UInt32).
Active = list[Any]

#: Per view and class (:data:`CLASS_SIZES`, then the full kernel), the positions among the
#: view's touching pairs (:data:`Active`) of those the step renders by that class and
#: their :func:`piece_codes` codes (Dr.Jit UInt32), or None for none.
Classes = list[list[tuple[Any, Any] | None]]

#: Per view, what :meth:`LayoutOptimizer._objective` renders: the (pixel, scratch) indices
#: of the pairs in use, the positions among them to render (None: all) and, if not None,
#: per class the positions and codes of the pairs it renders (:data:`Classes`); or None
#: when the view renders no pair.
ViewPairs = tuple[Any, Any, Any, list[tuple[Any, Any] | None] | None] | None


class NonFiniteError(ScratchfabError):
    """The loss or a gradient became NaN or infinite."""


def _non_finite(
    loss: float, images: Mapping[str, np.ndarray], grads: Mapping[str, np.ndarray]
) -> tuple[str, str] | None:
    """What of a step is NaN or infinite, in words, and what to try; None if nothing.

    A render comes first (the loss and gradients follow from it; learning rates do not
    make a render of valid scratches non-finite), then the loss, then the gradients.
    Checked in numpy: Dr.Jit compiles with fast-math, where NaN tests may fold away.
    """
    for name, image in images.items():
        bad = int(np.count_nonzero(~np.isfinite(image)))
        if bad:
            return (
                f"non-finite render of view '{name}' ({bad} of {image.size} pixels)",
                "check the design's light and tool; if they are ordinary, this is a "
                "defect: please report it with design/design.toml",
            )
    if not math.isfinite(loss):
        return "non-finite loss", "try smaller learning rates"
    for key, grad in grads.items():
        rows = np.flatnonzero(~np.isfinite(grad))
        if len(rows):
            return (
                f"non-finite gradient of {key} for {len(rows)} scratches (first: row "
                f"{int(rows[0]) + 1})",
                "try smaller learning rates",
            )
    return None


@dataclass(frozen=True)
class Settings:
    """Numerical settings of the loop (a subset of the stage's options).

    Attributes:
        lr: Per-variable learning rate (cx, cy in mm, theta in rad, length in mm).
        refresh_every: Steps between pair refreshes (K).
        space: Image error space, ``"linear"`` or ``"perceptual"``.
        merge_weight: Weight of the merge penalty (per scratch, per mm cut twice).
        bound_weight: Weight of the pull back onto the feasible set (per scratch, 1/mm^2).
        schedule: Multiples of ``lr`` step by step (None: ``lr`` throughout).
    """

    lr: Mapping[str, float]
    refresh_every: int = 8
    space: Space = "linear"
    merge_weight: float = 0.02
    bound_weight: float = 1.0
    schedule: StepSchedule | None = None

    @classmethod
    def of(cls, options: OptimizeOptions, schedule: StepSchedule | None = None) -> Settings:
        """The settings the stage's ``options`` give the loop.

        Args:
            options: The optimize options (the ``[optimize]`` table, the CLI's flags).
            schedule: The step-size schedule, where not ``options.schedule()`` (a resume
                past the planned iterations extends it).
        """
        return cls(
            lr=options.learning_rates(),
            refresh_every=options.refresh_every,
            space=options.space,
            merge_weight=options.merge_weight,
            schedule=schedule if schedule is not None else options.schedule(),
        )

    def pair_budget(self) -> int:
        """Steps at ``lr`` that the pair margin covers: K, or more for a larger scale."""
        if self.schedule is None:
            return self.refresh_every
        return max(self.refresh_every, math.ceil(self.schedule.largest()))


@dataclass
class StepResult:
    """What one step measured (before its update).

    Attributes:
        loss: Total loss.
        view_errors: E_k per view name.
        renders: R_k per view name, (H, W) float32.
    """

    loss: float
    view_errors: dict[str, float]
    renders: dict[str, np.ndarray]


def _hold(entry: tuple[Any, ...]) -> tuple[Any, ...]:
    """An Adam state entry whose arrays are new Python objects for the same Dr.Jit data.

    A frozen function's replay writes the new values of an input's arrays into the very
    objects it was given (traced code and recordings assign new objects), so a reference
    kept across a frozen step would show the values after it.
    """
    value, promoted, lr, extra = entry
    return (
        type(value)(value),
        promoted,
        lr,
        tuple(None if x is None else type(x)(x) for x in extra),
    )


class LayoutOptimizer:
    """Multi-view Adam optimization of a scratch layout.

    The image error leaves out each view's pixels where the bare board glints
    (:mod:`scratchfab.optimize.glint`), as it does those off the board.

    Bit-identical steps from the same inputs need one Dr.Jit thread
    (``drjit.set_thread_count(1)`` first, as :func:`scratchfab.optimize.stage.run_optimize`
    does by default): with several, its CPU kernels add floats in a varying order and two
    runs agree only to rounding (about 1e-13 mm).

    Args:
        design: The resolved design.
        targets: Linear (H, W) target per view name (NaN off the board); views without
            one are not optimized for.
        initial: The starting layout.
        settings: Numerical settings.
        m: Dr.Jit array namespace.
        freeze: Replay each step's kernels with ``dr.freeze`` instead of tracing them
            again (the same kernels, so the same results; it saves the tracing and AD
            bookkeeping, about a fifth of a demo step).
    """

    def __init__(
        self,
        design: Design,
        targets: Mapping[str, np.ndarray],
        initial: ScratchSet,
        settings: Settings,
        m: ModuleType,
        freeze: bool = True,
    ) -> None:
        if len(initial) == 0:
            raise ScratchfabError("the initial layout has no scratches")
        self.design = design
        self.settings = settings
        self.m = m
        self.bounds = Bounds.from_design(design)
        self.views = [v for v in design.views if v.name in targets]
        if not self.views:
            names = ", ".join(v.name for v in design.views)
            raise ScratchfabError(
                f"{design.source}: the targets ({', '.join(map(str, targets)) or 'none'}) "
                f"name none of the views ({names})"
            )
        if missing := [k for k in KEYS if k not in settings.lr]:
            raise ScratchfabError(
                f"Settings.lr: missing {', '.join(missing)} "
                "(OptimizeOptions().learning_rates() gives all four)"
            )
        self.renderers = [ViewRenderer(design, v, m) for v in self.views]
        #: The renderer's float type (float64: its closed form needs the precision).
        self.Float = m.Float64
        self.dtype = np.float64
        F = self.Float
        limit = design_glint_deg(design)
        #: Per view, the bare board's glint (:mod:`scratchfab.optimize.glint`).
        self.glint = [view_glint(r, limit) for r in self.renderers]
        #: Per view, the target the image error sees: NaN off the board and where the bare
        #: board glints (those pixels are left out of s_k and E_k; pruning reads it too).
        self.target_np: dict[str, np.ndarray] = {}
        self._targets = []
        for v, glint in zip(self.views, self.glint, strict=True):
            t = np.asarray(targets[v.name], dtype=np.float64)
            if t.shape != (v.height, v.width):
                raise ScratchfabError(
                    f"target of view '{v.name}' is {t.shape[1]}x{t.shape[0]} pixels, "
                    f"the view is {v.width}x{v.height}"
                )
            t = np.where(glint.mask, np.nan, t)
            self.target_np[v.name] = t
            ok = np.isfinite(t).ravel()
            self._targets.append((jit_array(F, np.where(ok, t.ravel(), 0.0)), jit_array(F, ok)))
        self.count = len(initial)
        self.width = initial.width.copy()
        self.depth = initial.depth.copy()
        self._half_width = jit_array(F, initial.width / 2)
        self._wbar = jit_array(F, solve_wbar(initial.width, initial.depth))
        self.tool_width = float(np.max(initial.width))
        self.opt = BoundedAdam(lr=1.0)
        raw = project_np(from_scratches(initial), self.bounds)
        for key, value in to_arrays(F, raw).items():
            self.opt[key] = value
        self.opt.set_learning_rate({k: float(settings.lr[k]) for k in KEYS})
        self.iteration = 0
        #: Steps at the learning rates that the pair margin covers (module docstring).
        self.budget = settings.pair_budget()
        self.margin = pair_margin(
            dict(settings.lr),
            self.bounds.max_length,
            self.budget,
            float(np.max(initial.width)) / 2,
        )
        # refresh_due's plan so far, and the sum of the scales since its last refresh
        self._due: list[bool] = []
        self._moved = 0.0
        self.ends = self._ends_np()
        self.refresh_ends: np.ndarray | None = None
        self.pairs: list[Pairs] = []
        #: The touching subset of ``pairs`` at the current parameters (None: not known).
        self.active: Active | None = None
        #: Per view and class, the pairs the next step renders (:meth:`_classes`).
        self.classes: Classes | None = None
        # A step's shape (which views render pairs, whether merge candidates exist, whether
        # the next step refreshes) keys its recording; a few recordings a run is normal.
        self._train_step = (
            dr.freeze(self._train, state_fn=self._recording_key, limit=16, warn_after=64)
            if freeze
            else self._train
        )
        self.neighbours: tuple[Any, Any] | None = None
        self._neighbour_count = 0

    def glint_notes(self) -> list[str]:
        """A line for the user per view whose glinting pixels the image error leaves out."""
        return [note for g in self.glint if (note := g.note())]

    # ------------------------------------------------------------------ state
    def _ends_np(self) -> np.ndarray:
        """Current projected endpoints (N, 4) x0, y0, x1, y1."""
        with dr.suspend_grad():
            ends = endpoints(*self._projected())
            return np.stack([np.asarray(e, dtype=self.dtype) for e in ends], axis=1)

    def _projected(self) -> tuple[Any, ...]:
        """Projection of the optimizer's current raw parameters (Dr.Jit)."""
        o = self.opt
        return project(o["cx"], o["cy"], o["theta"], o["length"], self.bounds)

    def scratches(self) -> ScratchSet:
        """The current (projected) layout."""
        e = self.ends.astype(np.float64)
        return ScratchSet(e[:, 0:2].copy(), e[:, 2:4].copy(), self.width.copy(), self.depth.copy())

    def state(self) -> dict[str, np.ndarray]:
        """Everything needed to continue on the same trajectory (numpy)."""
        out: dict[str, np.ndarray] = {"iteration": np.asarray(self.iteration)}
        # Copies, not views of Dr.Jit memory: a frozen replay reassigns these arrays in
        # place and frees their old memory (see :meth:`step`).
        for key in KEYS:
            value, _promoted, _lr, (t, m1, v1, _vmax) = self.opt.state[key]
            out[f"raw_{key}"] = np.array(value, dtype=self.dtype, copy=True)
            out[f"adam_t_{key}"] = np.array(t, dtype=np.uint32, copy=True)
            out[f"adam_m_{key}"] = np.array(m1, dtype=self.dtype, copy=True)
            out[f"adam_v_{key}"] = np.array(v1, dtype=self.dtype, copy=True)
        if self.refresh_ends is not None:
            out["refresh_ends"] = self.refresh_ends
        return out

    def load_state(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore :meth:`state` exactly (bit for bit)."""
        m = self.m
        for key in KEYS:
            raw = np.asarray(state[f"raw_{key}"], dtype=self.dtype)
            if raw.shape != (self.count,):
                raise ScratchfabError(
                    f"the checkpoint holds {raw.shape[0]} scratches, the job {self.count}"
                )
            value = jit_array(self.Float, raw)
            dr.enable_grad(value)
            _old, promoted, lr, _extra = self.opt.state[key]
            t = dr.opaque(m.UInt32, int(np.asarray(state[f"adam_t_{key}"]).ravel()[0]), 1)
            m1 = jit_array(self.Float, state[f"adam_m_{key}"], self.dtype)
            v1 = jit_array(self.Float, state[f"adam_v_{key}"], self.dtype)
            self.opt.state[key] = (value, promoted, lr, (t, m1, v1, None))
        self.iteration = int(state["iteration"])
        self.ends = self._ends_np()
        self.active = None
        self.classes = None
        if "refresh_ends" in state:
            self._refresh(np.asarray(state["refresh_ends"], dtype=self.dtype))
        else:
            self.refresh_ends = None
            self.pairs = []

    # ------------------------------------------------------------------ pairs
    def _refresh(self, ends: np.ndarray) -> None:
        """Re-find pixel pairs and merge candidates around the layout ``ends``."""
        # The old pairs go first, or they would take memory beside the new ones.
        self.pairs = []
        self.neighbours = None
        self._neighbour_count = 0
        self.active = None
        self.classes = None
        self.refresh_ends = ends.copy()
        e = ends.astype(np.float64)
        p0, p1 = e[:, 0:2], e[:, 2:4]
        half = self.width / 2
        reach = self.tool_width + 2 * (self.margin - float(np.max(half)))
        slack = 2 * self.budget * float(self.settings.lr["theta"])
        if dr.thread_count() > 1:
            # the merge candidates (numpy and compiled code, no Dr.Jit, the GIL released)
            # on a second core, beside the pixel pairs
            with ThreadPoolExecutor(max_workers=1) as pool:
                found = pool.submit(neighbour_pairs, p0, p1, reach, slack, dtype=np.uint32)
                pairs = [r.find_pairs(p0, p1, half, self.margin) for r in self.renderers]
                i, j = found.result()
        else:
            pairs = [r.find_pairs(p0, p1, half, self.margin) for r in self.renderers]
            i, j = neighbour_pairs(p0, p1, reach, slack, dtype=np.uint32)
        U = self.m.UInt32
        self.neighbours = (jit_array(U, i, np.uint32), jit_array(U, j, np.uint32))
        self._neighbour_count = len(i)
        self.pairs = pairs

    def scale(self, t: int) -> float:
        """The multiple of the learning rates that step ``t`` takes (1 without a schedule)."""
        schedule = self.settings.schedule
        return 1.0 if schedule is None else schedule.scale(t)

    def refresh_due(self, t: int) -> bool:
        """Whether pairs are re-found before step ``t``.

        Without a schedule every K steps. With one, before the step that would take the
        sum of the scales since the last refresh past the budget: no scratch then moves
        farther than the margin assumed. A function of ``t`` and the settings alone,
        planned from step 0, so a resumed run refreshes where an uninterrupted one does.
        """
        if self.settings.schedule is None:
            return t % self.settings.refresh_every == 0
        while len(self._due) <= t:
            i = len(self._due)
            s = self.scale(i)
            due = i == 0 or self._moved + s > self.budget
            self._moved = (0.0 if due else self._moved) + s
            self._due.append(due)
        return self._due[t]

    def pair_counts(self) -> list[int]:
        """Number of pairs per view in use."""
        return [len(p) for p in self.pairs]

    def _touching(self, ends: tuple[Any, Any, Any, Any], ctx: dict[str, Any]) -> list[Any]:
        """Per view, the mask of the pairs in use that may touch at endpoints ``ends``.

        A pair is dropped when its footprint's four corners, in its scratch's frame (x
        across, y along from p0, as :mod:`scratchfab.render.ndf` sets it up), all lie
        more than TOUCH_SLACK_MM beyond one side, |x| = w, or before its start, y = 0.
        Every edge piece of that footprint is then empty or has weight clamp(y, 0, L) = 0,
        so the pair adds exactly 0 to its pixel's NDF and covered area, with exactly zero
        derivatives. (Past the far end, y = L, the pieces cancel only to rounding, so
        those pairs stay.) Reads the pairs and the views from ``ctx``
        (:meth:`_context`). Not evaluated; detached.
        """
        F = self.Float
        masks = []
        with dr.suspend_grad():
            p0x, p0y, p1x, p1y = (dr.detach(e) for e in ends)
            for state, (pix, s) in zip(ctx["views"], ctx["pairs"], strict=True):
                ax, ay = dr.gather(F, p0x, s), dr.gather(F, p0y, s)
                ex, ey = dr.gather(F, p1x, s) - ax, dr.gather(F, p1y, s) - ay
                length = dr.sqrt(ex * ex + ey * ey)
                inv = dr.rcp(dr.select(length > 0, length, 1.0))
                ux = dr.select(length > 0, ex * inv, 0.0)
                uy = dr.select(length > 0, ey * inv, 1.0)
                across: list[Any] = []
                along: list[Any] = []
                for qx, qy in zip(state["qx"], state["qy"], strict=True):
                    rx, ry = dr.gather(F, qx, pix) - ax, dr.gather(F, qy, pix) - ay
                    across.append(rx * uy - ry * ux)
                    along.append(rx * ux + ry * uy)
                w = dr.gather(F, ctx["half_width"], s) + TOUCH_SLACK_MM
                lo = dr.minimum(dr.minimum(across[0], across[1]), dr.minimum(across[2], across[3]))
                hi = dr.maximum(dr.maximum(across[0], across[1]), dr.maximum(across[2], across[3]))
                top = dr.maximum(dr.maximum(along[0], along[1]), dr.maximum(along[2], along[3]))
                masks.append((lo <= w) & (hi >= -w) & (top >= -TOUCH_SLACK_MM))
        return masks

    @staticmethod
    def _compress(masks: list[Any]) -> Active:
        """The positions of the pairs that ``masks`` (evaluated) keep, in order."""
        return [dr.compress(mask) for mask in masks]

    def _classes(self, ends: tuple[Any, Any, Any, Any], active: Active) -> Classes:
        """Per view and class, positions among the ``active`` pairs and :func:`piece_codes`.

        A pair whose 8 terms are all exact zeros at endpoints ``ends`` (slack
        TOUCH_SLACK_MM) is left out; the others go to the first class of
        :data:`CLASS_SIZES` that holds their count of terms, or to the full kernel.
        Evaluated (it compresses).
        """
        U = self.m.UInt32
        with dr.suspend_grad():
            p0x, p0y, p1x, p1y = (dr.detach(e) for e in ends)
            codes: list[tuple[Any, Any] | None] = []
            for r, p, keep in zip(self.renderers, self.pairs, active, strict=True):
                if dr.width(keep) == 0:
                    codes.append(None)
                    continue
                pix, sc = dr.gather(U, p.pixel, keep), dr.gather(U, p.scratch, keep)
                codes.append(
                    piece_codes(
                        r.state, p0x, p0y, p1x, p1y, self._half_width, pix, sc, TOUCH_SLACK_MM
                    )
                )
            dr.eval(codes)
            # dr.freeze records again whenever two of its inputs' sizes start or stop
            # being equal: each class of each view is padded to its own residue
            per_view = len(CLASS_SIZES) + 1
            out: Classes = [
                [None] * per_view
                if spec is None
                else sort_classes(*spec, pad=CLASS_PAD, first_residue=2 + v * per_view)
                for v, spec in enumerate(codes)
            ]
        return out

    def active_counts(self) -> list[int]:
        """Number of pairs per view that the next step renders (after a refresh: all)."""
        if self.active is None:
            return self.pair_counts()
        return [dr.width(keep) for keep in self.active]

    def _context(self, half_width: Any = None, wbar: Any = None) -> dict[str, Any]:
        """Every Dr.Jit array a step reads besides the optimizer's, as one PyTree.

        A frozen function must receive each array it reads as an argument.
        """
        return {
            "views": [r.state for r in self.renderers],
            "targets": self._targets,
            "half_width": self._half_width if half_width is None else half_width,
            "wbar": self._wbar if wbar is None else wbar,
            "pairs": [(p.pixel, p.scratch) for p in self.pairs],
            "neighbours": self.neighbours if self._neighbour_count > 0 else None,
            "step_scale": None,
        }

    def _view_pairs(self, active: Active | None, classes: Classes | None = None) -> list[ViewPairs]:
        """What each view renders: the pairs in use, those of ``active`` (None: all).

        With ``classes`` (:meth:`_classes` of ``active``), those by class.
        """
        out: list[ViewPairs] = []
        for i, p in enumerate(self.pairs):
            keep = None if active is None else active[i]
            n = len(p) if keep is None else dr.width(keep)
            by_class = None if classes is None else classes[i]
            if by_class is not None and all(c is None for c in by_class):
                n = 0
            out.append((p.pixel, p.scratch, keep, by_class) if n > 0 else None)
        return out

    # ------------------------------------------------------------------ step
    def _forward(
        self,
        raw: list[Any],
        half_width: Any = None,
        wbar: Any = None,
        active: Active | None = None,
    ) -> tuple[Any, list[Any], list[Any], Any]:
        """Loss, per-view errors and renders of raw parameters (not evaluated).

        ``active`` renders only those pairs (:meth:`_compress`); by default all in use.
        """
        return self._objective(raw, self._context(half_width, wbar), self._view_pairs(active))

    def _objective(
        self, raw: list[Any], ctx: dict[str, Any], view_pairs: list[ViewPairs]
    ) -> tuple[Any, list[Any], list[Any], Any]:
        """:meth:`_forward` of the arrays in ``ctx`` (:meth:`_context`) alone."""
        F, U = self.Float, self.m.UInt32
        half_width, wbar = ctx["half_width"], ctx["wbar"]
        count = dr.width(raw[0])
        s = self.settings
        cx, cy, theta, length = project(raw[0], raw[1], raw[2], raw[3], self.bounds)
        p0x, p0y, p1x, p1y = endpoints(cx, cy, theta, length)
        renders = []
        errors = []
        for r, state, spec, (target, mask) in zip(
            self.renderers, ctx["views"], view_pairs, ctx["targets"], strict=True
        ):
            if spec is None:  # ViewRenderer.render's image without pairs: the flat board
                img = state["factor"] * state["on_board"] * state["d_flat"]
            else:
                pixel, scratch, keep, by_class = spec
                if keep is not None:
                    pixel, scratch = dr.gather(U, pixel, keep), dr.gather(U, scratch, keep)
                if by_class is not None:
                    img = render_classes(
                        state, r.alpha, r.pixel_count, p0x, p0y, p1x, p1y, half_width, wbar,
                        pixel, scratch, by_class,
                    )  # fmt: skip
                else:
                    img = render_pairs(
                        state, r.alpha, r.pixel_count, p0x, p0y, p1x, p1y, half_width, wbar,
                        pixel, scratch,
                    )  # fmt: skip
            err, _s = view_error(img, target, mask, s.space)
            renders.append(img)
            errors.append(err)
        loss = errors[0]
        for e in errors[1:]:
            loss = loss + e
        loss = loss / len(errors)
        n = float(count)
        if s.merge_weight > 0 and ctx["neighbours"] is not None:
            first, second = ctx["neighbours"]
            loss = loss + (s.merge_weight / n) * merge_penalty(
                F, p0x, p0y, p1x, p1y, first, second, self.tool_width
            )
        stray = dr.square(raw[0] - cx) + dr.square(raw[1] - cy) + dr.square(raw[3] - length)
        loss = loss + (s.bound_weight / n) * dr.sum(stray, mode="symbolic")
        return loss, errors, renders, (p0x, p0y, p1x, p1y)

    def _recording_key(self, *_args: Any) -> tuple[Any, ...]:
        """The Python values :meth:`_train` reads through ``self``, as a recording key.

        A frozen replay reuses the values it was recorded with; these are constant over a
        run today, but a change (a schedule, a caller editing ``settings``) must record
        again rather than replay stale constants.
        """
        s = self.settings
        return (
            tuple((k, float(s.lr[k])) for k in KEYS),
            s.space,
            float(s.merge_weight),
            float(s.bound_weight),
            astuple(self.bounds),
            self.tool_width,
            tuple((r.alpha, r.pixel_count) for r in self.renderers),
            self.count,
        )

    def _train(
        self, opt: BoundedAdam, ctx: dict[str, Any], view_pairs: list[ViewPairs], touch: bool
    ) -> tuple[Any, list[Any], list[Any], tuple[Any, ...], list[Any]]:
        """One Adam step of ``opt``: loss, errors and renders before it, endpoints after it.

        With ``touch``, also the touch masks of the pairs in use at the new endpoints.
        Reads Dr.Jit arrays only from its arguments, so that it can be frozen.
        """
        loss, errors, renders, _ends = self._objective([opt[k] for k in KEYS], ctx, view_pairs)
        dr.backward(loss)
        opt.scale = ctx["step_scale"]
        try:
            opt.step(eval=False)
        finally:
            opt.scale = None
        with dr.suspend_grad():
            cx, cy, theta, length = (opt[k] for k in KEYS)
            new_ends = endpoints(*project(cx, cy, theta, length, self.bounds))
            masks = self._touching(new_ends, ctx) if touch else []
        return loss, errors, renders, new_ends, masks

    def step(self) -> StepResult:
        """One Adam step; returns the loss of the parameters before it.

        Raises:
            NonFiniteError: When the loss or a gradient is not finite; the parameters
                are then left as they were before the step.
        """
        if not self.pairs or self.refresh_due(self.iteration):
            self._refresh(self.ends)
        ctx = self._context()
        if self.settings.schedule is not None:
            ctx["step_scale"] = dr.opaque(self.Float, self.scale(self.iteration), 1)
        if self.active is None:
            with dr.suspend_grad():
                masks = self._touching(endpoints(*self._projected()), ctx)
            dr.eval(masks)  # fresh pairs: the one step with a second evaluation
            self.active = self._compress(masks)
            self.classes = None
        if self.classes is None:
            self.classes = self._classes(endpoints(*self._projected()), self.active)
        # A frozen replay updates the optimizer's arrays in place (the same Python objects
        # get the new values), so the state to restore is held by new objects.
        saved = {k: _hold(self.opt.state[k]) for k in KEYS}
        refresh_next = self.refresh_due(self.iteration + 1)
        view_pairs = self._view_pairs(self.active, self.classes)
        # Python's cycle collector may free Dr.Jit arrays in the middle of a dr.freeze
        # recording; one that borrows NumPy memory then releases it through a host
        # callback, which a recording cannot hold ("enqueue_host_func(): this function
        # cannot be recorded", and Dr.Jit aborts the process). It runs after the step.
        collecting = gc.isenabled()
        gc.disable()
        try:
            loss, errors, renders, new_ends, next_masks = self._train_step(
                self.opt, ctx, view_pairs, not refresh_next
            )
        finally:
            if collecting:
                gc.enable()
        dr.schedule(loss, errors, renders, new_ends, next_masks)
        dr.eval()  # traced (freeze=False); a frozen step's outputs are evaluated already
        loss_value = float(loss[0])
        images = {
            v.name: np.asarray(img, dtype=np.float32).reshape(v.height, v.width)
            for v, img in zip(self.views, renders, strict=True)
        }
        grads = {k: np.asarray(self.opt.state[k][3][1]) for k in KEYS}
        problem = _non_finite(loss_value, images, grads)
        if problem is not None:
            for k in KEYS:
                self.opt.state[k] = saved[k]
                dr.enable_grad(saved[k][0])
                dr.clear_grad(saved[k][0])  # the failed step's backward reached it
            self.active = None
            self.classes = None
            raise NonFiniteError(
                f"{problem[0]} at iteration {self.iteration}; the run stopped and the last "
                f"good checkpoint is kept ({problem[1]})"
            )
        self.ends = np.stack([np.asarray(e, dtype=self.dtype) for e in new_ends], axis=1)
        self.active = self._compress(next_masks) if next_masks else None
        self.classes = None if self.active is None else self._classes(new_ends, self.active)
        self.iteration += 1
        return StepResult(
            loss_value,
            {v.name: float(e[0]) for v, e in zip(self.views, errors, strict=True)},
            images,
        )

    def evaluate(self, scratches: ScratchSet | None = None) -> StepResult:
        """Loss and renders of the current layout (or ``scratches``), with fresh exact pairs."""
        layout = scratches if scratches is not None else self.scratches()
        m = self.m
        params = from_scratches(layout)
        with dr.suspend_grad():
            raw = [jit_array(self.Float, params[k], self.dtype) for k in KEYS]
            saved_pairs, saved_nb = self.pairs, self.neighbours
            saved_count = self._neighbour_count
            try:
                half = layout.width / 2
                self.pairs = [r.find_pairs(layout.p0, layout.p1, half, 0.0) for r in self.renderers]
                i, j = neighbour_pairs(layout.p0, layout.p1, self.tool_width, dtype=np.uint32)
                U = m.UInt32
                self.neighbours = (jit_array(U, i, np.uint32), jit_array(U, j, np.uint32))
                self._neighbour_count = len(i)
                half_width = jit_array(self.Float, layout.width / 2)
                wbar = jit_array(self.Float, solve_wbar(layout.width, layout.depth))
                loss, errors, renders, _ = self._forward(raw, half_width, wbar)
                dr.eval(loss, errors, renders)
            finally:
                self.pairs, self.neighbours = saved_pairs, saved_nb
                self._neighbour_count = saved_count
        return StepResult(
            float(loss[0]),
            {v.name: float(e[0]) for v, e in zip(self.views, errors, strict=True)},
            {
                v.name: np.asarray(img, dtype=np.float32).reshape(v.height, v.width)
                for v, img in zip(self.views, renders, strict=True)
            },
        )
