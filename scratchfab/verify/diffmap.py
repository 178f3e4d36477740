"""Difference maps: where the verified board is brighter or darker than its target.

The map shows ``s R - T`` (:func:`scratchfab.metrics.exposed_difference`): the error the
PSNR of SPEC section 7 squares, on the same board pixels and with the same exposure
``s``, so the picture and the metrics table tell one story. The colour scale is fixed at
``DIFF_SCALE`` of the target's linear range (targets run from 0, black, to 1, white),
so two views, or two runs, read alike.

Colours run from white (equal) to Okabe and Ito's blue (darker) or to their vermillion
darkened to the blue's lightness (brighter): under protanopia and deuteranopia the two
sides stay blue and yellow-brown, and at equal sizes they are equally light, their
lightness falling with the size of the difference, so the magnitude reads in grey too.
Pixels off the board are grey and hatched. Where the bare board glints into the view
(:mod:`scratchfab.optimize.glint`) the map outlines the region in the feasibility map's
glint colour and its title says so: there no scratch can show the image, and the glint's
light sets the exposure, so the rest of the board reads darker.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from scratchfab import figures
from scratchfab.fileio import save_png
from scratchfab.metrics import exposed_difference
from scratchfab.optimize.glint import GLINT_KEY, GLINT_RGB, ViewGlint, outline_glint

#: Half-width of the colour scale in the target's linear units: differences of this
#: size or more get the full colour.
DIFF_SCALE = 0.5
#: The exposed render is brighter than the target: vermillion (213, 94, 0) darkened to
#: the blue's CIE L* of 46.
BRIGHTER_RGB: figures.RGB = (190, 70, 0)
#: The exposed render is darker than the target.
DARKER_RGB: figures.RGB = figures.OKABE_ITO["blue"]
#: No difference.
EQUAL_RGB: figures.RGB = (255, 255, 255)
#: The hatch lines over pixels off the board (as in a ``hatch`` legend swatch).
HATCH_RGB: figures.RGB = figures.HATCH_RGB
#: The map is enlarged (nearest neighbour) to at least this width.
MAP_MIN_PX = 256
_BAR_H = 14


def diff_colours(diff: np.ndarray, scale: float = DIFF_SCALE) -> np.ndarray:
    """8-bit sRGB (H, W, 3) of a signed difference; NaN (off the board) shows grey.

    Args:
        diff: ``s R - T`` per pixel.
        scale: The difference that gets the full colour; larger ones are clipped to it.
    """
    if not scale > 0:
        raise ValueError(f"scale must be > 0, got {scale}")
    finite = np.isfinite(diff)
    t = np.clip(np.where(finite, diff, 0.0) / scale, -1.0, 1.0)[..., None]
    end = np.where(t > 0, np.array(BRIGHTER_RGB, float), np.array(DARKER_RGB, float))
    white = np.array(EQUAL_RGB, float)
    rgb = np.round(white + np.abs(t) * (end - white)).astype(np.uint8)
    rgb[~finite] = figures.OFF_BOARD_RGB
    return rgb


@dataclass(frozen=True)
class DiffFigure:
    """A drawn difference map and where its parts lie (pixel boxes, inclusive).

    Attributes:
        image: The picture.
        map_box: The map; image pixel (i, j) is the block of ``factor`` pixels from
            ``(map_box[0] + j * factor, map_box[1] + i * factor)``.
        factor: Enlargement of the map.
        bar_box: The colour bar, from ``-scale`` (left) to ``+scale`` (right).
        legend_box: The key.
        scale: The colour scale's half-width.
    """

    image: Image.Image
    map_box: figures.Box
    factor: int
    bar_box: figures.Box
    legend_box: figures.Box
    scale: float


def diff_figure(
    diff: np.ndarray,
    view: str,
    scale: float = DIFF_SCALE,
    glint: ViewGlint | None = None,
    note: str = "",
) -> DiffFigure:
    """Draw ``view``'s difference map with its title, colour bar and key.

    Args:
        diff: ``s R - T`` (H, W), NaN off the board.
        view: The view's name (for the title).
        scale: The colour scale's half-width in the target's linear units.
        glint: Where the bare board glints into the view, outlined (None or an empty
            mask: no glint).
        note: Last title lines, split at "; " (verify's: how much of the map is sampling
            noise), or "".
    """
    rows, cols = diff.shape
    factor = max(1, -(-MAP_MIN_PX // cols))
    mw, mh = cols * factor, rows * factor
    big = figures.enlarge(diff_colours(diff, scale), factor)
    figures.hatch_cells(big, figures.enlarge(~np.isfinite(diff), factor), HATCH_RGB)
    shown = outline_glint(big, glint, factor)

    size = figures.TEXT_PX
    m = 12
    items = [
        figures.LegendItem("brighter than the target", BRIGHTER_RGB),
        figures.LegendItem("darker than the target", DARKER_RGB),
        figures.LegendItem(
            "off the board: not compared", HATCH_RGB, "hatch", fill=figures.OFF_BOARD_RGB
        ),
    ]
    if shown is not None:
        items.append(figures.LegendItem(GLINT_KEY, GLINT_RGB, "outline"))
    note_text = (
        "the verify render, brightened or dimmed to match the target\n"
        "overall, minus the target, in the target's linear brightness\n"
        f"(0 black, 1 white); beyond ±{scale:g} clipped"
    )
    lw, lh = figures.legend_size(items, size)
    tick_h = figures.text_size("0", size)[1]
    note_w, note_h = figures.text_size(note_text, size)
    width = max(mw, lw, note_w)
    height = mh + 10 + _BAR_H + 6 + tick_h + 4 + tick_h + 10 + note_h + 10 + lh
    canvas = Image.new("RGB", (width + 2 * m, height + 2 * m), (255, 255, 255))
    canvas.paste(Image.fromarray(big), (m, m))
    draw = ImageDraw.Draw(canvas)
    draw.rectangle((m - 1, m - 1, m + mw, m + mh), outline=figures.FRAME)

    bx0, bx1 = m, m + mw - 1
    y = m + mh + 10
    span = bx1 - bx0
    values = (np.arange(span + 1) + 0.5) / (span + 1) * 2 * scale - scale
    strip = np.repeat(diff_colours(values[None], scale), _BAR_H, axis=0)
    canvas.paste(Image.fromarray(strip), (bx0, y))
    bar_box = (bx0, y, bx1, y + _BAR_H - 1)
    draw.rectangle((bx0 - 1, y - 1, bx1 + 1, y + _BAR_H), outline=figures.FRAME)
    y += _BAR_H + 1
    for frac in (-1.0, -0.5, 0.0, 0.5, 1.0):
        x = bx0 + int(round(span * (frac + 1) / 2))
        text = "0" if frac == 0 else f"{frac * scale:+g}"
        tw = figures.text_size(text, size)[0]
        tx = min(max(bx0, x - tw // 2), bx1 - tw)
        draw.line([(x, y), (x, y + 4)], fill=(0, 0, 0), width=1)
        draw.text((tx, y + 5), text, fill=(0, 0, 0), font=figures.font(size))
    y += 5 + tick_h + 4
    draw.text((bx0, y), "darker", fill=(0, 0, 0), font=figures.font(size))
    tw = figures.text_size("brighter", size)[0]
    draw.text((bx1 - tw, y), "brighter", fill=(0, 0, 0), font=figures.font(size))
    y += tick_h + 10
    draw.multiline_text((bx0, y), note_text, fill=(0, 0, 0), font=figures.font(size), spacing=3)
    y += note_h + 10
    legend_box = figures.draw_legend(canvas, items, (m, y), size)

    beyond = clipped_share(diff, scale)
    title = [
        f"view '{view}': verified board minus target",
        "the render scaled to the target's overall brightness (as PSNR takes it)",
        f"{100 * beyond:.0f} % of the board at ±{scale:g} or beyond"
        if math.isfinite(beyond)
        else "no board pixels",
    ]
    if shown is not None:
        title.append(
            f"the bare board glints on {100 * shown.board_share:.1f} % of the board (outlined)"
        )
    if note:
        title += note.split("; ")
    out = figures.add_title(canvas, title, size + 1, margin=m)
    dy = out.height - canvas.height

    def shift(b: figures.Box) -> figures.Box:
        return (b[0], b[1] + dy, b[2], b[3] + dy)

    return DiffFigure(
        out,
        shift((m, m, m + mw - 1, m + mh - 1)),
        factor,
        shift(bar_box),
        shift(legend_box),
        scale,
    )


def write_diff_map(
    path: str | Path,
    render: np.ndarray,
    target: np.ndarray,
    view: str,
    scale: float = DIFF_SCALE,
    glint: ViewGlint | None = None,
    note: str = "",
) -> DiffFigure:
    """Draw ``view``'s map of ``s R - T`` and save it (atomically) as the PNG ``path``.

    ``glint`` and ``note``: as :func:`diff_figure` takes them.
    """
    if render.shape != target.shape:
        raise ValueError(f"view {view}: render {render.shape} and target {target.shape} differ")
    diff, _ = exposed_difference(render, target)
    fig = diff_figure(diff, view, scale, glint, note)
    save_png(path, fig.image)
    return fig


def clipped_share(diff: np.ndarray, scale: float = DIFF_SCALE) -> float:
    """Share of the board pixels whose difference reaches the scale (drawn clipped)."""
    board = np.isfinite(diff)
    return float(np.mean(np.abs(diff[board]) >= scale)) if board.any() else math.nan
