"""The ``render`` output layout (SPEC section 5): ``<view>.npy`` and ``<view>.png`` per view.

Also where ``render JOB`` finds its inputs in a job folder (SPEC section 6).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin

from scratchfab.errors import ConfigError
from scratchfab.fileio import load_numpy, save_npy, write_bytes
from scratchfab.render.tonemap import tone_map

#: PNG text key holding the tone map's exposure.
EXPOSURE_KEY = "scratchfab.exposure"


def png_bytes(image: np.ndarray, exposure_value: float | None = None) -> bytes:
    """The preview PNG of a linear image (see :mod:`scratchfab.render.tonemap`)."""
    grey, used = tone_map(image, exposure_value)
    info = PngImagePlugin.PngInfo()
    info.add_text(EXPOSURE_KEY, repr(used))
    buf = io.BytesIO()
    Image.fromarray(grey, mode="L").save(buf, format="PNG", pnginfo=info)
    return buf.getvalue()


def write_render_layout(
    out_dir: str | Path,
    images: dict[str, np.ndarray],
    exposure_value: float | None = None,
) -> list[Path]:
    """Write ``<name>.npy`` (float32 (H, W) linear radiance) and ``<name>.png`` per image.

    Every file is written atomically; all previews are encoded before the first write.

    Args:
        out_dir: The folder (created if missing).
        images: ``{view name: (H, W) linear radiance}``.
        exposure_value: A fixed exposure for every preview (default: per image).

    Returns:
        The paths written.
    """
    folder = Path(out_dir)
    arrays = {name: np.asarray(img, dtype=np.float32) for name, img in images.items()}
    for name, arr in arrays.items():
        if arr.ndim != 2:
            raise ValueError(f"image {name!r} must be 2-D (H, W), got shape {arr.shape}")
    previews = {name: png_bytes(arr, exposure_value) for name, arr in arrays.items()}
    written = []
    for name, arr in arrays.items():
        save_npy(folder / f"{name}.npy", arr)
        write_bytes(folder / f"{name}.png", previews[name])
        written += [folder / f"{name}.npy", folder / f"{name}.png"]
    return written


def read_render_layout(directory: str | Path) -> dict[str, np.ndarray]:
    """Read every ``<name>.npy`` of a render layout folder.

    Raises:
        ConfigError: When the folder is missing, holds no ``.npy`` image, or an image is
            not a 2-D float array.
    """
    folder = Path(directory)
    if not folder.is_dir():
        raise ConfigError(f"{folder}: render folder not found")
    images = {}
    for path in sorted(folder.glob("*.npy")):
        arr = load_numpy(path)
        if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.floating):
            raise ConfigError(f"{path}: expected a 2-D float image, got {arr.dtype} {arr.shape}")
        images[path.stem] = arr
    if not images:
        raise ConfigError(f"{folder}: no <view>.npy images in this folder")
    return images
