"""Loading target images: any Pillow format to linear luminance in [0, 1].

EXIF orientation is honoured, colour becomes luminance (Rec. 709 weights on linear
channels), alpha is composited over black (after the colour is inverted, when asked), and
pixel values are decoded in the colour space the file declares (SPEC section 5 makes sRGB
the default):

* an embedded ICC profile (any format) is converted to sRGB with littleCMS through
  Pillow's ImageCms, relative colorimetric intent: RGB (LUT-based profiles) and CMYK
  images to 8-bit sRGB, gray images to 16-bit values on the sRGB tone curve, matrix/TRC
  RGB profiles by tables (below);
* a PNG without ``iCCP`` or ``sRGB`` chunk is decoded with its ``gAMA`` exponent
  (linear = stored ** (1 / gamma)) and its ``cHRM`` primaries and white (luminance
  weights of those primaries, Bradford-adapted to D65);
* anything else is sRGB, decoded with the exact piecewise transfer function
  (IEC 61966-2-1). That includes floating-point (32-bit grey TIFF) pixels: SPEC section 5
  makes a target's pixel values sRGB-encoded brightness, whatever their type, so a float
  file without a profile must hold values in [0, 1] (beyond 0.01 outside, it is refused:
  an HDR image clipped would be mostly white); a gray profile with a linear curve marks
  linear values.

16-bit PNGs and TIFFs keep their 16 bits: grey ones Pillow reads as such; colour ones
(RGB, RGBA, CMYK) and grey-with-alpha PNGs, which Pillow opens at 8 bits, are read a
second time for the low bytes; grey-with-alpha TIFFs, which Pillow refuses, are opened
with its table of TIFF layouts extended for the call; a TIFF of separate 16-bit planes
(Pillow reads an uncompressed one's bytes as 8-bit samples, and libtiff hands it each
compressed plane's high bytes) is read again plane by plane, as 16-bit grey images. EXIF
orientation turns them as it turns the image. A TIFF's associated (premultiplied) alpha
is divided out of the 16-bit colour where alpha > 0, and 16-bit and float WhiteIsZero
grey is inverted (Pillow inverts only 8-bit grey; it refuses big-endian 16-bit such
files, which are opened as grey-with-alpha TIFFs are). 16-bit CMYK without a profile
becomes RGB as Pillow converts CMYK, ``(1 - C)(1 - K)``, at 16 bits.

RGB pixels with a matrix/TRC profile (sRGB, Adobe RGB, Display P3, ProPhoto), 8- or
16-bit, are decoded from per-channel tables of their luminance, without rounding to
8-bit sRGB or clipping to its gamut (so 8 and 16 bits agree); a LUT-based RGB profile
(or one with both a table and a matrix, which littleCMS converts by the table) and a
CMYK profile convert 8 bits to 8-bit sRGB. Pillow's ImageCms has no 16-bit RGB or CMYK
mode: a 16-bit pixel's luminance is interpolated between those of the 8-bit codes
around it, so 16-bit codes 257 c read as the 8-bit codes c do and the low bytes still
count.
A PNG ``tRNS`` colour key makes its pixels transparent at 16 bits too; a CIELAB TIFF is
read by its L* channel.
"""

from __future__ import annotations

import io
import struct
import warnings
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError, features

from scratchfab.design.images_deep import (
    CHUNK_ROWS,
    PHOTOMETRIC,
    TIFF_MAGIC,
    deep_read,
    deep_samples,
    naive_rgb,
    open_image,
    orientation,
    tiff_tag,
    upright,
)
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.fileio import read_input

if TYPE_CHECKING:
    from PIL.ImageCms import ImageCmsProfile, ImageCmsTransform

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


def invert_picture(picture: np.ndarray) -> np.ndarray:
    """A linear picture turned negative as it looks: ``1 - v`` on sRGB-encoded values.

    Inverted in the encoding, as an image editor inverts a file (8-bit code ``255 - c``),
    not in linear light: there a mid grey (encoded 0.5, linear 0.21) would become linear
    0.79 (encoded 0.9), and the dark outline of a light-on-dark picture's shapes a bright
    halo. In the encoding black and white swap and grey stays grey, as the eye sees it.
    Values are clipped to [0, 1] first. A file's transparency is no part of the picture
    here: ``load_image(path, invert=True)`` inverts the colours and then composites them
    over black, so a transparent ground stays black.
    """
    return srgb_to_linear(1.0 - linear_to_srgb(picture))


def _open(path: Path) -> tuple[Image.Image, np.ndarray | None]:
    """The upright image, and its 16-bit samples where Pillow keeps only 8 bits.

    A TIFF of separate 16-bit planes comes back unloaded: its samples are all in the
    array, read plane by plane, and Pillow's own decode of the whole (8-bit, or refused
    by libtiff for grey and alpha) would be wasted work.
    """
    data = read_input(path, "an image file", missing="image file not found")
    if not data:
        raise ConfigError(f"{path}: empty file, expected an image")
    try:
        # Closed on the way out: Pillow keeps the stream it is given, and with it the bytes.
        with warnings.catch_warnings(), io.BytesIO(data) as stream:
            # Pillow warns of what it skips (a corrupt EXIF block, a tag past the end) and
            # of large images; the pixels decode or the file is refused below, in one line.
            warnings.simplefilter("ignore")
            image = open_image(stream)
            read = deep_read(image)  # before load(), which drops the tiles
            if read is not None and read.planes:  # as stored: load() is what turns a TIFF
                return image, upright(deep_samples(data, image, read), orientation(image))
            if read is not None:
                image.tile = read.high
            image.load()
            deep = None
            if read is not None:
                # Pillow's decoder turned what it read of a TIFF and dropped the tag (a
                # PNG's getexif() before load() would have loaded it with the wrong tiles)
                deep = upright(deep_samples(data, image, read), orientation(image))
            # In place (a copy of a 12-MP photo is 48 MB), once upright has read the tag.
            ImageOps.exif_transpose(image, in_place=True)
            return image, deep
    except UnidentifiedImageError:
        raise ConfigError(f"{path}: not an image file Pillow can read{_hint(data)}") from None
    except Image.DecompressionBombError:
        raise ConfigError(f"{path}: image is too large (decompression bomb check)") from None
    except (OSError, ValueError, SyntaxError, EOFError, struct.error) as exc:
        raise ConfigError(f"{path}: corrupt or truncated image ({exc})") from None


#: ISO media brands of still images (HEIF, HEIC as iPhones write it, AVIF).
_HEIF_BRANDS = (b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"mif1", b"msf1", b"avif")


def _hint(data: bytes) -> str:
    """What a file Pillow cannot identify seems to be, and what to save instead."""
    head = data[:1024].lstrip()
    if data[:4] in TIFF_MAGIC:
        what = (
            "a TIFF in a layout Pillow does not decode, such as floating-point colour or "
            "16- or 64-bit floats (it reads floats only as one 32-bit grey channel)"
        )
    elif data[4:8] == b"ftyp" and data[8:12] in _HEIF_BRANDS:
        what = "a HEIF/HEIC or AVIF photo, which this Pillow does not decode"
    elif data[:4] == b"%PDF":
        what = "a PDF document"
    elif b"<svg" in data[:4096]:
        what = "an SVG drawing (vector, not pixels)"
    elif head[:14].lower() == b"<!doctype html" or head[:5].lower() == b"<html":
        what = "a web page (HTML), perhaps saved in place of the picture it shows"
    elif head.startswith(b"<?xml"):
        what = "an XML document, not pixels"
    elif data[:4] == b"\x76\x2f\x31\x01":
        what = "an OpenEXR image"
    else:
        return ""
    return (
        f" ({what}); expected PNG, JPEG, TIFF (8-bit; 16-bit grey, grey and alpha, RGB, "
        "RGBA or CMYK; 32-bit float grey) or WebP pixels (export the picture as one)"
    )


#: Linear values of every 8-bit and 16-bit code (decoding by table is exact and fast).
_LUT8 = srgb_to_linear(np.arange(256) / 255.0)
_LUT16 = srgb_to_linear(np.arange(65536) / 65535.0)
#: How far floating-point pixels may stray outside [0, 1] (rounding, filters' overshoot)
#: before the file is refused rather than clipped.
_FLOAT_SLACK = 0.01

_GRAY_MODES = ("1", "L", "LA", "La", "I", "F", "I;16", "I;16L", "I;16B", "I;16N")
_RGB_MODES = ("RGB", "RGBA", "RGBX", "RGBa", "P", "PA")
#: What an embedded profile must describe for each kind of image (ICC colour space).
_SPACE_OF_KIND = {"grayscale": "GRAY", "RGB": "RGB", "CMYK": "CMYK"}


class _Decoding:
    """How stored codes become linear light: per-channel tables and luminance weights."""

    def __init__(
        self,
        lut8: np.ndarray = _LUT8,
        lut16: np.ndarray = _LUT16,
        weights: np.ndarray = LUMA_709,
    ) -> None:
        self.lut8 = lut8
        self.lut16 = lut16
        self.weights = weights

    def unit(self, v: np.ndarray) -> np.ndarray:
        """Linear values of gray values in [0, 1] that fall between 16-bit codes."""
        if self.lut16 is _LUT16:
            return srgb_to_linear(v)
        return np.interp(v, np.linspace(0.0, 1.0, 65536), self.lut16)


def _kind(image: Image.Image, deep: np.ndarray | None) -> str:
    """What the pixels are: "grayscale", "RGB", "CMYK", or Pillow's mode for anything else."""
    if deep is not None:
        return "grayscale" if deep.shape[2] <= 2 else "CMYK" if image.mode == "CMYK" else "RGB"
    if image.mode in _GRAY_MODES:
        return "grayscale"
    if image.mode == "CMYK":
        return "CMYK"
    return "RGB" if image.mode in _RGB_MODES else image.mode


# -- ICC profiles -----------------------------------------------------------------------


def _s15(v: float) -> bytes:
    return struct.pack(">i", round(v * 65536))


@cache
def _srgb_gray_profile() -> bytes:
    """A minimal ICC v4 gray display profile whose tone curve is sRGB's (IEC 61966-2-1).

    ``para`` function type 3: Y = ((X + 0.055) / 1.055) ** 2.4 above 0.04045, X / 12.92
    below; D50 white, as v4 requires.
    """
    d50 = _s15(0.9642) + _s15(1.0) + _s15(0.8249)
    text = "sRGB tone curve gray".encode("utf-16-be")
    params = (2.4, 1 / 1.055, 0.055 / 1.055, 1 / 12.92, 0.04045)
    tags = [
        (b"desc", b"mluc" + struct.pack(">4xII4sII", 1, 12, b"enUS", len(text), 28) + text),
        (b"wtpt", b"XYZ " + bytes(4) + d50),
        (b"kTRC", b"para" + struct.pack(">4xHxx", 3) + b"".join(_s15(p) for p in params)),
    ]
    start = 128 + 4 + 12 * len(tags)
    table, body = b"", b""
    for sig, data in tags:
        data += bytes(-len(data) % 4)
        table += sig + struct.pack(">II", start + len(body), len(data))
        body += data
    header = struct.pack(
        ">I4xI4s4s4s12x4s24xI", start + len(body), 0x04300000, b"mntr", b"GRAY", b"XYZ ", b"acsp", 0
    )
    header += d50
    return header + bytes(128 - len(header)) + struct.pack(">I", len(tags)) + table + body


def _embedded_profile(image: Image.Image, file: Path, kind: str) -> ImageCmsProfile | None:
    """The image's ICC profile, checked against its pixels, or None when it has none."""
    icc = image.info.get("icc_profile")
    if not icc:
        if "icc_profile" in image.info and image.format == "PNG":
            # Pillow stores None when the iCCP chunk's compressed data does not inflate.
            raise ConfigError(
                f"{file}: the PNG iCCP chunk (embedded ICC profile) is corrupt; expected a "
                "zlib-compressed ICC profile (re-save the image, or without a profile for sRGB)"
            )
        return None
    if not features.check("littlecms2"):
        raise ScratchfabError(
            f"{file}: the image has an embedded ICC colour profile but this Pillow was built "
            "without littleCMS (PIL.ImageCms), so it cannot be read in its colour space; "
            "install a Pillow wheel with littleCMS, or re-save the image as sRGB without a "
            "profile"
        )
    from PIL import ImageCms

    try:
        profile = ImageCms.ImageCmsProfile(io.BytesIO(icc))
    except (OSError, ValueError, ImageCms.PyCMSError) as exc:
        raise ConfigError(
            f"{file}: the embedded ICC profile is corrupt ({exc}); expected a valid ICC colour "
            "profile (re-save the image, or without a profile for sRGB)"
        ) from None
    space = profile.profile.xcolor_space.strip()
    expected = _SPACE_OF_KIND.get(kind)
    if expected is None:
        raise ConfigError(
            f"{file}: has an embedded ICC profile but its pixels are {kind}; expected an RGB, "
            "CMYK or grayscale image with a profile (re-save it as one)"
        )
    device_class = profile.profile.device_class.strip()
    if device_class in ("link", "abst", "nmcl"):
        raise ConfigError(
            f"{file}: the embedded ICC profile is a {device_class!r} profile, not one that "
            f"describes the pixels; expected an input, display or output profile for {expected}"
        )
    if space != expected:
        raise ConfigError(
            f"{file}: the embedded ICC profile describes {space} colours but the image is "
            f"{kind} ({image.mode}); expected a {expected} profile (re-save the image with a "
            "matching profile, or without one for sRGB)"
        )
    return profile


def _build(
    file: Path,
    source: ImageCmsProfile,
    target: ImageCmsProfile,
    modes: tuple[str, str],
    exact: bool,
) -> ImageCmsTransform:
    from PIL import ImageCms

    try:
        return ImageCms.buildTransform(
            source,
            target,
            *modes,
            renderingIntent=ImageCms.Intent.RELATIVE_COLORIMETRIC,
            flags=ImageCms.Flags.NOOPTIMIZE if exact else ImageCms.Flags.NONE,
        )
    except ImageCms.PyCMSError as exc:
        raise ConfigError(
            f"{file}: littleCMS cannot use the embedded ICC profile ({exc}); expected a valid "
            "ICC colour profile (re-save the image, or without a profile for sRGB)"
        ) from None


def _gray_decoding(file: Path, profile: ImageCmsProfile) -> _Decoding:
    """Tables of the linear value of every 8-bit and 16-bit code in a gray profile.

    Each code is converted once, without littleCMS's curve-joining optimisation (it is
    off by up to 80 % in deep shadows), to a 16-bit value on the sRGB curve, which is
    then decoded exactly: errors stay near 2e-5 of full scale.
    """
    from PIL import ImageCms

    gray = ImageCms.ImageCmsProfile(io.BytesIO(_srgb_gray_profile()))
    tables = []
    for mode, codes in (("L", np.arange(256, dtype=np.uint8)), ("I;16", np.arange(65536))):
        ramp = Image.fromarray(codes.astype(np.uint8 if mode == "L" else np.uint16)[None, :])
        transform = _build(file, profile, gray, (mode, "I;16"), exact=True)
        out = ImageCms.applyTransform(ramp, transform)
        assert out is not None
        tables.append(_LUT16[np.asarray(out).astype(np.int64)[0]])
    return _Decoding(lut8=tables[0], lut16=tables[1])


#: Tags of device-to-PCS tables: littleCMS converts relative colorimetric input by one of
#: them rather than by the matrix and curves when a profile has both.
_DEVICE_TO_PCS_LUTS = {b"A2B0", b"A2B1", b"D2B0", b"D2B1"}


def _has_device_to_pcs_lut(icc: bytes) -> bool:
    """Whether an ICC profile's tag table holds an A2B0/A2B1 or D2B0/D2B1 table."""
    (count,) = struct.unpack_from(">I", icc, 128)
    count = min(count, (len(icc) - 132) // 12)
    return any(icc[132 + 12 * i : 136 + 12 * i] in _DEVICE_TO_PCS_LUTS for i in range(count))


def _matrix_shaper_decoding(file: Path, profile: ImageCmsProfile) -> _Decoding | None:
    """Per-channel tables of 16-bit codes' luminance through a matrix/TRC RGB profile.

    Relative colorimetric to sRGB is ``M_srgb^-1 M @ TRC(codes)`` (M: the D50 colorants),
    so luminance is ``sum_c k_c TRC_c(code_c)`` with ``k = LUMA_709 M_srgb^-1 M``: one
    table per channel. littleCMS gives ``Y_c TRC_c`` at the 256 8-bit codes (that channel
    alone, converted without optimisation to 16-bit gray on the sRGB curve), and the
    16-bit codes fall between them, by linear interpolation. None for a LUT profile,
    including one with matrix and curves too (littleCMS converts by its table).
    """
    from PIL import ImageCms

    def colorants(p: ImageCmsProfile) -> np.ndarray | None:
        xyz = [p.profile.red_colorant, p.profile.green_colorant, p.profile.blue_colorant]
        return np.array([c[0] for c in xyz if c is not None]).T if None not in xyz else None

    source = colorants(profile)
    srgb = colorants(ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")))
    if (
        not profile.profile.is_matrix_shaper
        or _has_device_to_pcs_lut(profile.tobytes())
        or source is None
        or np.any(source[1] <= 0)
    ):
        return None
    assert srgb is not None
    k = LUMA_709 @ np.linalg.solve(srgb, source)
    codes = np.arange(256, dtype=np.uint8)
    ramps = np.zeros((3, 256, 3), np.uint8)
    for c in range(3):
        ramps[c, :, c] = codes
    gray = ImageCms.ImageCmsProfile(io.BytesIO(_srgb_gray_profile()))
    transform = _build(file, profile, gray, ("RGB", "I;16"), exact=True)
    out = ImageCms.applyTransform(Image.fromarray(ramps), transform)
    assert out is not None
    trc = _LUT16[np.asarray(out).astype(np.int64)] / source[1][:, None]
    lut16 = np.column_stack(
        [k[c] * np.interp(np.arange(65536) / 65535.0, codes / 255.0, trc[c]) for c in range(3)]
    )
    return _Decoding(lut16=lut16, weights=np.ones(3))


def _to_srgb(image: Image.Image, file: Path, profile: ImageCmsProfile) -> Image.Image:
    """An RGB or CMYK image converted to 8-bit sRGB (RGBA keeps its alpha as it was).

    littleCMS's optimised 8-bit path is used: against the exact conversion it is within
    0.52 of an 8-bit code, the output's own rounding (half a code, i.e. at most 0.0045 of
    linear full scale, near white).
    """
    if image.mode == "CMYK":
        rgb, alpha = image, None
    else:
        codes = _rgb_codes(image, file)
        rgb = Image.fromarray(np.ascontiguousarray(codes[..., :3]))
        alpha = (
            Image.fromarray(np.ascontiguousarray(codes[..., 3])) if codes.shape[2] == 4 else None
        )
    out = _converted(rgb, file, _srgb_transform(file, profile, rgb.mode))
    if alpha is not None:
        out.putalpha(alpha)
    return out


def _srgb_transform(file: Path, profile: ImageCmsProfile, mode: str) -> ImageCmsTransform:
    """The optimised littleCMS transform of 8-bit ``mode`` pixels to 8-bit sRGB."""
    from PIL import ImageCms

    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB"))
    return _build(file, profile, srgb, (mode, "RGB"), exact=False)


def _converted(image: Image.Image, file: Path, transform: ImageCmsTransform) -> Image.Image:
    """The image converted to 8-bit sRGB, a littleCMS failure as one line naming the file."""
    from PIL import ImageCms

    try:
        out = ImageCms.applyTransform(image, transform)
    except ImageCms.PyCMSError as exc:
        raise ConfigError(f"{file}: littleCMS cannot convert the image to sRGB ({exc})") from None
    assert out is not None
    return out


def _between_codes(
    samples: np.ndarray, kind: str, file: Path, profile: ImageCmsProfile
) -> tuple[np.ndarray, np.ndarray | None]:
    """Linear luminance (and alpha) of 16-bit RGB or CMYK samples through a LUT profile.

    Pillow's ImageCms has no 16-bit RGB or CMYK mode: each pixel is interpolated between
    the 8-bit codes around it (code v / 257) on a simplex of the cell (Kuhn's: the corner
    below, then one channel more at a time, largest fraction first), the corners
    converted as an 8-bit image is (:func:`_to_srgb`) and their luminance weighed. A
    file of 8-bit codes c stored as 257 c reads as the 8-bit file; the low bytes move
    the picture between the codes, where the high bytes alone would band.
    """
    n = 4 if kind == "CMYK" else 3
    transform = _srgb_transform(file, profile, kind)
    lin = np.empty(samples.shape[:2])
    rows = max(1, 65536 // samples.shape[1])  # some 64 K pixels: ~20 float copies of them
    for r0 in range(0, samples.shape[0], rows):
        block = samples[r0 : r0 + rows, :, :n]
        below = np.minimum(block // 257, 254).astype(np.uint8)
        rest = block - below * np.uint16(257)  # 257 times the fraction, 0 to 257
        # Each channel's place in the walk, largest fraction first (of equal ones, the
        # earlier channel), by comparisons: an argsort and its takes cost twice the time.
        place = np.zeros(block.shape, np.uint8)
        for c in range(n):
            for d in range(n):
                place[..., c] += (
                    rest[..., d] >= rest[..., c] if d < c else rest[..., d] > rest[..., c]
                )
        steps = np.sort(rest, axis=-1)[..., ::-1] / 257.0
        # Corner k's weight: the k-th largest fraction less the next (1 before the first).
        weights = np.concatenate(
            [1.0 - steps[..., :1], -np.diff(steps, axis=-1), steps[..., -1:]], -1
        )
        lum = np.zeros(block.shape[:2])
        height, width = block.shape[:2]
        for k in range(n + 1):  # corner k: one step along each of the k placed first
            if not weights[..., k].any():  # 8-bit codes stored as 257 c: corner 0 alone
                continue
            corner = below + (place < k)
            pixels = Image.frombuffer(kind, (width, height), corner, "raw", kind, 0, 1)
            rgb = np.asarray(_converted(pixels, file, transform))
            lum += weights[..., k] * (_LUT8[rgb] @ LUMA_709)
        lin[r0 : r0 + rows] = lum
    alpha = samples[..., n] / 65535.0 if samples.shape[2] > n else None
    return lin, alpha


# -- PNG gAMA / cHRM ----------------------------------------------------------------------

#: Bradford cone response matrix (chromatic adaptation, as in ICC v4 Annex E).
_BRADFORD = np.array(
    [[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]]
)
#: D65 white (x, y) of sRGB.
_D65 = (0.3127, 0.3290)


def _xyz(x: float, y: float) -> np.ndarray:
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


def _chrm_weights(file: Path, chromaticity: tuple[float, ...]) -> np.ndarray:
    """Luminance weights of linear R, G, B for a PNG cHRM chunk (white and primaries).

    The primaries' XYZ are scaled so that R = G = B = 1 is the chunk's white (Y = 1),
    then Bradford-adapted to D65; for sRGB's chromaticities this gives Rec. 709 weights.
    """
    wx, wy, rx, ry, gx, gy, bx, by = chromaticity
    bad = (
        f"{file}: the PNG cHRM chunk's chromaticities {tuple(round(c, 5) for c in chromaticity)} "
        "do not describe a colour space; expected white and three primaries with 0 < x, y "
        "and x + y <= 1 spanning a triangle"
    )
    if min(chromaticity) < 0 or min(wy, ry, gy, by) <= 0:
        raise ConfigError(bad)
    primaries = np.column_stack([_xyz(rx, ry), _xyz(gx, gy), _xyz(bx, by)])
    if abs(np.linalg.det(primaries)) < 1e-9:
        raise ConfigError(bad)
    scale = np.linalg.solve(primaries, _xyz(wx, wy))
    if np.any(scale <= 0):
        raise ConfigError(bad)
    cone_src = _BRADFORD @ _xyz(wx, wy)
    cone_dst = _BRADFORD @ _xyz(*_D65)
    adapt = np.linalg.inv(_BRADFORD) @ np.diag(cone_dst / cone_src) @ _BRADFORD
    return np.asarray((adapt @ (primaries * scale))[1])


def _png_decoding(image: Image.Image, file: Path, kind: str) -> _Decoding | None:
    """The decoding a PNG's gAMA / cHRM chunks ask for, or None for sRGB.

    An ``sRGB`` chunk means sRGB whatever else is there (PNG specification, 3rd ed.,
    section 11.3.2); ``gAMA`` stores the encoding exponent (0.45455 for a 2.2 display).
    """
    if image.format != "PNG" or "srgb" in image.info:
        return None
    gamma = image.info.get("gamma")
    chromaticity = image.info.get("chromaticity")
    if gamma is None and (chromaticity is None or kind == "grayscale"):
        return None
    decoding = _Decoding()
    if gamma is not None:
        if not gamma > 0:
            raise ConfigError(
                f"{file}: the PNG gAMA chunk is {gamma}; expected a positive encoding exponent "
                "(e.g. 0.45455, or 1.0 for linear values)"
            )
        exponent = 1.0 / gamma
        decoding.lut8 = (np.arange(256) / 255.0) ** exponent
        decoding.lut16 = (np.arange(65536) / 65535.0) ** exponent
    if chromaticity is not None and kind == "RGB":
        decoding.weights = _chrm_weights(file, chromaticity)
    return decoding


# -- pixels -------------------------------------------------------------------------------


def _gray16(image: Image.Image) -> np.ndarray | None:
    """A 16-bit grey image's samples, (h, w, 1) uint16, else None.

    Pillow opens 16-bit grey as "I;16" (or "I" in some versions: any "I" image within
    the 16-bit range counts).
    """
    if image.mode.startswith("I;16"):
        return np.asarray(image).astype(np.uint16)[..., None]
    if image.mode == "I":
        arr = np.asarray(image)
        if arr.min(initial=0) >= 0 and arr.max(initial=0) <= 65535:
            return arr.astype(np.uint16)[..., None]
    return None


def _keyed(samples: np.ndarray, image: Image.Image) -> np.ndarray:
    """16-bit samples with an alpha channel added where a PNG ``tRNS`` colour key applies.

    The key (Pillow's ``transparency``: a grey value, or R, G, B) holds 16-bit values for
    a 16-bit PNG; pixels equal to it are transparent, all others opaque.
    """
    key = np.atleast_1d(np.asarray(image.info.get("transparency", ()), dtype=np.int64))
    if samples.shape[2] % 2 == 0 or key.shape != (samples.shape[2],):
        return samples
    opaque = np.any(samples != key, axis=-1)
    return np.concatenate([samples, (opaque * np.uint16(65535))[..., None]], axis=-1)


def _lab_luminance(image: Image.Image) -> np.ndarray | None:
    """Luminance of a CIELAB image (its L* channel, CIE 1976), else None.

    Y = ((L* + 16) / 116) ** 3, or L* 27 / 24389 at or below L* = 8 (relative to white).
    """
    if image.mode != "LAB":
        return None
    lstar = np.asarray(image.getchannel("L"), dtype=np.float64) * (100.0 / 255.0)
    return np.where(lstar > 8.0, ((lstar + 16.0) / 116.0) ** 3, lstar * (27.0 / 24389.0))


def _high_bit_gray(image: Image.Image, file: Path, decoding: _Decoding) -> np.ndarray | None:
    """Linear gray values of 32-bit integer and float images, else None.

    WhiteIsZero (a TIFF's PhotometricInterpretation 0) turns a value v in [0, 1] into
    1 - v before it is decoded, as 16-bit codes c become 65535 - c.
    """
    white_is_zero = tiff_tag(image, PHOTOMETRIC) == 0
    if image.mode == "I":  # beyond 16 bits (_gray16 takes the rest): scaled to its maximum
        arr = np.asarray(image, dtype=np.int64)
        unit = np.clip(arr / float(max(arr.max(), 1)), 0.0, 1.0)
        return decoding.unit(1.0 - unit if white_is_zero else unit)
    if image.mode == "F":
        values = np.asarray(image, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            outside = (values < -_FLOAT_SLACK) | (values > 1.0 + _FLOAT_SLACK)
        for bad, expected in (
            (~np.isfinite(values), "finite brightness values ({} pixels are NaN or infinite)"),
            (
                outside,
                "brightness in [0, 1] ({} pixels are outside): floating-point pixels are "
                "brightness, sRGB-encoded unless a colour profile says otherwise (SPEC "
                "section 5); scale the image to [0, 1] (tone-map an HDR image first), and "
                "embed a gray profile with a linear curve (gamma 1.0) for linear values",
            ),
        ):
            where = np.argwhere(bad)
            if len(where):
                row, col = (int(v) for v in where[0])
                raise ConfigError(
                    f"{file}: pixel (row {row}, column {col}) is {values[row, col]:.6g}; "
                    f"expected {expected.format(len(where))}"
                )
        unit = np.clip(values, 0.0, 1.0)
        return decoding.unit(1.0 - unit if white_is_zero else unit)
    return None


def _luminance_16bit(
    samples: np.ndarray, decoding: _Decoding
) -> tuple[np.ndarray, np.ndarray | None]:
    """Linear luminance of (h, w, c) 16-bit samples (grey or RGB), and alpha if c is even.

    ``decoding.lut16`` is one table for every channel or, (65536, 3), one per channel.
    The luminance is the colour's, not composited: alpha (in [0, 1]) comes apart.
    """
    table = decoding.lut16.reshape(65536, -1)
    colour = samples.shape[2] >= 3
    weights = decoding.weights if colour else np.ones(1)
    # One contiguous table per channel: a 1-D lookup is ~4x faster than a 2-D one.
    luts = [np.ascontiguousarray(table[:, c % table.shape[1]]) for c in range(len(weights))]
    lin = np.empty(samples.shape[:2])
    for r0 in range(0, samples.shape[0], CHUNK_ROWS):
        block = samples[r0 : r0 + CHUNK_ROWS]
        lum = np.zeros(block.shape[:2])
        for c, (weight, lut) in enumerate(zip(weights, luts, strict=True)):
            lum += weight * lut[block[..., c]]
        lin[r0 : r0 + CHUNK_ROWS] = lum
    alpha = samples[..., -1] / 65535.0 if samples.shape[2] % 2 == 0 else None
    return lin, alpha


def _rgb_codes(image: Image.Image, file: Path) -> np.ndarray:
    """The image's 8-bit R, G, B codes, (h, w, 3), and alpha (h, w, 4) where it has one."""
    has_alpha = image.mode in ("RGBA", "LA", "PA", "RGBa", "La") or ("transparency" in image.info)
    try:
        return np.asarray(image.convert("RGBA" if has_alpha else "RGB"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{file}: cannot convert {image.mode} image to RGB ({exc})") from None


def _luminance_8bit(
    image: Image.Image, file: Path, decoding: _Decoding
) -> tuple[np.ndarray, np.ndarray | None]:
    """Linear luminance of an 8-bit image's R, G, B codes (grey ones too), and its alpha."""
    rgba = _rgb_codes(image, file)
    lin = np.empty(rgba.shape[:2])
    for r0 in range(0, rgba.shape[0], CHUNK_ROWS):
        block = rgba[r0 : r0 + CHUNK_ROWS]
        lin[r0 : r0 + CHUNK_ROWS] = decoding.lut8[block[..., :3]] @ decoding.weights
    return lin, rgba[..., 3] / 255.0 if rgba.shape[2] == 4 else None


def load_image(path: str | Path, invert: bool = False) -> np.ndarray:
    """Read an image file as linear luminance, in the colour space the file declares.

    Transparency is composited over black (straight alpha, in linear light: ``alpha *
    colour``): a transparent ground is the bare board.

    Args:
        path: Any format Pillow reads (PNG incl. 16-bit and palette, JPEG incl. CMYK,
            TIFF incl. 16-bit grey, grey and alpha, RGB(A) and CMYK, float grey and
            CIELAB, WebP, ...), with or without an ICC
            profile.
        invert: Turn the colours negative (:func:`invert_picture`) before compositing,
            so that a dark logo on a transparent ground becomes a light logo on black.

    Returns:
        (h, w) float64 array in [0, 1], row 0 at the top of the (upright) picture.

    Raises:
        ConfigError: One line naming the file when it is missing, unreadable (saying what
            it seems to be: HEIC, PDF, SVG, EXR, a float TIFF) or corrupt, when its colour
            profile or PNG colour chunks are unusable, or when float pixels are NaN or
            outside [0, 1].
        ScratchfabError: The file has an ICC profile and Pillow lacks littleCMS.
    """
    file = Path(path)
    image, deep = _open(file)
    deep = deep if deep is not None else _gray16(image)
    if deep is not None and tiff_tag(image, PHOTOMETRIC) == 0:
        deep[..., 0] = 65535 - deep[..., 0]  # white is zero: Pillow inverts only 8 bits
    if deep is not None:
        deep = _keyed(deep, image)
    kind = _kind(image, deep)
    decoding: _Decoding | None = _Decoding()
    lin: np.ndarray | None = None
    alpha: np.ndarray | None = None
    profile = _embedded_profile(image, file, kind)
    if profile is None and kind == "CMYK" and deep is not None:
        deep = naive_rgb(deep)
    if profile is not None and kind == "grayscale":
        decoding = _gray_decoding(file, profile)
    elif profile is not None:
        decoding = _matrix_shaper_decoding(file, profile) if kind == "RGB" else None
        if decoding is None:  # through littleCMS's 8-bit transform
            if deep is not None:  # with the alpha a 16-bit colour key gave
                lin, alpha = _between_codes(deep, kind, file, profile)
            else:
                image = _to_srgb(image, file, profile)
            deep, decoding = None, _Decoding()
        elif deep is None:  # 8-bit codes c are the 16-bit codes 257 c, on the tables' grid
            deep = _rgb_codes(image, file).astype(np.uint16) * np.uint16(257)
    else:
        decoding = _png_decoding(image, file, kind) or _Decoding()
    if lin is None and deep is not None:
        lin, alpha = _luminance_16bit(deep, decoding)
    if lin is None:
        lin = _high_bit_gray(image, file, decoding)
    if lin is None:
        lin = _lab_luminance(image)
    if lin is None:
        lin, alpha = _luminance_8bit(image, file, decoding)
    if lin.ndim != 2 or lin.size == 0:
        raise ConfigError(f"{file}: image has no pixels")
    if invert:
        lin = invert_picture(lin)
    if alpha is not None:
        lin *= alpha
    return np.clip(lin, 0.0, 1.0, out=lin)
