"""Draw the two bundled demo targets with Pillow (no downloads): ``sun.png`` and ``house.png``.

Run ``python scratchfab/data/demo/make_demo_images.py`` to regenerate them; the output is
deterministic (fixed seed, shapes drawn at 4x and box-filtered down for smooth edges).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

SIZE = 256
SUPER = 4
SEED = 20231121


def _canvas() -> tuple[Image.Image, ImageDraw.ImageDraw]:
    image = Image.new("L", (SIZE * SUPER, SIZE * SUPER), 0)
    return image, ImageDraw.Draw(image)


def _finish(image: Image.Image) -> Image.Image:
    return image.resize((SIZE, SIZE), Image.Resampling.BOX)


def sun(rng: np.random.Generator) -> Image.Image:
    """A bright disc with twelve rays and a few stars."""
    image, draw = _canvas()
    c = SIZE * SUPER / 2
    r = 0.22 * SIZE * SUPER
    draw.ellipse((c - r, c - r, c + r, c + r), fill=255)
    for k in range(12):
        a = 2 * math.pi * k / 12
        w = 0.09
        inner, outer = 1.35 * r, 2.05 * r
        pts = [
            (c + inner * math.cos(a - w), c + inner * math.sin(a - w)),
            (c + outer * math.cos(a), c + outer * math.sin(a)),
            (c + inner * math.cos(a + w), c + inner * math.sin(a + w)),
        ]
        draw.polygon(pts, fill=255)
    for _ in range(6):
        x, y = rng.uniform(0.06, 0.94, 2) * SIZE * SUPER
        if math.hypot(x - c, y - c) < 2.15 * r:
            continue
        s = 0.025 * SIZE * SUPER
        draw.ellipse((x - s, y - s, x + s, y + s), fill=200)
    return _finish(image)


def house(rng: np.random.Generator) -> Image.Image:
    """A house with a roof, a door and a window, on a ground bar."""
    image, draw = _canvas()
    u = SIZE * SUPER / 16
    draw.polygon([(2 * u, 7.5 * u), (8 * u, 2 * u), (14 * u, 7.5 * u)], fill=255)
    draw.rectangle((3.5 * u, 7.5 * u, 12.5 * u, 13.5 * u), fill=230)
    draw.rectangle((7 * u, 9.5 * u, 9 * u, 13.5 * u), fill=0)
    draw.rectangle((4.5 * u, 8.5 * u, 6.2 * u, 10.2 * u), fill=0)
    draw.rectangle((9.8 * u, 8.5 * u, 11.5 * u, 10.2 * u), fill=0)
    draw.rectangle((0.5 * u, 13.5 * u, 15.5 * u, 14.5 * u), fill=160)
    level = int(rng.integers(150, 200))
    draw.rectangle((10.5 * u, 3 * u, 11.7 * u, 5.6 * u), fill=level)
    return _finish(image)


def moon() -> Image.Image:
    """A crescent moon with three dots (the third view of the full-size example)."""
    image, draw = _canvas()
    u = SIZE * SUPER / 16
    draw.ellipse((3 * u, 3 * u, 13 * u, 13 * u), fill=255)
    draw.ellipse((5.5 * u, 1.8 * u, 15.5 * u, 11.8 * u), fill=0)
    for x, y in ((12.5, 12.0), (13.8, 9.5), (11.0, 14.0)):
        draw.ellipse(((x - 0.45) * u, (y - 0.45) * u, (x + 0.45) * u, (y + 0.45) * u), fill=220)
    return _finish(image)


def main() -> None:
    """Write the images beside this script."""
    here = Path(__file__).resolve().parent
    rng = np.random.default_rng(SEED)
    sun(rng).save(here / "sun.png")
    house(rng).save(here / "house.png")
    moon().save(here / "moon.png")


if __name__ == "__main__":
    main()
