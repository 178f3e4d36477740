"""Loading target images: any Pillow format to linear luminance in [0, 1].

EXIF orientation is honoured, colour becomes luminance (Rec. 709 weights on linear
channels), alpha is composited over black, and sRGB values are decoded with the exact
piecewise sRGB transfer function (IEC 61966-2-1).
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from scratchfab.errors import ConfigError
from scratchfab.fileio import read_input

#: Rec. 709 / sRGB luminance weights of linear R, G, B.
LUMA_709 = np.array([0.2126, 0.7152, 0.0722])


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """Exact sRGB EOTF: encoded values in [0, 1] to linear light."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_to_linear` (values clipped to [0, 1] first)."""
    v = np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * v ** (1 / 2.4) - 0.055)


def _open(path: Path) -> Image.Image:
    data = read_input(path, "an image file", missing="image file not found")
    if not data:
        raise ConfigError(f"{path}: empty file, expected an image")
    try:
        with warnings.catch_warnings():
            # Pillow warns of what it skips (a corrupt EXIF block, a tag past the end) and
            # of large images; the pixels decode or the file is refused below, in one line.
            warnings.simplefilter("ignore")
            image = Image.open(io.BytesIO(data))
            image.load()
            return ImageOps.exif_transpose(image)
    except UnidentifiedImageError:
        raise ConfigError(f"{path}: not an image file Pillow can read") from None
    except Image.DecompressionBombError:
        raise ConfigError(f"{path}: image is too large (decompression bomb check)") from None
    except (OSError, ValueError, SyntaxError, EOFError) as exc:
        raise ConfigError(f"{path}: corrupt or truncated image ({exc})") from None


#: Linear values of every 8-bit and 16-bit code (decoding by table is exact and fast).
_LUT8 = srgb_to_linear(np.arange(256) / 255.0)
_LUT16 = srgb_to_linear(np.arange(65536) / 65535.0)
#: Rows converted at a time, so that large photos do not need several float copies.
_CHUNK_ROWS = 256


def _high_bit_gray(image: Image.Image, file: Path) -> np.ndarray | None:
    """Linear gray values of 16-bit / 32-bit integer and float images, else None."""
    if image.mode.startswith("I;16"):
        return _LUT16[np.asarray(image).astype(np.uint16)]
    if image.mode == "I":
        arr = np.asarray(image, dtype=np.int64)
        # Pillow opens 16-bit grayscale PNGs as "I" in some versions; their range is 16-bit.
        if arr.min(initial=0) >= 0 and arr.max(initial=0) <= 65535:
            return _LUT16[arr]
        return srgb_to_linear(np.clip(arr / float(max(arr.max(), 1)), 0.0, 1.0))
    if image.mode == "F":
        values = np.asarray(image, dtype=np.float64)
        bad = np.argwhere(~np.isfinite(values))
        if len(bad):
            row, col = (int(v) for v in bad[0])
            raise ConfigError(
                f"{file}: pixel (row {row}, column {col}) is "
                f"{values[row, col]}; expected finite brightness values ({len(bad)} pixels "
                "are NaN or infinite)"
            )
        return srgb_to_linear(np.clip(values, 0.0, 1.0))
    return None


def load_image(path: str | Path) -> np.ndarray:
    """Read an image file as linear luminance.

    Args:
        path: Any format Pillow reads (PNG incl. 16-bit and palette, JPEG incl. CMYK,
            TIFF, WebP, ...).

    Returns:
        (h, w) float64 array in [0, 1], row 0 at the top of the (upright) picture.

    Raises:
        ConfigError: One line naming the file when it is missing, unreadable or corrupt.
    """
    file = Path(path)
    image = _open(file)
    lin = _high_bit_gray(image, file)
    if lin is None:
        has_alpha = image.mode in ("RGBA", "LA", "PA", "RGBa", "La") or (
            "transparency" in image.info
        )
        try:
            rgba = np.asarray(image.convert("RGBA" if has_alpha else "RGB"))
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{file}: cannot convert {image.mode} image to RGB ({exc})") from None
        lin = np.empty(rgba.shape[:2])
        for r0 in range(0, rgba.shape[0], _CHUNK_ROWS):
            block = rgba[r0 : r0 + _CHUNK_ROWS]
            lum = _LUT8[block[..., :3]] @ LUMA_709
            if has_alpha:
                lum *= block[..., 3] / 255.0
            lin[r0 : r0 + _CHUNK_ROWS] = lum
    if lin.ndim != 2 or lin.size == 0:
        raise ConfigError(f"{file}: image has no pixels")
    return np.clip(lin, 0.0, 1.0)
