"""Target images in board space and as each camera sees them (SPEC sections 5 to 7).

A target is a picture painted on the board: its top edge along +y, its left edge along
-x. :func:`board_image` fits a file to the board's aspect; :func:`warp_to_view` shows
that painted board through a view's camera, area-averaging each pixel's footprint.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image

from scratchfab.design.images import invert_picture, linear_to_srgb, load_image, srgb_to_linear
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.figures import gray_rgb
from scratchfab.model.camera import Camera
from scratchfab.model.design import Board, Design, View

Fit = Literal["contain", "cover"]
FITS: tuple[str, ...] = ("contain", "cover")

#: Board-space images get at least / at most this many pixels along their long side.
MIN_SIDE = 256
MAX_SIDE = 2048
#: Supersampling per pixel axis in :func:`warp_to_view` is kept within these bounds.
MIN_SUPERSAMPLE = 5
MAX_SUPERSAMPLE = 16


def board_grid_shape(native: tuple[int, int], board: Board, fit: str) -> tuple[int, int]:
    """Rows and columns of the board-space image for a picture of native (h, w) pixels."""
    h, w = native
    aspect = board.width_mm / board.height_mm
    wider = w / h > aspect
    if (fit == "contain") == wider:
        cols = float(w)
        rows = w / aspect
    else:
        rows = float(h)
        cols = h * aspect
    long_side = max(rows, cols)
    scale = min(max(long_side, MIN_SIDE), MAX_SIDE) / long_side
    return max(1, round(rows * scale)), max(1, round(cols * scale))


def _resize(
    img: np.ndarray, size: tuple[int, int], box: tuple[float, float, float, float] | None
) -> np.ndarray:
    """Resample a float image to (rows, cols): area average when shrinking, bilinear when growing."""
    rows, cols = size
    src = Image.fromarray(img.astype(np.float32))
    bw = img.shape[1] if box is None else box[2] - box[0]
    shrink = cols < bw
    if box is None and (rows, cols) == img.shape:
        return img
    out = src.resize(
        (cols, rows),
        resample=Image.Resampling.BOX if shrink else Image.Resampling.BILINEAR,
        box=box,
    )
    return np.asarray(out, dtype=np.float64)


def adjust(image: np.ndarray, gamma: float = 1.0, contrast: float = 1.0) -> np.ndarray:
    """Tone adjustments on linear values: ``v**gamma``, then contrast about the mean, clipped."""
    if gamma <= 0 or not math.isfinite(gamma):
        raise ConfigError(f"gamma must be a positive number, got {gamma}")
    if contrast < 0 or not math.isfinite(contrast):
        raise ConfigError(f"contrast must be a non-negative number, got {contrast}")
    out = image
    if gamma != 1.0:
        out = out**gamma
    if contrast != 1.0:
        mean = float(out.mean())
        out = np.clip(mean + contrast * (out - mean), 0.0, 1.0)
    return out


def fit_to_board(picture: np.ndarray, board: Board, fit: str = "contain") -> np.ndarray:
    """Place a linear picture (h, w) on the board: ``contain`` pads with black, ``cover`` crops.

    The picture is linear luminance in [0, 1] (0 black, 1 white), row 0 at its top, as
    :func:`scratchfab.design.images.load_image` reads a file; an 8-bit sRGB array ``a``
    becomes one by ``srgb_to_linear(a / 255)``.

    Returns:
        (rows, cols) float64 board-space image; row 0 lies along the board's top edge
        (+y), column 0 along its left edge (-x).

    Raises:
        ConfigError: ``fit`` is neither ``contain`` nor ``cover``.
        ValueError: ``picture`` is not 2-D, or holds values outside [0, 1] (an 8-bit
            or sRGB-encoded array passed as it is).
    """
    if np.ndim(picture) != 2:
        raise ValueError(
            f"picture: expected (h, w) linear luminance, got shape {np.shape(picture)}"
        )
    values = np.asarray(picture, dtype=np.float64)
    if values.size and not (np.all(np.isfinite(values)) and 0 <= values.min() <= values.max() <= 1):
        raise ValueError(
            f"picture: expected linear luminance in [0, 1], got values from {values.min():g} "
            f"to {values.max():g} (8-bit sRGB a: srgb_to_linear(a / 255))"
        )
    picture = values
    if fit not in FITS:
        raise ConfigError(f"fit must be one of {', '.join(FITS)}, got {fit!r}")
    h, w = picture.shape
    rows, cols = board_grid_shape((h, w), board, fit)
    aspect = board.width_mm / board.height_mm
    if fit == "cover":
        if w / h > aspect:
            cw = h * aspect
            box = ((w - cw) / 2, 0.0, (w + cw) / 2, float(h))
        else:
            ch = w / aspect
            box = (0.0, (h - ch) / 2, float(w), (h + ch) / 2)
        if box == (0.0, 0.0, float(w), float(h)):
            return _resize(picture, (rows, cols), None)
        return _resize(picture, (rows, cols), box)
    if w / h > aspect:
        fw, fh = cols, max(1, min(rows, round(cols * h / w)))
    else:
        fw, fh = max(1, min(cols, round(rows * w / h))), rows
    canvas = np.zeros((rows, cols))
    r0, c0 = (rows - fh) // 2, (cols - fw) // 2
    canvas[r0 : r0 + fh, c0 : c0 + fw] = _resize(picture, (fh, fw), None)
    return canvas


def picture_area(shape: tuple[int, int], board: Board, fits: Iterable[str]) -> np.ndarray:
    """Where a picture of ``shape`` (h, w) lies on the board once fitted by each of ``fits``.

    The picture's own part of the board, without the black bars ``contain`` adds: a
    picture of ones through the same :func:`fit_to_board` steps.

    Returns:
        (rows, cols) bool on the board-space grid of the last step, True on the picture.
    """
    area = np.ones(shape)
    for fit in fits:
        area = fit_to_board(area, board, fit)
    return area > 0.5


def board_image(
    path: str | Path,
    board: Board,
    fit: str = "contain",
    gamma: float = 1.0,
    contrast: float = 1.0,
    invert: bool = False,
) -> np.ndarray:
    """The target file as a linear board-space image.

    Args:
        path: Image file (any format Pillow reads).
        board: The board whose aspect the picture is fitted to.
        fit: ``"contain"`` (whole picture visible, black bars) or ``"cover"`` (board
            filled, picture cropped).
        gamma: Exponent applied to linear values.
        contrast: Scale of the deviation from the picture's mean (1 = unchanged).
        invert: Invert the picture's colours first (:func:`invert_picture`); a
            transparent ground stays black (``load_image(path, invert)``).

    Returns:
        (rows, cols) float64 in [0, 1]; top edge +y, left edge -x (SPEC section 5).
    """
    return fit_picture(load_image(path, invert), board, fit, gamma, contrast)


def fit_picture(
    picture: np.ndarray,
    board: Board,
    fit: str,
    gamma: float = 1.0,
    contrast: float = 1.0,
    invert: bool = False,
) -> np.ndarray:
    """A linear picture inverted if asked, toned and placed on the board.

    :func:`invert_picture` first (as an image editor would), then :func:`adjust`, then
    :func:`fit_to_board`, whose bars stay black. The picture is opaque here: a file with
    transparency is inverted as it is read (``load_image(path, invert=True)``), which
    keeps its transparent ground black.
    """
    picture = invert_picture(picture) if invert else picture
    return fit_to_board(adjust(picture, gamma, contrast), board, fit)


def quantize_like_png(board_img: np.ndarray) -> np.ndarray:
    """The values a 16-bit sRGB-encoded PNG of ``board_img`` reads back as."""
    return srgb_to_linear(encode_16bit(board_img) / 65535.0)


def encode_16bit(board_img: np.ndarray) -> np.ndarray:
    """sRGB-encode linear values as uint16 codes."""
    return np.round(linear_to_srgb(board_img) * 65535.0).astype(np.uint16)


def board_image_png(board_img: np.ndarray) -> Image.Image:
    """A 16-bit grayscale, sRGB-encoded Pillow image of a linear board-space image."""
    return Image.fromarray(encode_16bit(board_img))


def preview_png(values: np.ndarray) -> Image.Image:
    """An 8-bit sRGB preview of linear values in [0, 1]; NaN (off the board) shows grey."""
    return Image.fromarray(gray_rgb(values))


def bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` at pixel-centre coordinates (u right, v down), clamped."""
    rows, cols = img.shape
    u = np.clip(u, 0.0, cols - 1)
    v = np.clip(v, 0.0, rows - 1)
    u0 = np.minimum(np.floor(u).astype(np.intp), max(cols - 2, 0))
    v0 = np.minimum(np.floor(v).astype(np.intp), max(rows - 2, 0))
    u1 = np.minimum(u0 + 1, cols - 1)
    v1 = np.minimum(v0 + 1, rows - 1)
    fu = u - u0
    fv = v - v0
    return (
        img[v0, u0] * (1 - fu) * (1 - fv)
        + img[v0, u1] * fu * (1 - fv)
        + img[v1, u0] * (1 - fu) * fv
        + img[v1, u1] * fu * fv
    )


def sample_board(board_img: np.ndarray, board: Board, points: np.ndarray) -> np.ndarray:
    """Bilinear samples of a board-space image at board points (..., 2); 0 off the board."""
    rows, cols = board_img.shape
    hw, hh = board.half_extent
    x = points[..., 0]
    y = points[..., 1]
    on = (np.abs(x) <= hw) & (np.abs(y) <= hh)
    u = (x + hw) / board.width_mm * cols - 0.5
    v = (hh - y) / board.height_mm * rows - 0.5
    return np.where(on, bilinear(board_img, u, v), 0.0)


def supersample_rate(board_img: np.ndarray, board: Board, camera: Camera) -> int:
    """Samples per pixel axis so that sample spacing is about half a board texel or finer."""
    quads, valid = camera.footprints()
    if not valid.any():
        return MIN_SUPERSAMPLE
    q = quads[valid]
    edges = np.linalg.norm(q - np.roll(q, -1, axis=1), axis=2).max()
    texel = min(board.width_mm / board_img.shape[1], board.height_mm / board_img.shape[0])
    return int(np.clip(math.ceil(2 * edges / texel), MIN_SUPERSAMPLE, MAX_SUPERSAMPLE))


def warp_to_view(board_img: np.ndarray, board: Board, view: View) -> np.ndarray:
    """What ``view``'s camera sees of the painted board.

    Each pixel averages the board image over its footprint: n x n stratified samples of
    the pixel's image-plane square are traced to the board and weighted by the board
    area each stands for (the Jacobian C_z^2 / |d_z|^3 of the ray map), so the mean is
    an area average over the footprint P. Samples that miss the board count as black,
    so edge pixels are dimmed like the render's (SPEC section 4, the |P ∩ B| term).

    Args:
        board_img: (rows, cols) linear board-space image, as :func:`fit_to_board` or
            :func:`board_image` return it.
        board: The board the image covers.
        view: The camera.

    Returns:
        (H, W) float64 (the view's resolution); NaN where the pixel centre's ray misses
        the board.

    Raises:
        ValueError: ``board_img`` is not 2-D.
    """
    if np.ndim(board_img) != 2:
        raise ValueError(
            f"board_img: expected a (rows, cols) board image, got shape {np.shape(board_img)}"
        )
    camera = Camera.from_view(view)
    n = supersample_rate(board_img, board, camera)
    offsets = (np.arange(n) + 0.5) / n
    H, W = view.height, view.width
    out = np.empty((H, W))
    rows_per_chunk = max(1, 2_000_000 // max(1, W * n * n))
    for r0 in range(0, H, rows_per_chunk):
        r1 = min(H, r0 + rows_per_chunk)
        t = (np.arange(r0, r1)[:, None, None, None] + offsets[None, None, :, None]) * np.ones(
            (1, W, n, n)
        )
        s = (np.arange(W)[None, :, None, None] + offsets[None, None, None, :]) * np.ones(
            (r1 - r0, 1, n, 1)
        )
        pts, ok = camera.board_hits(s, t)
        dz = camera.directions(s, t)[..., 2]
        # Board area per image-plane area of a sample, C_z^2 / |d_z|^3 (f . d = 1).
        jac = np.where(ok, 1.0 / np.abs(np.where(ok, dz, -1.0)) ** 3, 0.0)
        vals = np.where(ok, sample_board(board_img, board, pts), 0.0)
        norm = jac.sum(axis=(2, 3))
        out[r0:r1] = (vals * jac).sum(axis=(2, 3)) / np.where(norm > 0, norm, 1.0)
    return np.where(board_pixels(board, view), out, np.nan)


def board_pixels(board: Board, view: View) -> np.ndarray:
    """(H, W) bool: the pixels of ``view`` whose centre's ray meets the board (its targets)."""
    centres, ok = Camera.from_view(view).center_grid()
    hw, hh = board.half_extent
    return ok & (np.abs(centres[..., 0]) <= hw) & (np.abs(centres[..., 1]) <= hh)


def _board_images(
    design: Design, views: Iterable[View], fit: str, gamma: float, contrast: float
) -> dict[str, np.ndarray]:
    cache: dict[tuple[Path, bool], np.ndarray] = {}
    images: dict[str, np.ndarray] = {}
    for view in views:
        path = design.target_path(view)
        if path is None:
            continue
        key = (path, view.invert)
        if key not in cache:
            cache[key] = board_image(path, design.board, fit, gamma, contrast, view.invert)
        images[view.name] = cache[key]
    return images


def view_targets(
    design: Design, fit: str = "contain", gamma: float = 1.0, contrast: float = 1.0
) -> dict[str, np.ndarray]:
    """Each view's target in its own camera pixels (views without a target are left out).

    For a job's resolved ``design.toml`` the targets are the board-space images that
    ``design`` wrote, so the defaults reproduce ``targets/<view>.npy`` exactly.
    """
    images = _board_images(design, design.views, fit, gamma, contrast)
    return {
        v.name: warp_to_view(images[v.name], design.board, v)
        for v in design.views
        if v.name in images
    }


def cross_targets(
    design: Design, fit: str = "contain", gamma: float = 1.0, contrast: float = 1.0
) -> dict[tuple[str, str], np.ndarray]:
    """T_j->k for every pair of views with targets: view j's image as camera k sees it.

    Keys are ``(k, j)`` view names; ``(k, k)`` is view k's own target (SPEC section 7).
    """
    images = _board_images(design, design.views, fit, gamma, contrast)
    out: dict[tuple[str, str], np.ndarray] = {}
    for k in design.views:
        for j in design.views:
            if j.name in images:
                out[(k.name, j.name)] = warp_to_view(images[j.name], design.board, k)
    return out


def job_cross_targets(design: Design) -> dict[tuple[str, str], np.ndarray] | None:
    """:func:`cross_targets` of a job's resolved design, or None if its pictures are unreadable.

    A job's ``design/board/*.png`` may be gone or broken; optimize and verify then fall
    back to the per-view ``targets/<view>.npy`` (the diagonal) instead of failing.
    """
    try:
        return cross_targets(design)
    except (ScratchfabError, OSError, KeyError):
        return None
