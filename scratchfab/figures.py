"""Drawing helpers shared by the PNG pictures: text, keys, scale bars, padding, CVD checks.

Every picture a stage writes should explain itself: a title line, a key for its colours,
a scale where lengths matter, and room around the border so nothing drawn on it is cut.
The helpers draw with Pillow's bundled font (no system font needed) and return the
boxes they drew, so tests can find them by their pixels.

The palette is Okabe and Ito's, chosen to stay apart under the common colour-vision
deficiencies; :func:`simulate_cvd` and :func:`lightness` let a test check that.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from scratchfab.design.images import LUMA_709, linear_to_srgb, srgb_to_linear

RGB = tuple[int, int, int]
Box = tuple[int, int, int, int]
Corner = Literal["top-left", "top-right", "bottom-left", "bottom-right"]

#: Okabe-Ito colours (told apart under protanopia and deuteranopia).
OKABE_ITO: dict[str, RGB] = {
    "black": (0, 0, 0),
    "orange": (230, 159, 0),
    "sky_blue": (86, 180, 233),
    "bluish_green": (0, 158, 115),
    "yellow": (240, 228, 66),
    "blue": (0, 114, 178),
    "vermillion": (213, 94, 0),
    "reddish_purple": (204, 121, 167),
}
#: Default text size in pixels: readable at 100 % zoom.
TEXT_PX = 15
#: Frame and key border colour.
FRAME: RGB = (90, 90, 90)
#: Pixels off the board (a target's NaN) in grey previews.
OFF_BOARD_RGB: RGB = (128, 128, 128)
#: Hatch lines: cells a map marks as not usable (unreachable, off the board) and their keys.
HATCH_RGB: RGB = (40, 40, 40)

LegendKind = Literal["line", "box", "ring", "hatch", "dots", "arrow", "outline"]


@dataclass(frozen=True)
class LegendItem:
    """One row of a key: a swatch drawn as ``kind`` in ``color``, then ``label``.

    Attributes:
        label: The text.
        color: Swatch colour.
        kind: ``line`` (a stroke), ``box`` (filled square), ``ring`` (circle outline),
            ``hatch`` (square in ``color`` with dark diagonal lines), ``dots`` (white square with
            dots), ``arrow`` or ``outline`` (square framed in ``color``, as
            :func:`outline_cells` marks a region).
        fill: Background of ``hatch``/``dots``/``outline`` swatches (default: ``color`` /
            white / white).
    """

    label: str
    color: RGB
    kind: LegendKind = "box"
    fill: RGB | None = None


@lru_cache(maxsize=16)
def font(size: int = TEXT_PX) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """Pillow's bundled sans font at ``size`` pixels (cached)."""
    return ImageFont.load_default(size=size)


def text_size(text: str, size: int = TEXT_PX) -> tuple[int, int]:
    """Width and height in pixels of ``text`` (one or more lines) at ``size``."""
    draw = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    x0, y0, x1, y1 = draw.multiline_textbbox((0, 0), text, font=font(size), spacing=3)
    return int(x1 - min(x0, 0)), int(y1 - min(y0, 0))


def pad(
    img: Image.Image,
    px: int | tuple[int, int, int, int],
    fill: RGB = (255, 255, 255),
) -> Image.Image:
    """A copy of ``img`` with a border of ``px`` (or left, top, right, bottom) pixels."""
    left, top, right, bottom = (px, px, px, px) if isinstance(px, int) else px
    out = Image.new("RGB", (img.width + left + right, img.height + top + bottom), fill)
    out.paste(img.convert("RGB"), (left, top))
    return out


def add_title(
    img: Image.Image, lines: list[str] | str, size: int = TEXT_PX + 1, margin: int = 8
) -> Image.Image:
    """A copy of ``img`` with a band of text above it (first line bold-ish by size)."""
    text = lines if isinstance(lines, str) else "\n".join(lines)
    w, h = text_size(text, size)
    band = h + 2 * margin
    out = pad(img, (0, band, max(0, w + 2 * margin - img.width), 0))
    ImageDraw.Draw(out).multiline_text(
        (margin, margin), text, fill=(0, 0, 0), font=font(size), spacing=3
    )
    return out


def _swatch(draw: ImageDraw.ImageDraw, box: Box, item: LegendItem) -> None:
    x0, y0, x1, y1 = box
    cy = (y0 + y1) // 2
    if item.kind == "line":
        draw.line([(x0, cy), (x1, cy)], fill=item.color, width=3)
    elif item.kind == "arrow":
        draw_arrow(draw, (x0, cy), (x1, cy), item.color, width=2, head=6)
    elif item.kind == "ring":
        r = (y1 - y0) // 2
        cx = (x0 + x1) // 2
        draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=item.color, width=2)
    elif item.kind == "hatch":
        draw.rectangle(box, fill=item.fill or item.color)
        hatch(draw, box, HATCH_RGB, step=5)
        draw.rectangle(box, outline=FRAME)
    elif item.kind == "outline":
        draw.rectangle(box, fill=item.fill or (255, 255, 255), outline=item.color, width=2)
    elif item.kind == "dots":
        draw.rectangle(box, fill=item.fill or (255, 255, 255))
        for y in range(y0 + 2, y1, 4):
            for x in range(x0 + 2, x1, 4):
                draw.point((x, y), fill=item.color)
        draw.rectangle(box, outline=FRAME)
    else:
        draw.rectangle(box, fill=item.color, outline=FRAME)


def hatch(draw: ImageDraw.ImageDraw, box: Box, color: RGB, step: int = 6) -> None:
    """Diagonal lines (upper-left to lower-right) across ``box``, ``step`` px apart."""
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    for k in range(0, w + h, step):
        # The line x - x0 + (y1 - y) = k, clipped to the box.
        a = (x0 + max(0, k - h), y1 - min(k, h))
        b = (x0 + min(k, w), y1 - max(0, k - w))
        draw.line([a, b], fill=color, width=1)


def hatch_cells(rgb: np.ndarray, mask: np.ndarray, color: RGB = HATCH_RGB, step: int = 6) -> None:
    """Draw :func:`hatch` lines over the pixels of ``rgb`` (H, W, 3) where ``mask`` holds, in place.

    The lines run across the whole picture, so neighbouring marked cells join up.
    """
    if not mask.any():
        return
    h, w = mask.shape
    lines = Image.new("RGB", (w, h), (255, 255, 255))
    hatch(ImageDraw.Draw(lines), (0, 0, w - 1, h - 1), color, step)
    rgb[mask & np.all(np.asarray(lines) == color, axis=-1)] = color


def outline_cells(rgb: np.ndarray, mask: np.ndarray, color: RGB, width: int = 2) -> None:
    """Draw the inner edge of the region ``mask`` in ``rgb`` (H, W, 3), ``width`` px wide.

    A pixel of the region is on its edge when one within ``width`` steps (up, down, left,
    right) lies outside it or off the picture.
    """
    inner = mask.astype(bool)
    for _ in range(width):
        padded = np.pad(inner, 1, constant_values=False)
        inner = inner & padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:]
    rgb[mask & ~inner] = color


def legend_size(items: list[LegendItem], size: int = TEXT_PX, title: str = "") -> tuple[int, int]:
    """Width and height in pixels of the key :func:`draw_legend` would draw."""
    row = max(size + 6, 16)
    sw = 2 * row
    widths = [text_size(it.label, size)[0] for it in items]
    width = sw + 8 + max(widths, default=0) + 16
    height = len(items) * row + 12
    if title:
        tw, th = text_size(title, size)
        width = max(width, tw + 16)
        height += th + 4
    return width, height


def draw_legend(
    img: Image.Image,
    items: list[LegendItem],
    corner: Corner | tuple[int, int] = "top-right",
    size: int = TEXT_PX,
    title: str = "",
    margin: int = 6,
) -> Box:
    """Draw a framed key on ``img`` in place.

    Args:
        img: The picture (RGB).
        items: The rows, top to bottom.
        corner: Where: a corner of ``img`` (``margin`` px in) or the key's top-left pixel.
        size: Text size in pixels.
        title: An optional heading line.
        margin: Distance from the image border for a named corner.

    Returns:
        The key's box (x0, y0, x1, y1), inclusive.
    """
    w, h = legend_size(items, size, title)
    if isinstance(corner, tuple):
        x0, y0 = corner
    else:
        x0 = margin if corner.endswith("left") else img.width - w - margin
        y0 = margin if corner.startswith("top") else img.height - h - margin
    draw = ImageDraw.Draw(img)
    box = (x0, y0, x0 + w - 1, y0 + h - 1)
    draw.rectangle(box, fill=(255, 255, 255), outline=FRAME)
    row = max(size + 6, 16)
    y = y0 + 6
    if title:
        draw.text((x0 + 8, y), title, fill=(0, 0, 0), font=font(size))
        y += text_size(title, size)[1] + 4
    for it in items:
        sbox = (x0 + 8, y + 3, x0 + 8 + 2 * row - 8, y + row - 3)
        _swatch(draw, sbox, it)
        draw.text(
            (sbox[2] + 8, y + (row - size) // 2 - 1), it.label, fill=(0, 0, 0), font=font(size)
        )
        y += row
    return box


def nice_length(limit: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above ``limit`` (> 0)."""
    if not limit > 0:
        raise ValueError(f"nice_length needs a positive limit, got {limit}")
    p = 10.0 ** np.floor(np.log10(limit))
    for m in (5.0, 2.0, 1.0):
        if m * p <= limit * (1 + 1e-12):
            return float(m * p)
    return float(p)


def draw_scale_bar(
    img: Image.Image,
    px_per_unit: float,
    xy: tuple[int, int],
    max_px: int = 160,
    unit: str = "mm",
    size: int = TEXT_PX,
) -> tuple[float, Box]:
    """Draw a scale bar of a round length whose left end sits at ``xy`` (its baseline).

    Returns:
        The bar's length in ``unit`` and its box in pixels (the bar itself, no label).
    """
    length = nice_length(max_px / px_per_unit)
    n = int(round(length * px_per_unit))
    x, y = xy
    draw = ImageDraw.Draw(img)
    box = (x, y - 3, x + n, y + 3)
    draw.rectangle((x, y - 1, x + n, y + 1), fill=(0, 0, 0))
    draw.line([(x, y - 5), (x, y + 5)], fill=(0, 0, 0), width=2)
    draw.line([(x + n, y - 5), (x + n, y + 5)], fill=(0, 0, 0), width=2)
    label = f"{length:g} {unit}"
    draw.text((x + n + 8, y - size // 2 - 2), label, fill=(0, 0, 0), font=font(size))
    return length, box


def draw_arrow(
    draw: ImageDraw.ImageDraw,
    a: tuple[float, float],
    b: tuple[float, float],
    color: RGB,
    width: int = 2,
    head: float = 9.0,
) -> None:
    """A line from ``a`` to ``b`` with a filled head at ``b``."""
    ax, ay = a
    bx, by = b
    d = np.array([bx - ax, by - ay], dtype=float)
    n = float(np.hypot(*d))
    draw.line([(ax, ay), (bx, by)], fill=color, width=width)
    if n < 1e-9:
        return
    u = d / n
    v = np.array([-u[1], u[0]])
    base = np.array([bx, by]) - head * u
    p1, p2 = base + 0.5 * head * v, base - 0.5 * head * v
    draw.polygon([(bx, by), (float(p1[0]), float(p1[1])), (float(p2[0]), float(p2[1]))], fill=color)


# Machado, Oliveira and Fernandes (2009), severity 1.0, acting on linear RGB.
_CVD = {
    "protanopia": np.array(
        [
            [0.152286, 1.052583, -0.204868],
            [0.114503, 0.786281, 0.099216],
            [-0.003882, -0.048116, 1.051998],
        ]
    ),
    "deuteranopia": np.array(
        [
            [0.367322, 0.860646, -0.227968],
            [0.280085, 0.672501, 0.047413],
            [-0.011820, 0.042940, 0.968881],
        ]
    ),
}


def gray_rgb(values: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """8-bit sRGB grey (H, W, 3) of linear ``values * scale``; NaN shows ``OFF_BOARD_RGB``."""
    finite = np.isfinite(values)
    enc = linear_to_srgb(np.where(finite, values * scale, 0.0))
    rgb = np.repeat(np.round(enc * 255).astype(np.uint8)[..., None], 3, axis=2)
    rgb[~finite] = OFF_BOARD_RGB
    return rgb


def simulate_cvd(rgb: np.ndarray, kind: str = "deuteranopia") -> np.ndarray:
    """How a dichromat sees 8-bit sRGB colours (..., 3): the simulated sRGB in [0, 1].

    Args:
        rgb: Colours as 0-255 values.
        kind: ``protanopia`` or ``deuteranopia``.
    """
    lin = srgb_to_linear(np.asarray(rgb, dtype=np.float64) / 255.0)
    return linear_to_srgb(lin @ _CVD[kind].T)


def lightness(rgb01: np.ndarray) -> np.ndarray:
    """CIE L* (0-100) of sRGB colours in [0, 1] (..., 3)."""
    y = srgb_to_linear(rgb01) @ LUMA_709
    return np.where(y > (6 / 29) ** 3, 116 * np.cbrt(y) - 16, y * (29 / 3) ** 3)


def enlarge(pixels: np.ndarray, factor: int) -> np.ndarray:
    """Each pixel of an (H, W[, C]) array as a ``factor`` x ``factor`` block (nearest neighbour)."""
    return np.repeat(np.repeat(pixels, factor, axis=0), factor, axis=1)
