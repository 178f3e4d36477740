"""16-bit samples that Pillow reads at 8 bits, misreads or refuses (PNG and TIFF).

Pillow has no 16-bit colour mode: it opens 16-bit RGB, RGBA and CMYK (and grey with
alpha in a PNG) at 8 bits, keeping each sample's high byte. Its own decoders (PNG filters
and interlacing, TIFF compressions) read the file a second time with rawmodes that keep
the low bytes instead. A 16-bit grey-and-alpha TIFF and a big-endian 16-bit WhiteIsZero
grey one, which Pillow refuses, are opened with its table of TIFF layouts extended for
the call; a TIFF of separate 16-bit planes (Pillow reads an uncompressed one's bytes as
8-bit samples, and libtiff hands it a compressed one's high bytes) is read again plane by
plane, each as a 16-bit grey image. A TIFF's associated alpha is divided out of the
colour, and EXIF orientation turns the samples as it turns the image.
"""

from __future__ import annotations

import io
import struct
import sys
import threading
from typing import Any, NamedTuple

import numpy as np
from PIL import ExifTags, Image, ImageFile, ImageOps, TiffImagePlugin, UnidentifiedImageError

#: Rows converted at a time, so that large photos do not need several float copies.
CHUNK_ROWS = 256

#: 16-bit layouts that Pillow decodes to 8 bits (it has no 16-bit colour mode), by the
#: rawmode it reads them with (PNG, TIFF; "RGBX" is a TIFF's RGB with an unspecified fourth
#: sample, "RGBa" RGB with associated alpha), and the rawmodes that read the same rows
#: keeping the high bytes, then the low ones: "RGB;16L" takes each big-endian sample's
#: second byte ("N" is the computer's own order), "RGBA;16B" reads "RGBa;16B" rows as they
#: are stored (Pillow's "RGBa" divides by alpha at 8 bits), and for grey with alpha a
#: 4-byte "RGBA" pixel is all of them (grey high, grey low, alpha high, alpha low).
_DEEP_RAWMODES = {
    "LA;16B": ("LA;16B", "RGBA"),
    **{
        f"{mode};16{order}": (f"{straight};16{order}", f"{straight};16{other}")
        for mode, straight in (
            ("RGB", "RGB"),
            ("RGBA", "RGBA"),
            ("RGBX", "RGBX"),
            ("RGBa", "RGBA"),
            ("CMYK", "CMYK"),
        )
        for order, other in (
            ("B", "L"),
            ("L", "B"),
            ("N", "B" if sys.byteorder == "little" else "L"),
        )
    },
}

#: TIFF tags: BitsPerSample, PhotometricInterpretation (0 WhiteIsZero, 1 BlackIsZero),
#: ExtraSamples (0 unspecified, 1 associated alpha, 2 alpha), PlanarConfiguration (2:
#: separate planes), and where the pixels are.
_BITS_PER_SAMPLE, PHOTOMETRIC, _EXTRA_SAMPLES, _PLANAR = 258, 262, 338, 284
_IMAGE_WIDTH, _IMAGE_LENGTH, _COMPRESSION, _SAMPLES_PER_PIXEL = 256, 257, 259, 277
_STRIP_OFFSETS, _ROWS_PER_STRIP, _STRIP_COUNTS = 273, 278, 279
_TILE_WIDTH, _TILE_LENGTH, _TILE_OFFSETS, _TILE_COUNTS = 322, 323, 324, 325
_STRIPS = _STRIP_OFFSETS, _STRIP_COUNTS
#: Tags a separate plane's directory (:func:`_planes`) takes from the file's: compression,
#: predictor, JPEG tables (samples read as unsigned; Pillow refuses 16-bit FillOrder 2 at
#: open); and those written as LONG (the rest are SHORT).
_PLANE_TAGS = (_COMPRESSION, 317, 347)
_LONG_TAGS = {_IMAGE_WIDTH, _IMAGE_LENGTH, _ROWS_PER_STRIP, _TILE_WIDTH, _TILE_LENGTH}
_LONG_TAGS |= {_STRIP_OFFSETS, _STRIP_COUNTS, _TILE_OFFSETS, _TILE_COUNTS}
TIFF_MAGIC = (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+")
#: Pillow's TIFF format keys (byte order, photometric, sample format, fill order, bits,
#: extra samples) for 16-bit grey with a second sample, which it does not list: read as
#: "RGBA" pixels of 4 stored bytes, which :func:`deep_samples` pairs up.
_TiffKey = tuple[bytes, int, tuple[int, ...], int, tuple[int, ...], tuple[int, ...]]
_GREY_AND_ALPHA_16: dict[_TiffKey, tuple[str, str]] = {
    (prefix, photometric, (1,), 1, (16, 16), (extra,)): ("RGBA", "RGBA")
    for prefix in (b"II", b"MM")
    for photometric in (0, 1)
    for extra in (0, 1, 2)
}
#: Big-endian 16-bit WhiteIsZero grey, which Pillow lists only little-endian: read as the
#: BlackIsZero layout is (``load_image`` inverts 16-bit WhiteIsZero grey itself).
_WHITE_IS_ZERO_16: dict[_TiffKey, tuple[str, str]] = {
    (b"MM", 0, (1,), 1, (16,), ()): ("I;16B", "I;16B")
}
#: The TIFF layouts :func:`open_image` adds to Pillow's table for a file it refuses.
_ADDED_LAYOUTS = {**_GREY_AND_ALPHA_16, **_WHITE_IS_ZERO_16}
_OPEN_INFO_LOCK = threading.Lock()


def open_image(stream: io.BytesIO) -> ImageFile.ImageFile:
    """The file opened by Pillow (not loaded), 16-bit grey-and-alpha TIFFs included.

    Pillow refuses those, and big-endian 16-bit WhiteIsZero grey; they are opened with its
    table of TIFF layouts extended for the call (under a lock: the table is Pillow's,
    shared by every thread).
    """
    try:
        return Image.open(stream)
    except UnidentifiedImageError as exc:
        stream.seek(0)
        if stream.read(4) not in TIFF_MAGIC:
            raise
        refused = exc
    stream.seek(0)
    table = getattr(TiffImagePlugin, "OPEN_INFO", None)
    if not isinstance(table, dict):  # another Pillow: refused as Pillow refuses it
        raise refused
    with _OPEN_INFO_LOCK:
        added = [key for key in _ADDED_LAYOUTS if key not in table]
        table.update({key: _ADDED_LAYOUTS[key] for key in added})
        try:
            return Image.open(stream)
        finally:
            for key in added:
                del table[key]


class DeepRead(NamedTuple):
    """How Pillow reads a 16-bit image's bytes: tiles for the high bytes, then the low."""

    #: Empty for ``planes``.
    high: list[Any]
    #: None when the first read takes every byte (a 16-bit grey-and-alpha TIFF) or when
    #: the samples are read plane by plane (``planes``).
    low: list[Any] | None
    #: A TIFF of separate 16-bit planes, which Pillow reads at 8 bits or misreads.
    planes: bool = False


def _rawmode(tile: Any) -> str | None:
    args = tile[3]
    return args if isinstance(args, str) else args[0] if args else None


def _with_rawmode(tile: Any, rawmode: str) -> Any:
    args = tile[3]
    new = rawmode if isinstance(args, str) else (rawmode, *args[1:])
    # Pillow 11 on: named tuples (a file of several strips reads their offsets).
    return tile._replace(args=new) if hasattr(tile, "_replace") else (*tile[:3], new)


def tiff_tag(opened: Image.Image, tag: int) -> Any:
    """A TIFF tag's value, None when absent or the image is no TIFF."""
    if not isinstance(opened, TiffImagePlugin.TiffImageFile):
        return None
    return opened.tag_v2.get(tag)


def deep_read(opened: Image.Image) -> DeepRead | None:
    """The tiles that read the image's 16 bits, or None unless it is 16-bit colour or LA."""
    tiles = list(getattr(opened, "tile", []))
    if tiff_tag(opened, _PLANAR) == 2 and len(opened.getbands()) > 1:
        if set(tiff_tag(opened, _BITS_PER_SAMPLE) or ()) != {16} or not tiles:
            return None
        return DeepRead([], None, planes=True)  # no tiles: Pillow decodes no plane whole
    if tiff_tag(opened, _BITS_PER_SAMPLE) == (16, 16):  # opened by _GREY_AND_ALPHA_16
        every = tiles and all(_rawmode(tile) == "RGBA" for tile in tiles)
        return DeepRead(tiles, None) if every else None
    high, low = [], []
    for tile in tiles:
        rawmode = _rawmode(tile)
        if rawmode not in _DEEP_RAWMODES:
            return None
        high.append(_with_rawmode(tile, _DEEP_RAWMODES[rawmode][0]))
        low.append(_with_rawmode(tile, _DEEP_RAWMODES[rawmode][1]))
    return DeepRead(high, low) if high else None


def _big_endian(opened: Image.Image, tile: Any) -> bool:
    """Whether a tile reads 16-bit samples high byte first.

    PNG stores them so; a TIFF in its own order, which libtiff (any compression) turns
    into the computer's.
    """
    if not isinstance(opened, TiffImagePlugin.TiffImageFile):
        return True
    if tile[0] == "libtiff":
        return sys.byteorder == "big"
    return bool(opened.tag_v2.prefix == b"MM")


def deep_samples(data: bytes, opened: Image.Image, read: DeepRead) -> np.ndarray:
    """A 16-bit image's samples, (h, w, channels) uint16, colour divided by alpha.

    ``opened`` holds the first read's bytes (the high ones, or all of them); Pillow's own
    decoder (PNG filters and interlacing, TIFF compressions) reads the file a second time
    with the ``read.low`` tiles. Associated alpha (a TIFF's premultiplied colour) is
    divided out; an unspecified second sample of a grey TIFF is dropped.
    """
    if read.planes:
        assert isinstance(opened, TiffImagePlugin.TiffImageFile)
        return _unassociated(_planes(data, opened), opened)
    if read.low is None:
        raw, every = np.asarray(opened), True
    else:
        again = Image.open(io.BytesIO(data))
        assert isinstance(again, ImageFile.ImageFile)
        again.tile = read.low
        again.load()
        raw, every = np.asarray(again), _rawmode(read.low[0]) == "RGBA"
        del again  # a 12-MP photo: each copy of it is 36 MB or more
    if every:  # grey and alpha: every byte
        first, second = raw[..., 0::2], raw[..., 1::2]
        big = _big_endian(opened, (read.low or read.high)[0])
        high, lows = (first, second) if big else (second, first)
    else:
        high, lows = np.asarray(opened), raw
    samples = high.astype(np.uint16)
    samples <<= 8
    samples |= lows
    return _unassociated(samples, opened)


def _unassociated(samples: np.ndarray, opened: Image.Image) -> np.ndarray:
    """A TIFF's samples with associated alpha divided out, an unspecified extra dropped.

    Pillow's "RGBX" rawmodes drop the extra sample themselves: only samples that still
    have every one the file stores lose it here.
    """
    extra = tiff_tag(opened, _EXTRA_SAMPLES)
    if extra == (1,):
        _unpremultiply(samples)
    elif extra == (0,) and samples.shape[2] == tiff_tag(opened, _SAMPLES_PER_PIXEL):
        samples = samples[..., :-1]
    return samples


def _planes(data: bytes, opened: TiffImagePlugin.TiffImageFile) -> np.ndarray:
    """A TIFF's separate 16-bit planes, (h, w, planes) uint16, each decoded by Pillow.

    Pillow reads an uncompressed file's planes as 8-bit samples (a wrong picture) and gets
    a compressed one's high bytes from libtiff. Each plane is a 16-bit grey image: a small
    TIFF of that plane's strips or tiles alone (TIFF 6.0, PlanarConfiguration 2: each
    plane's follow the one before's) under a directory naming the file's compression and
    predictor, so Pillow's decoders (libtiff's for a compressed file) read every byte.
    Malformed tags raise ValueError.
    """
    tags = opened.tag_v2
    width, height = tags[_IMAGE_WIDTH], tags[_IMAGE_LENGTH]
    tiled = _TILE_OFFSETS in tags
    if tiled:
        across, down = tags[_TILE_WIDTH], tags[_TILE_LENGTH]
    else:  # rows per strip beyond the height (often 2**32 - 1): one strip
        across, down = width, min(tags.get(_ROWS_PER_STRIP, height), height)
    if not across > 0 < down:
        raise ValueError(f"strips or tiles of {across} x {down} pixels")
    where = {_TILE_WIDTH: across, _TILE_LENGTH: down} if tiled else {_ROWS_PER_STRIP: down}
    per_plane = -(-width // across) * -(-height // down)
    planes = tags.get(_SAMPLES_PER_PIXEL, 1)
    offsets_tag, counts_tag = (_TILE_OFFSETS, _TILE_COUNTS) if tiled else _STRIPS
    offsets = tags[offsets_tag]
    # Uncompressed, each strip's rows or each tile whole at 2 bytes a sample, as Pillow's
    # own reader takes them whatever the byte counts say; compressed, the byte counts
    # (libtiff's), else those sizes up to the file's end at most.
    stored = tags.get(counts_tag)
    raw = tags.get(_COMPRESSION, 1) == 1
    counts = (
        stored
        if stored and not raw
        else [
            2 * across * (down if tiled else min(down, height - k % per_plane * down))
            for k in range(len(offsets))
        ]
    )
    if min(len(offsets), len(counts)) < planes * per_plane:
        raise ValueError(f"{len(offsets)} strip or tile offsets for {planes} planes")
    kept = {tag: tags[tag] for tag in _PLANE_TAGS if tag in tags}
    order = "<" if tags.prefix == b"II" else ">"
    view = memoryview(data)
    samples = np.empty((height, width, planes), np.uint16)
    for plane in range(planes):
        part = range(plane * per_plane, (plane + 1) * per_plane)
        pieces = [view[offsets[k] : offsets[k] + counts[k]] for k in part]  # no copies
        short = [k for k, piece in zip(part, pieces, strict=True) if len(piece) < counts[k]]
        if short and (raw or stored):
            raise ValueError(f"truncated: strip or tile {short[0]} ends past the file's end")
        starts = np.cumsum([8] + [len(piece) for piece in pieces])
        at = int(starts[-1] + starts[-1] % 2)  # the directory, on a word boundary
        fields = {
            **kept,
            _IMAGE_WIDTH: width,
            _IMAGE_LENGTH: height,
            _BITS_PER_SAMPLE: 16,
            PHOTOMETRIC: 1,
            _SAMPLES_PER_PIXEL: 1,
            _PLANAR: 1,
            **where,
            offsets_tag: tuple(int(start) for start in starts[:-1]),
            counts_tag: tuple(len(piece) for piece in pieces),
        }
        head = tags.prefix + struct.pack(order + "HI", 42, at)
        tail = bytes(at - int(starts[-1])) + _directory(fields, order, at)
        with Image.open(io.BytesIO(b"".join([head, *pieces, tail]))) as page:
            for r0 in range(0, height, CHUNK_ROWS):  # a band at a time: no plane-sized copy
                band = page.crop((0, r0, width, min(r0 + CHUNK_ROWS, height)))
                samples[r0 : r0 + CHUNK_ROWS, :, plane] = np.asarray(band)
    return samples


def _directory(fields: dict[int, Any], order: str, at: int) -> bytes:
    """A TIFF's one directory written at ``at``, its values after its entries.

    Values are SHORT or LONG by tag (:data:`_LONG_TAGS`), bytes UNDEFINED.
    """
    entries, values = b"", b""
    values_at = at + 2 + 12 * len(fields) + 4
    for tag, value in sorted(fields.items()):
        if isinstance(value, bytes):
            kind, count, raw = 7, len(value), value
        else:
            items = tuple(value) if isinstance(value, tuple) else (value,)
            code = "I" if tag in _LONG_TAGS else "H"
            kind, count = 4 if code == "I" else 3, len(items)
            raw = struct.pack(f"{order}{count}{code}", *items)
        if len(raw) <= 4:
            entries += struct.pack(order + "HHI", tag, kind, count) + raw.ljust(4, b"\0")
        else:
            entries += struct.pack(order + "HHII", tag, kind, count, values_at + len(values))
            values += raw + bytes(len(raw) % 2)
    return struct.pack(order + "H", len(fields)) + entries + bytes(4) + values


def _unpremultiply(samples: np.ndarray) -> None:
    """Colour divided by alpha (the last channel) in place, where alpha > 0, rounded."""
    for r0 in range(0, samples.shape[0], CHUNK_ROWS):
        block = samples[r0 : r0 + CHUNK_ROWS]
        alpha = block[..., -1:].astype(np.uint32)
        colour = block[..., :-1].astype(np.uint32)
        straight = (colour * 65535 + alpha // 2) // np.maximum(alpha, 1)
        block[..., :-1] = np.where(alpha > 0, np.minimum(straight, 65535), colour)


def naive_rgb(cmyk: np.ndarray) -> np.ndarray:
    """16-bit CMYK to RGB as Pillow converts CMYK without a profile, ``(1 - C)(1 - K)``.

    Each channel is 1 minus its ink times 1 minus black, rounded to a 16-bit code.
    """
    rgb = np.empty((*cmyk.shape[:2], 3), np.uint16)
    for r0 in range(0, cmyk.shape[0], CHUNK_ROWS):
        paper = 65535 - cmyk[r0 : r0 + CHUNK_ROWS].astype(np.uint32)
        rgb[r0 : r0 + CHUNK_ROWS] = (paper[..., :3] * paper[..., 3:] + 32767) // 65535
    return rgb


def orientation(opened: Image.Image) -> int | None:
    """The image's orientation (EXIF, TIFF tag or XMP), None where it has none.

    A TIFF's ``load()`` turns the picture it decodes and drops the tag; read before it, it
    says how to turn samples read from the file's bytes (:func:`_planes`).
    """
    found = opened.getexif().get(ExifTags.Base.Orientation)
    return int(found) if found is not None else None


def upright(samples: np.ndarray, orientation: int | None) -> np.ndarray:
    """Samples turned as ``ImageOps.exif_transpose`` turns an image of that orientation."""
    exif = Image.Exif()
    if orientation is None:
        return samples
    exif[ExifTags.Base.Orientation] = orientation
    channels = []
    for c in range(samples.shape[2]):
        channel = Image.fromarray(np.ascontiguousarray(samples[..., c]))
        channel.info["exif"] = exif.tobytes()
        channels.append(np.asarray(ImageOps.exif_transpose(channel)))
    return np.stack(channels, axis=-1)
