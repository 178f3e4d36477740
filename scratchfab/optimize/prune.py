"""``--prune``: drop the scratches the images do not need.

1. Each scratch's own contribution to every pixel it touches is measured by rendering
   the layout in groups of scratches that share no pixel in any view (a greedy
   colouring of the overlap graph): within a group every touched pixel belongs to one
   scratch, so group render minus bare-board render is that scratch's contribution c_s.
2. With the exposure solved in closed form, the linear error of a view is
   E = 1 - (R.T)^2 / (R.R T.T), so removing scratch s (R -> R - c_s) changes it by an
   amount computed exactly from three sparse dot products. Scratches are ranked by this
   predicted rise (averaged over the views).
3. The longest prefix of that ranking whose removal keeps the true loss (re-rendered,
   exposure re-solved) within ``(1 + tolerance)`` of the unpruned loss is found by
   bisection over the prefix length.

Machining time saved is a simple estimate: cutting length / engrave feed plus a fixed
overhead per stroke (rapid move, plunge, retract); both are settings, not measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np
from scipy import sparse

from scratchfab.backend import jit_array
from scratchfab.model.scratches import ScratchSet
from scratchfab.optimize.optimizer import LayoutOptimizer
from scratchfab.render.pairs import Pairs
from scratchfab.render.profile import solve_wbar


@dataclass(frozen=True)
class PruneReport:
    """What pruning removed and saved.

    Attributes:
        kept: The pruned layout.
        removed: Number of scratches dropped.
        loss_before: Loss of the full layout.
        loss_after: Loss of the pruned layout.
        length_saved_mm: Total cutting length of the dropped scratches.
        time_saved_s: Estimated machining time saved.
        feed_mm_min: Engrave feed used for the estimate.
        stroke_overhead_s: Per-stroke overhead used for the estimate.
    """

    kept: ScratchSet
    removed: int
    loss_before: float
    loss_after: float
    length_saved_mm: float
    time_saved_s: float
    feed_mm_min: float
    stroke_overhead_s: float


def _colouring(incidence: sparse.csr_matrix) -> np.ndarray:
    """Greedy colours of scratches so that no two of one colour share a pixel."""
    conflict = (incidence @ incidence.T).tocsr()
    n = incidence.shape[0]
    colour = np.full(n, -1, dtype=np.int64)
    for s in np.argsort(-np.diff(conflict.indptr), kind="stable"):
        nb = conflict.indices[conflict.indptr[s] : conflict.indptr[s + 1]]
        used = set(colour[nb][colour[nb] >= 0].tolist())
        c = 0
        while c in used:
            c += 1
        colour[s] = c
    return colour


def removal_effect(opt: LayoutOptimizer, layout: ScratchSet) -> np.ndarray:
    """Predicted rise of the mean linear view error when each scratch alone is removed."""
    m = opt.m
    n = len(layout)
    half = layout.width / 2
    pairs = [r.find_pairs(layout.p0, layout.p1, half, 0.0) for r in opt.renderers]
    offsets = np.cumsum([0] + [r.pixel_count for r in opt.renderers])
    rows = np.concatenate([p.scratch_np for p in pairs])
    cols = np.concatenate([p.pixel_np + off for p, off in zip(pairs, offsets, strict=False)])
    incidence = sparse.csr_matrix(
        (np.ones(len(rows), np.float32), (rows, cols)), shape=(n, int(offsets[-1]))
    )
    colour = _colouring(incidence)
    F = opt.Float
    p0x, p0y = jit_array(F, layout.p0[:, 0]), jit_array(F, layout.p0[:, 1])
    p1x, p1y = jit_array(F, layout.p1[:, 0]), jit_array(F, layout.p1[:, 1])
    hw = jit_array(F, layout.width / 2)
    wbar = jit_array(F, solve_wbar(layout.width, layout.depth))
    effect = np.zeros(n)
    with dr.suspend_grad():
        for r, p, v in zip(opt.renderers, pairs, opt.views, strict=True):
            target = opt.target_np[v.name].ravel()
            ok = np.isfinite(target)
            t = np.where(ok, target, 0.0)
            empty = Pairs(m.UInt32(), m.UInt32(), np.zeros(0, np.uint32), np.zeros(0, np.uint32))
            bare = np.asarray(r.render(p0x, p0y, p1x, p1y, hw, wbar, empty), np.float64)
            full = np.asarray(r.render(p0x, p0y, p1x, p1y, hw, wbar, p), np.float64)
            full = np.where(ok, full, 0.0)
            contrib = np.zeros(len(p))
            pair_colour = colour[p.scratch_np]
            for g in range(int(colour.max()) + 1):
                sel = np.flatnonzero(pair_colour == g)
                if len(sel) == 0:
                    continue
                sub = Pairs(
                    jit_array(m.UInt32, p.pixel_np[sel], np.uint32),
                    jit_array(m.UInt32, p.scratch_np[sel], np.uint32),
                    p.pixel_np[sel],
                    p.scratch_np[sel],
                )
                img = np.asarray(r.render(p0x, p0y, p1x, p1y, hw, wbar, sub), np.float64)
                contrib[sel] = (img - bare)[p.pixel_np[sel]]
            contrib = np.where(ok[p.pixel_np], contrib, 0.0)
            rt, rr, tt = float(full @ t), float(full @ full), float(t @ t)
            ct = np.bincount(p.scratch_np, contrib * t[p.pixel_np], minlength=n)
            cr = np.bincount(p.scratch_np, contrib * full[p.pixel_np], minlength=n)
            cc = np.bincount(p.scratch_np, contrib * contrib, minlength=n)
            e0 = 1 - rt * rt / max(rr * tt, 1e-300)
            rr1 = np.maximum(rr - 2 * cr + cc, 1e-300)
            e1 = 1 - (rt - ct) ** 2 / (rr1 * max(tt, 1e-300))
            effect += (e1 - e0) / len(opt.views)
    return effect


def prune(
    opt: LayoutOptimizer,
    layout: ScratchSet,
    tolerance: float,
    feed_mm_min: float,
    stroke_overhead_s: float,
) -> PruneReport:
    """Drop the scratches whose removal raises the loss by at most ``tolerance`` (relative)."""
    loss0 = opt.evaluate(layout).loss
    order = np.argsort(removal_effect(opt, layout), kind="stable")
    limit = loss0 * (1 + tolerance)

    def keep_mask(k: int) -> np.ndarray:
        mask = np.ones(len(layout), dtype=bool)
        mask[order[:k]] = False
        return mask

    lo, hi = 0, len(layout) - 1
    best_loss = loss0
    while lo < hi:
        mid = (lo + hi + 1) // 2
        loss = opt.evaluate(layout.subset(keep_mask(mid))).loss
        if loss <= limit:
            lo, best_loss = mid, loss
        else:
            hi = mid - 1
    kept = layout.subset(keep_mask(lo))
    dropped = layout.subset(~keep_mask(lo))
    length = float(dropped.lengths.sum())
    return PruneReport(
        kept=kept,
        removed=lo,
        loss_before=loss0,
        loss_after=best_loss,
        length_saved_mm=length,
        time_saved_s=length / feed_mm_min * 60.0 + lo * stroke_overhead_s,
        feed_mm_min=feed_mm_min,
        stroke_overhead_s=stroke_overhead_s,
    )
