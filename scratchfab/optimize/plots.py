"""PNG figures of a run: the loss curve and targets beside renders (Pillow only)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from scratchfab.figures import (
    OFF_BOARD_RGB,
    OKABE_ITO,
    TEXT_PX,
    LegendItem,
    draw_legend,
    enlarge,
    font,
    gray_rgb,
    legend_size,
    text_size,
)
from scratchfab.fileio import save_png
from scratchfab.metrics import exposure, pearson
from scratchfab.optimize.glint import GLINT_KEY, GLINT_RGB, ViewGlint, outline_glint

#: What the off-board colour means, printed under the side-by-side picture.
OFF_BOARD_CAPTION = "grey: off the board (not scratched, not scored)"
#: Side-by-side cells are enlarged (nearest neighbour) to at least this width.
MIN_CELL_PX = 160
#: Side-by-side cells of larger views are shrunk (block means) to at most this long side,
#: so that the picture stays about 1000 px wide and quick to write at any resolution
#: (two 2048 px views made a 4120 x 4208 px, 3.4 MB file in 4 s). The renders are kept
#: at full size in ``optimize/renders/``.
MAX_CELL_PX = 512
#: Loss curve colour.
LOSS_RGB = OKABE_ITO["blue"]
#: Per-view curve colours, in view order (repeating); not black, the frame's colour (the
#: loss curve's blue is in the other panel).
VIEW_RGB = [
    OKABE_ITO[k]
    for k in ("vermillion", "bluish_green", "orange", "reddish_purple", "sky_blue", "blue")
]
#: Length in pixels of one view's dash when the quality panel has several views. View k
#: of n draws the stretches k..n of each n-dash period over the solid first view, so that
#: where curves coincide every view still shows its own dash.
DASH_PX = 8.0
#: Gridline colour.
GRID_RGB = (215, 215, 215)
#: Plot frame colour.
AXIS_RGB = (0, 0, 0)

_WIDTH = 760
_LEFT = 78
_RIGHT = 24
_PANEL_H = 300
_TITLE_H = 2 * TEXT_PX + 20
_XLABEL_H = 2 * TEXT_PX + 14


def log_ticks(lo: float, hi: float) -> list[float]:
    """Round values between ``10**lo`` and ``10**hi`` for a log axis, ascending.

    Decades where the range holds at least three; else 1, 2 and 5 times a decade; else
    every integer multiple; else (a range narrower than that) round linear steps inside
    it, and at least its two ends. Over many decades every second (third, ...) decade.
    """
    first, last = math.floor(lo) - 1, math.ceil(hi) + 1
    for mults in ((1,), (1, 2, 5), tuple(range(1, 10))):
        ticks = [
            m * 10.0**e
            for e in range(first, last + 1)
            for m in mults
            if lo - 1e-9 <= e + math.log10(m) <= hi + 1e-9
        ]
        if len(ticks) >= (3 if mults == (1,) else 2):
            break
    else:
        ticks = [t for t in linear_ticks(10.0**lo, 10.0**hi, 4) if t > 0]
        if len(ticks) < 2:
            ticks = sorted({10.0**lo, 10.0**hi})
    step = max(1, math.ceil(len(ticks) / 8))
    return ticks[::step]


def linear_ticks(lo: float, hi: float, target: int = 6) -> list[float]:
    """About ``target`` round values (1, 2 or 5 times a power of ten apart) in [lo, hi]."""
    span = hi - lo
    if not span > 0:
        return [lo]
    raw = span / target
    base = 10.0 ** math.floor(math.log10(raw))
    step = next(m * base for m in (1, 2, 5, 10) if m * base >= raw)
    start = math.ceil(lo / step - 1e-9)
    return [k * step for k in range(start, math.floor(hi / step + 1e-9) + 1)]


#: Where the rho panel's axis may start: the highest of these below every view's lowest
#: rho (never on the frame's edge), so a run that stays near 1 is not drawn as a flat
#: line at the top.
RHO_AXIS_FLOORS = (0.0, 0.5, 0.8, 0.9)


def rho_axis_floor(views: Mapping[str, Sequence[float]]) -> float:
    """The bottom of the rho panel's axis (its top is 1) for these views' rho curves."""
    finite = [np.asarray(v, dtype=np.float64) for v in views.values()]
    lows = [float(r[np.isfinite(r)].min()) for r in finite if np.isfinite(r).any()]
    low = min(lows, default=0.0)
    return max((f for f in RHO_AXIS_FLOORS if f < low), default=0.0)


def _label(value: float) -> str:
    return f"{value:.3g}"


@dataclass(frozen=True)
class _Axes:
    """A plot box and the data range it shows (y on a log10 scale when ``log``)."""

    box: tuple[int, int, int, int]
    x_range: tuple[float, float]
    y_range: tuple[float, float]
    log: bool

    def px(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x0, y0, x1, y1 = self.box
        (a, b), (c, d) = self.x_range, self.y_range
        yy = np.log10(y) if self.log else y
        return x0 + (x - a) / (b - a) * (x1 - x0), y1 - (yy - c) / (d - c) * (y1 - y0)

    def frame(self, img: Image.Image, x_ticks: list[float], y_ticks: list[float]) -> None:
        draw = ImageDraw.Draw(img)
        x0, y0, x1, y1 = self.box
        f = font(TEXT_PX - 2)
        xs, _ = self.px(np.asarray(x_ticks, dtype=np.float64), np.ones(len(x_ticks)))
        for t, x in zip(x_ticks, xs.tolist(), strict=True):
            xi = round(x)
            draw.line([(xi, y0), (xi, y1)], fill=GRID_RGB)
            draw.line([(xi, y1), (xi, y1 + 4)], fill=AXIS_RGB)
            draw.text((xi, y1 + 6), f"{t:g}", fill=AXIS_RGB, font=f, anchor="mt")
        _, ys = self.px(np.zeros(len(y_ticks)), np.asarray(y_ticks, dtype=np.float64))
        for t, y in zip(y_ticks, ys.tolist(), strict=True):
            yi = round(y)
            draw.line([(x0, yi), (x1, yi)], fill=GRID_RGB)
            draw.line([(x0 - 4, yi), (x0, yi)], fill=AXIS_RGB)
            draw.text((x0 - 7, yi), _label(t), fill=AXIS_RGB, font=f, anchor="rm")
        draw.rectangle(self.box, outline=AXIS_RGB)

    def curve(
        self,
        img: Image.Image,
        x: np.ndarray,
        y: np.ndarray,
        color: tuple,
        dash: tuple[float, float, float] | None = None,
    ) -> None:
        """Draw ``y`` against ``x``; ``dash`` (start, stop, period): only those stretches.

        The stretches are measured in pixels along the drawn line, so two curves that
        coincide on screen share their dash phases whatever their data spacing.
        """
        px, py = self.px(x, y)
        draw = ImageDraw.Draw(img)
        points = np.stack([px, py], axis=1)
        if len(points) == 1:
            cx, cy = points[0].tolist()
            draw.ellipse((cx - 3, cy - 3, cx + 3, cy + 3), fill=color)
            return
        for piece in [points] if dash is None else dash_pieces(points, *dash):
            draw.line([tuple(p) for p in piece.tolist()], fill=color, width=2, joint="curve")


def dash_pieces(points: np.ndarray, start: float, stop: float, period: float) -> list[np.ndarray]:
    """The stretches of a polyline between arc lengths ``start`` and ``stop`` of each period.

    Args:
        points: (m, 2) vertices, m >= 2.
        start: Where each drawn stretch begins within the period (pixels along the line).
        stop: Where it ends (``start`` < ``stop`` <= ``period``).
        period: Length of one dash pattern.

    Returns:
        (k, 2) polylines, each with its cut ends interpolated on the line.
    """
    seg = np.hypot(*np.diff(points, axis=0).T)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    pieces = []
    for p in range(int(arc[-1] // period) + 1):
        a, b = p * period + start, min(p * period + stop, arc[-1])
        if b <= a:
            continue
        inside = (arc > a) & (arc < b)
        ends = [np.interp(t, arc, points[:, i]) for t in (a, b) for i in (0, 1)]
        pieces.append(np.vstack([ends[:2], points[inside], ends[2:]]))
    return pieces


_KEY_TITLE = "view: last rho"


def _emptiest_corner(
    img: Image.Image, box: tuple[int, int, int, int], items: list[LegendItem]
) -> tuple[int, int]:
    """Top-left pixel of the key in the corner of ``box`` that hides the fewest curve pixels."""
    w, h = legend_size(items, TEXT_PX - 1, _KEY_TITLE)
    x0, y0, x1, y1 = box
    rgb = np.asarray(img, dtype=np.int16)
    drawn = np.any(rgb != 255, axis=2) & np.any(rgb != GRID_RGB, axis=2)
    corners = [
        (x1 - w - 8, y1 - h - 8),
        (x0 + 8, y1 - h - 8),
        (x1 - w - 8, y0 + 8),
        (x0 + 8, y0 + 8),
    ]
    hidden = [int(drawn[y + 1 : y + h - 1, x + 1 : x + w - 1].sum()) for x, y in corners]
    return corners[int(np.argmin(hidden))]


def _titles(draw: ImageDraw.ImageDraw, top: int, title: str, subtitle: str) -> None:
    draw.text((_LEFT, top + 6), title, fill=AXIS_RGB, font=font(TEXT_PX + 2))
    draw.text((_LEFT, top + TEXT_PX + 12), subtitle, fill=(70, 70, 70), font=font(TEXT_PX - 1))


def _iteration_label(draw: ImageDraw.ImageDraw, box: tuple[int, int, int, int]) -> None:
    """The x axis' name, centred under a panel's tick labels."""
    draw.text(
        ((box[0] + box[2]) // 2, box[3] + TEXT_PX + 10),
        "iteration",
        fill=AXIS_RGB,
        font=font(),
        anchor="mt",
    )


def save_loss_plot(
    path: Path,
    iterations: Sequence[float],
    losses: Sequence[float],
    rho: Mapping[str, Sequence[float]] | None = None,
) -> None:
    """Loss against iteration on a log scale and, given ``rho``, each view's correlation.

    Args:
        path: The PNG to write.
        iterations: Iteration of each row of ``log.csv``.
        losses: Loss of each row (non-positive or NaN rows are left out of the curve).
        rho: Per view name, its target correlation rho_kk of each row (a second panel
            on a 0..1 axis with a key by view name).
    """
    views = dict(rho or {})
    height = _TITLE_H + _PANEL_H + _XLABEL_H
    if views:
        height += _TITLE_H + _PANEL_H + _XLABEL_H
    img = Image.new("RGB", (_WIDTH, height), "white")
    draw = ImageDraw.Draw(img)
    it = np.asarray(iterations, dtype=np.float64)
    loss = np.asarray(losses, dtype=np.float64)
    ok = np.isfinite(loss) & (loss > 0) & np.isfinite(it)
    box = (_LEFT, _TITLE_H, _WIDTH - _RIGHT, _TITLE_H + _PANEL_H)
    x_range = (float(it[ok].min()), float(it[ok].max())) if ok.any() else (0.0, 1.0)
    if x_range[1] - x_range[0] < 1:
        x_range = (x_range[0], x_range[0] + 1.0)
    x_ticks = linear_ticks(*x_range)
    if ok.any():
        lo, hi = math.log10(loss[ok].min()), math.log10(loss[ok].max())
        margin = 0.05 * max(hi - lo, 0.2)
        axes = _Axes(box, x_range, (lo - margin, hi + margin), log=True)
        axes.frame(img, x_ticks, log_ticks(lo - margin, hi + margin))
        axes.curve(img, it[ok], loss[ok], LOSS_RGB)
        first, last = np.flatnonzero(ok)[[0, -1]]
        subtitle = (
            f"lower is better: {_label(loss[first])} at iteration {it[first]:.0f}, "
            f"{_label(loss[last])} at iteration {it[last]:.0f}"
        )
    else:
        _Axes(box, x_range, (0.0, 1.0), log=False).frame(img, x_ticks, [])
        subtitle = "no finite loss was logged"
    _titles(draw, 0, "Optimization loss (log scale)", subtitle)
    _iteration_label(draw, box)
    if views:
        top = box[3] + _XLABEL_H
        box2 = (_LEFT, top + _TITLE_H, _WIDTH - _RIGHT, top + _TITLE_H + _PANEL_H)
        floor = rho_axis_floor(views)
        axes = _Axes(box2, x_range, (floor, 1.0), log=False)
        axes.frame(img, x_ticks, linear_ticks(floor, 1.0, 5))
        items = []
        for k, (name, values) in enumerate(views.items()):
            color = VIEW_RGB[k % len(VIEW_RGB)]
            r = np.asarray(values, dtype=np.float64)
            keep = np.isfinite(r) & np.isfinite(it)
            if keep.any():
                period = DASH_PX * len(views)
                dash = (k * DASH_PX, period, period) if k else None
                axes.curve(img, it[keep], np.clip(r[keep], floor, 1.0), color, dash)
                final = f"{r[keep][-1]:.3f}"
            else:
                final = "n/a"
            items.append(LegendItem(f"{name}: {final}", color, "line"))
        draw_legend(img, items, _emptiest_corner(img, box2, items), TEXT_PX - 1, _KEY_TITLE)
        _titles(
            draw,
            top,
            "How well each view shows its picture",
            "correlation rho of the render with the view's target: 1 = perfect, 0 = unrelated"
            + (f" (axis from {floor:g})" if floor > 0 else ""),
        )
        _iteration_label(draw, box2)
    save_png(path, img)


def shrink_factor(shape: tuple[int, ...]) -> int:
    """The block size that brings an (H, W) view's long side to at most :data:`MAX_CELL_PX`."""
    return max(1, math.ceil(max(shape[:2]) / MAX_CELL_PX))


def block_means(values: np.ndarray, factor: int) -> np.ndarray:
    """(H, W) linear values as the means of ``factor`` x ``factor`` blocks.

    Blocks at the right and bottom edges hold what lies in them. A block whose pixels are
    NaN (off the board) for half or more is NaN; the others average their finite pixels.
    """
    if factor == 1:
        return values
    finite = np.isfinite(values)
    total = _block_sums(np.where(finite, values, 0.0), factor)
    count = _block_sums(finite, factor)
    real = _block_sums(np.ones(values.shape), factor)  # pixels in each block: fewer at the edges
    return np.where(2 * count > real, total / np.maximum(count, 1), np.nan)


def _block_sums(values: np.ndarray, factor: int) -> np.ndarray:
    """Sums of ``factor`` x ``factor`` blocks of (H, W) ``values`` (zeros pad the edges)."""
    h, w = values.shape
    rows, cols = -(-h // factor), -(-w // factor)
    padded = np.pad(values, ((0, rows * factor - h), (0, cols * factor - w)))
    return padded.reshape(rows, factor, cols, factor).sum(axis=(1, 3), dtype=np.float64)


def _shrunk_glint(glint: ViewGlint | None, factor: int) -> ViewGlint | None:
    """``glint`` on the blocks of :func:`block_means`: a block glints where any pixel does."""
    if glint is None or factor == 1:
        return glint
    return replace(glint, mask=_block_sums(glint.mask, factor) > 0)


def save_side_by_side(
    path: Path,
    targets: Mapping[str, np.ndarray],
    renders: Mapping[str, np.ndarray],
    glints: Mapping[str, ViewGlint] | None = None,
) -> None:
    """One row per view: target | exposed render (both sRGB-encoded), labelled.

    Cells are enlarged by a whole factor (nearest neighbour) to at least ``MIN_CELL_PX``
    wide, and a view longer than ``MAX_CELL_PX`` is shrunk by a whole factor (block means
    of its linear values; its rho and exposure are the full view's), said in its title;
    pixels off the board show ``OFF_BOARD_RGB``, which a caption line explains.

    Args:
        path: The PNG to write.
        targets: Per view, its target (linear, NaN off the board).
        renders: Per view, its render.
        glints: Per view, where the bare board glints into it
            (:attr:`scratchfab.optimize.optimizer.LayoutOptimizer.glint`): outlined on both
            cells as verify's difference maps outline it, left out of the render's exposure
            as the image error leaves it out, and explained by a caption line.
    """
    glints = glints or {}
    rows = []
    for name, target in targets.items():
        render = renders[name]
        glint = glints.get(name)
        s = exposure(render, target if glint is None else glint.left_out(target))
        shown = np.where(np.isfinite(target), render, np.nan)
        rho = pearson(render, target)
        # As optimize's closing figures: rho counts the glint too, which the exposure leaves out.
        every = " over every pixel" if glint is not None and glint.mask.any() else ""
        k = shrink_factor(target.shape)
        scale = f", shown at 1/{k}" if k > 1 else ""
        title = f"{name}: target | render (rho {rho:.3f}{every}{scale})"
        rows.append(
            (title, block_means(target, k), block_means(shown, k), s, _shrunk_glint(glint, k))
        )
    if not rows:
        return
    cell_w = max(r[1].shape[1] for r in rows)
    cell_h = max(r[1].shape[0] for r in rows)
    # a narrow view is enlarged no longer than the cap
    factor = max(1, min(math.ceil(MIN_CELL_PX / cell_w), MAX_CELL_PX // cell_h))
    cell_w, cell_h = cell_w * factor, cell_h * factor
    gap, label = 8, TEXT_PX + 10
    glinting = any(g is not None and g.mask.any() for *_, g in rows)
    caption = [
        OFF_BOARD_CAPTION,
        "render scaled to best match its target's brightness"
        + (" outside the glint" if glinting else ""),
    ]
    if glinting:
        caption.insert(1, f"outlined: {GLINT_KEY} (left out of the image error)")
    width = max(
        2 * cell_w + 3 * gap,
        330,
        *(text_size(c, TEXT_PX - 2)[0] + 40 for c in caption),
        *(text_size(r[0])[0] + 2 * gap for r in rows),
    )
    height = len(rows) * (cell_h + label + gap) + len(caption) * (TEXT_PX + 4) + gap
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    y = gap // 2
    for text, t, r, s, glint in rows:
        draw.text((gap, y + 3), text, fill=AXIS_RGB, font=font())
        for x, cell in ((gap, gray_rgb(t)), (2 * gap + cell_w, gray_rgb(r, s))):
            big = enlarge(cell, factor)
            outline_glint(big, glint, factor)
            img.paste(Image.fromarray(big), (x, y + label))
        y += cell_h + label + gap
    swatch = TEXT_PX - 3
    for k, line in enumerate(caption):
        x = gap
        if k == 0:
            draw.rectangle(
                (x, y + 2, x + swatch, y + 2 + swatch), fill=OFF_BOARD_RGB, outline=AXIS_RGB
            )
        elif line.startswith("outlined"):
            draw.rectangle((x, y + 2, x + swatch, y + 2 + swatch), outline=GLINT_RGB, width=2)
        if k == 0 or line.startswith("outlined"):
            x += swatch + 6
        draw.text((x, y), line, fill=(60, 60, 60), font=font(TEXT_PX - 2))
        y += TEXT_PX + 4
    save_png(path, img)
