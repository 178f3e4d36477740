"""PNG figures of a run: the loss curve and targets beside renders (Pillow only)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from scratchfab.fileio import save_png


def _encode(values: np.ndarray, scale: float) -> np.ndarray:
    """8-bit sRGB gray of linear values times ``scale``; NaN shows dark blue."""
    finite = np.isfinite(values)
    v = np.clip(np.where(finite, values * scale, 0.0), 0.0, 1.0)
    enc = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    rgb = np.repeat(np.round(enc * 255).astype(np.uint8)[..., None], 3, axis=2)
    rgb[~finite] = (16, 24, 64)
    return rgb


def save_loss_plot(path: Path, iterations: Sequence[float], losses: Sequence[float]) -> None:
    """Loss against iteration on a log scale, with axis labels."""
    w, h, left, bottom, pad = 640, 400, 70, 40, 20
    img = Image.new("RGB", (w, h), "white")
    draw = ImageDraw.Draw(img)
    x0, x1, y0, y1 = left, w - pad, h - bottom, pad
    draw.rectangle((x0, y1, x1, y0), outline="black")
    it = np.asarray(iterations, dtype=np.float64)
    loss = np.asarray(losses, dtype=np.float64)
    ok = np.isfinite(loss) & (loss > 0)
    if ok.sum() >= 1:
        it, loss = it[ok], loss[ok]
        lo, hi = math.log10(loss.min()), math.log10(loss.max())
        if hi - lo < 1e-9:
            lo, hi = lo - 0.5, hi + 0.5
        span = max(it.max() - it.min(), 1.0)
        px = x0 + (it - it.min()) / span * (x1 - x0)
        py = y0 - (np.log10(loss) - lo) / (hi - lo) * (y0 - y1)
        draw.line(list(zip(px.tolist(), py.tolist(), strict=True)), fill=(200, 40, 40), width=2)
        draw.text((5, y1), f"{10**hi:.3g}", fill="black")
        draw.text((5, y0 - 10), f"{10**lo:.3g}", fill="black")
        draw.text((x0, y0 + 5), f"{it.min():.0f}", fill="black")
        draw.text((x1 - 40, y0 + 5), f"{it.max():.0f}", fill="black")
    draw.text((w // 2 - 40, h - 18), "iteration", fill="black")
    draw.text((5, h // 2), "loss (log)", fill="black")
    save_png(path, img)


def save_side_by_side(
    path: Path, targets: Mapping[str, np.ndarray], renders: Mapping[str, np.ndarray]
) -> None:
    """One row per view: target | exposed render (both sRGB-encoded), labelled."""
    rows = []
    for name, target in targets.items():
        render = renders[name]
        ok = np.isfinite(target) & np.isfinite(render)
        rr = float(np.sum(render[ok].astype(np.float64) ** 2))
        s = float(np.sum(render[ok] * target[ok])) / rr if rr > 0 else 0.0
        shown = np.where(np.isfinite(target), render, np.nan)
        rows.append((name, _encode(target, 1.0), _encode(shown, s)))
    if not rows:
        return
    label = 16
    cell_w = max(r[1].shape[1] for r in rows)
    cell_h = max(r[1].shape[0] for r in rows)
    img = Image.new("RGB", (2 * cell_w + 12, len(rows) * (cell_h + label) + 4), "white")
    draw = ImageDraw.Draw(img)
    for k, (name, t, r) in enumerate(rows):
        y = k * (cell_h + label)
        draw.text((4, y + 2), f"{name}: target | render", fill="black")
        img.paste(Image.fromarray(t), (4, y + label))
        img.paste(Image.fromarray(r), (cell_w + 8, y + label))
    save_png(path, img)
