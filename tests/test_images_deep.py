"""Deep images: 16-bit colour PNGs and TIFFs (Pillow opens them at 8 bits), float TIFFs."""

from __future__ import annotations

import itertools
import struct
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_images import (
    D50,
    LUMA,
    P3_COLORANTS,
    P3_LUMA,
    SRGB_CURV,
    _chrm,
    curv_gamma,
    eotf,
    gamma_of,
    gray_icc,
    icc,
    needs_lcms,
    rgb_icc,
    srgb_colorants,
    xyz_tag,
)

from scratchfab.design.images import load_image
from scratchfab.errors import ConfigError

#: PNG colour types with 16-bit samples: grey and alpha, RGB, RGBA.
CHANNELS = {4: 2, 2: 3, 6: 4}


def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else b if pb <= pc else c


def _filtered(rows: list[bytes], bpp: int) -> bytes:
    """Each row filtered with type (row % 5): None, Sub, Up, Average, Paeth (PNG spec 9.2)."""
    out = b""
    prior = bytes(len(rows[0]))
    for r, row in enumerate(rows):
        kind = r % 5
        line = bytearray()
        for i, x in enumerate(row):
            a = row[i - bpp] if i >= bpp else 0
            b = prior[i]
            c = prior[i - bpp] if i >= bpp else 0
            predictor = (0, a, b, (a + b) // 2, _paeth(a, b, c))[kind]
            line.append((x - predictor) % 256)
        out += bytes([kind]) + bytes(line)
        prior = row
    return out


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


#: Adam7 passes: first column, first row, column step, row step (PNG spec 8.2).
ADAM7 = (
    (0, 0, 8, 8),
    (4, 0, 8, 8),
    (0, 4, 4, 8),
    (2, 0, 4, 4),
    (0, 2, 2, 4),
    (1, 0, 2, 2),
    (0, 1, 1, 2),
)


def write_png16(
    path: Path, samples: np.ndarray, *chunks: tuple[bytes, bytes], interlace: bool = False
) -> None:
    """A 16-bit PNG written by hand (Pillow cannot), chunks before IDAT except eXIf after."""
    h, w, c = samples.shape
    colour_type = {v: k for k, v in CHANNELS.items()}[c]
    passes = ADAM7 if interlace else ((0, 0, 1, 1),)
    body = b""
    for x0, y0, dx, dy in passes:
        sub = samples[y0::dy, x0::dx]
        if sub.size:  # each pass filtered on its own (an empty pass has no rows)
            body += _filtered([row.astype(">u2").tobytes() for row in sub], 2 * c)
    head = _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, int(interlace)))
    before = b"".join(_chunk(k, d) for k, d in chunks if k != b"eXIf")
    after = b"".join(_chunk(k, d) for k, d in chunks if k == b"eXIf")
    idat = _chunk(b"IDAT", zlib.compress(body))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + head + before + idat + after + _chunk(b"IEND", b""))


def _packbits(data: bytes) -> bytes:
    """PackBits (TIFF 6.0 section 9): literal runs of up to 128 bytes, each after its length - 1."""
    return b"".join(
        bytes([len(run) - 1]) + run for run in (data[i : i + 128] for i in range(0, len(data), 128))
    )


def _lzw(data: bytes) -> bytes:
    """TIFF LZW (section 13), each byte its own 9-bit code: a Clear code every 250 codes keeps
    the decoder's table (one entry a code) short of 511, where codes would widen to 10 bits.
    """
    codes = []
    for i in range(0, len(data), 250):
        codes += [256, *data[i : i + 250]]
    codes.append(257)  # EndOfInformation
    bits = "".join(f"{code:09b}" for code in codes)
    bits += "0" * (-len(bits) % 8)
    return int(bits, 2).to_bytes(len(bits) // 8, "big") if bits else b""


def write_tiff(
    path: Path,
    samples: np.ndarray,
    order: str = "<",
    deflate: bool = False,
    rows_per_strip: int | None = None,
    orientation: int | None = None,
    extra_samples: int = 2,
    photometric: int | None = None,
    icc: bytes | None = None,
    planar: bool = False,
    tile: tuple[int, int] | None = None,
    compression: str | None = None,
    byte_counts: bool = True,
) -> None:
    """A TIFF of the samples' type written by hand (Pillow cannot write 16-bit colour).

    ``compression`` is "deflate" (``deflate=True``) or "lzw", each with horizontal
    differencing (integer samples only), or "packbits"; a fourth (second) sample is
    ``extra_samples`` (TIFF 6.0: 0 unspecified, 1 associated alpha, 2 alpha) unless
    ``photometric`` is 5 (CMYK: four inks); ``icc`` is an embedded ICC profile.
    ``planar`` stores each sample's plane after the other's (PlanarConfiguration 2);
    ``tile`` (width, length) stores tiles, padded where they overhang, not strips.
    Without ``byte_counts`` the strips' or tiles' byte counts are left out.
    """
    h, w, c = samples.shape
    compression = compression or ("deflate" if deflate else None)
    predictor = compression in ("deflate", "lzw")
    rows_per_strip = rows_per_strip or h
    planes = [samples[..., i : i + 1] for i in range(c)] if planar else [samples]
    if tile:
        tw, th = tile
        blocks = []
        for plane in planes:
            for y in range(0, h, th):
                for x in range(0, w, tw):
                    block = np.zeros((th, tw, plane.shape[2]), samples.dtype)
                    part = plane[y : y + th, x : x + tw]
                    block[: part.shape[0], : part.shape[1]] = part
                    blocks.append(block)
    else:
        blocks = [p[r : r + rows_per_strip] for p in planes for r in range(0, h, rows_per_strip)]
    if predictor:  # predictor 2: each sample minus its left neighbour (in its block), mod 2**16
        blocks = [b.astype(np.int64) for b in blocks]
        for block in blocks:
            block[:, 1:] = (block[:, 1:] - block[:, :-1]) % 65536
    strips = [block.astype(samples.dtype.newbyteorder(order)).tobytes() for block in blocks]
    encode = {"deflate": zlib.compress, "lzw": _lzw, "packbits": _packbits, None: bytes}
    strips = [encode[compression](strip) for strip in strips]
    n = len(strips)
    tags = {
        256: (4, [w]),
        257: (4, [h]),
        258: (3, [samples.dtype.itemsize * 8] * c),
        259: (3, [{"deflate": 8, "lzw": 5, "packbits": 32773, None: 1}[compression]]),
        262: (3, [(2 if c >= 3 else 1) if photometric is None else photometric]),
        277: (3, [c]),
        284: (3, [2 if planar else 1]),
        317: (3, [2 if predictor else 1]),
        339: (3, [3 if samples.dtype.kind == "f" else 1] * c),
    }
    offsets_tag = 324 if tile else 273
    if tile:
        tags.update({322: (4, [tile[0]]), 323: (4, [tile[1]]), 325: (4, [len(x) for x in strips])})
    else:
        tags.update({278: (4, [rows_per_strip]), 279: (4, [len(x) for x in strips])})
    if not byte_counts:
        del tags[325 if tile else 279]
    tags[offsets_tag] = (4, [0] * n)
    if c % 2 == 0 and photometric != 5:
        tags[338] = (3, [extra_samples])
    if icc is not None:
        tags[34675] = (7, list(icc))
    if orientation:
        tags[274] = (3, [orientation])

    def layout(data_at: int) -> tuple[bytes, bytes]:
        tags[offsets_tag] = (4, list(data_at + np.cumsum([0] + [len(x) for x in strips[:-1]])))
        extra_at = 8 + 2 + 12 * len(tags) + 4
        ifd, extra = struct.pack(order + "H", len(tags)), b""
        for tag, (kind, values) in sorted(tags.items()):
            raw = struct.pack(order + {3: "H", 4: "I", 7: "B"}[kind] * len(values), *values)
            if len(raw) <= 4:
                ifd += struct.pack(order + "HHI", tag, kind, len(values)) + raw.ljust(4, b"\0")
            else:
                ifd += struct.pack(order + "HHII", tag, kind, len(values), extra_at + len(extra))
                extra += raw + bytes(len(raw) % 2)  # offsets stay even (TIFF 6.0)
        return ifd + bytes(4), extra

    ifd, extra = layout(0)
    ifd, extra = layout(8 + len(ifd) + len(extra))
    head = (b"II*\0" if order == "<" else b"MM\0*") + struct.pack(order + "I", 8)
    path.write_bytes(head + ifd + extra + b"".join(strips))


def reference(samples: np.ndarray, decode=None, weights=LUMA) -> np.ndarray:
    """Luminance written out pixel by pixel: decode each sample, weigh, times alpha."""
    decode = decode or eotf
    h, w, c = samples.shape
    out = np.empty((h, w))
    for r in range(h):
        for col in range(w):
            s = [int(v) / 65535 for v in samples[r, col]]
            colour = s[:3] if c >= 3 else s[:1]
            lum = sum(wt * decode(v) for wt, v in zip(weights, colour, strict=True))
            out[r, col] = lum * (s[-1] if c % 2 == 0 else 1.0)
    return out


def random_samples(c: int, shape=(9, 13), seed=5) -> np.ndarray:
    samples = np.random.default_rng(seed).integers(0, 65536, (*shape, c), dtype=np.uint16)
    samples[0, :3] = 1000  # neighbours one code apart, that 8 bits would merge
    samples[0, 1] = 1001
    return samples


def peak_of_a_second_load(path: Path) -> int:
    """Python's peak memory (bytes) while ``load_image`` reads ``path`` a second time.

    The first load warms Pillow's plugins and caches; the second must give the same array.
    """
    expected = load_image(path)
    tracemalloc.start()
    try:
        got = load_image(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(got, expected)
    return int(peak)


@pytest.mark.parametrize("interlace", [False, True])
@pytest.mark.parametrize("colour_type", [2, 6, 4])
def test_16bit_colour_png_keeps_every_bit(tmp_path, colour_type, interlace):
    c = CHANNELS[colour_type]
    samples = random_samples(c)
    path = tmp_path / "deep.png"
    write_png16(path, samples, interlace=interlace)
    with Image.open(path) as im:  # what Pillow alone gives: 8 bits
        assert im.mode in ("RGB", "RGBA")
    got = load_image(path)
    weights = LUMA if c >= 3 else (1.0,)
    np.testing.assert_allclose(got, reference(samples, weights=weights), rtol=0, atol=1e-12)
    assert got[0, 0] < got[0, 1]  # codes 1000 and 1001 stay apart


def test_16bit_png_gama_and_chrm_apply(tmp_path):
    samples = random_samples(3)
    path = tmp_path / "g.png"
    write_png16(path, samples, (b"gAMA", struct.pack(">I", 100000)))
    np.testing.assert_allclose(
        load_image(path), reference(samples, decode=lambda v: v), rtol=0, atol=1e-12
    )
    p3 = _chrm((0.3127, 0.3290), (0.680, 0.320), (0.265, 0.690), (0.150, 0.060))
    write_png16(path, samples, (b"gAMA", struct.pack(">I", 100000)), (b"cHRM", p3))
    expected = reference(samples, decode=lambda v: v, weights=P3_LUMA)
    np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=1e-4)


@needs_lcms
def test_16bit_png_with_srgb_profile_reads_like_no_profile(tmp_path):
    samples = random_samples(3)
    path = tmp_path / "s.png"
    write_png16(
        path, samples, (b"iCCP", b"x\0\0" + zlib.compress(rgb_icc(SRGB_CURV, srgb_colorants())))
    )
    got = load_image(path)
    # The profile's curve is a 4096-entry table; 8-bit decoding would be off by ~1e-3.
    np.testing.assert_allclose(got, reference(samples), rtol=0, atol=5e-5)
    assert got[0, 0] < got[0, 1]


@needs_lcms
def test_16bit_display_p3_gamma_profile(tmp_path):
    samples = random_samples(4)
    icc = rgb_icc(curv_gamma(1.8), P3_COLORANTS)
    path = tmp_path / "p3.png"
    write_png16(path, samples, (b"iCCP", b"x\0\0" + zlib.compress(icc)))
    expected = reference(samples, decode=lambda v: v ** gamma_of(1.8), weights=P3_LUMA)
    got = load_image(path)
    # P3_LUMA is the published D65 figure; the profile's colorants are rounded D50 ones.
    np.testing.assert_allclose(got, expected, rtol=0, atol=2e-4)
    assert got[0, 0] < got[0, 1]


@needs_lcms
def test_16bit_gray_and_alpha_with_gray_profile(tmp_path):
    samples = random_samples(2)
    path = tmp_path / "la.png"
    write_png16(path, samples, (b"iCCP", b"x\0\0" + zlib.compress(gray_icc(curv_gamma(1.8)))))
    expected = reference(samples, decode=lambda v: v ** gamma_of(1.8), weights=(1.0,))
    np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=3e-5)


def test_truncated_16bit_png_fails_with_one_line(tmp_path):
    path = tmp_path / "cut.png"
    write_png16(path, random_samples(3, shape=(40, 40)))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ConfigError) as info:
        load_image(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("c", "order", "deflate", "rows"),
    [(3, "<", False, None), (3, ">", False, 2), (3, "<", True, None), (4, ">", True, 4)],
)
def test_16bit_colour_tiff_keeps_every_bit(tmp_path, c, order, deflate, rows):
    samples = random_samples(c)
    path = tmp_path / "deep.tif"
    write_tiff(path, samples, order, deflate, rows)
    with Image.open(path) as im:  # what Pillow alone gives: 8 bits
        assert im.mode in ("RGB", "RGBA")
    got = load_image(path)
    np.testing.assert_allclose(got, reference(samples), rtol=0, atol=1e-12)
    assert got[0, 0] < got[0, 1]


def test_16bit_tiff_orientation_tag_turns_it_upright(tmp_path):
    samples = random_samples(3, shape=(6, 10))
    path = tmp_path / "turned.tif"
    write_tiff(path, samples, deflate=True, orientation=6)
    np.testing.assert_allclose(load_image(path), np.rot90(reference(samples), -1), atol=1e-12)


#: Each TIFF/EXIF orientation as numpy turns the stored (rows, cols) picture upright.
UPRIGHT = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1, :],
    5: lambda a: a.swapaxes(0, 1),
    6: lambda a: np.rot90(a, -1),
    7: lambda a: a[::-1, ::-1].swapaxes(0, 1),
    8: lambda a: np.rot90(a, 1),
}


@pytest.mark.parametrize(
    ("planar", "compression"),
    [(False, None), (True, None), (True, "deflate")],
    ids=["chunky", "planar", "planar-deflate"],
)
@pytest.mark.parametrize("turn", sorted(UPRIGHT))
def test_16bit_tiff_each_orientation_in_either_layout(tmp_path, planar, compression, turn):
    """Separate planes, read again plane by plane, are turned too (a reviewer: Pillow's
    TIFF load turns what it decodes and drops the tag, so they came back as stored)."""
    samples = random_samples(3, shape=(5, 9))
    path = tmp_path / "turned.tif"
    write_tiff(
        path,
        samples,
        "<",
        rows_per_strip=2,
        planar=planar,
        orientation=turn,
        compression=compression,
    )
    expected = UPRIGHT[turn](reference(samples))
    np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "samples",
    [
        np.full((2, 3, 3), 0.5, np.float32),
        np.full((2, 3, 1), 0.5, np.float16),
    ],
    ids=["float-rgb", "half-float-grey"],
)
def test_tiff_pillow_cannot_read_is_a_clear_error(tmp_path, samples):
    path = tmp_path / "float.tif"
    write_tiff(path, samples)
    with pytest.raises(ConfigError) as info:
        load_image(path)
    text = str(info.value)
    assert str(path) in text and "TIFF" in text and "expected" in text and "\n" not in text


def test_float_tiff_without_profile_is_srgb_encoded_per_spec(tmp_path):
    values = np.array([[0.0, 0.02, 0.5, 1.0, 1.004, -0.004]], np.float32)
    path = tmp_path / "f.tif"
    Image.fromarray(values).save(path)
    expected = [eotf(min(max(float(v), 0.0), 1.0)) for v in values[0]]
    np.testing.assert_allclose(load_image(path)[0], expected, rtol=0, atol=1e-7)


@needs_lcms
def test_float_tiff_with_linear_profile_is_linear(tmp_path):
    values = np.linspace(0.0, 1.0, 201, dtype=np.float32)[None]
    path = tmp_path / "lin.tif"
    Image.fromarray(values).save(path, icc_profile=gray_icc(curv_gamma(1.0)))
    np.testing.assert_allclose(load_image(path)[0], values[0], rtol=0, atol=3e-5)


def test_hdr_float_tiff_is_refused_not_clipped(tmp_path):
    values = np.full((3, 4), 0.5, np.float32)
    values[1, 2] = 3.5
    values[2, 0] = -0.2
    path = tmp_path / "hdr.tif"
    Image.fromarray(values).save(path)
    with pytest.raises(ConfigError) as info:
        load_image(path)
    text = str(info.value)
    assert text.startswith(f"{path}: pixel (row 1, column 2) is 3.5; expected brightness in [0, 1]")
    assert "(2 pixels are outside)" in text and "SPEC section 5" in text and "\n" not in text


@needs_lcms
def test_8bit_and_16bit_with_matrix_profile_agree_even_out_of_srgb_gamut(tmp_path):
    codes = np.random.default_rng(8).integers(0, 256, (6, 7, 3), dtype=np.uint8)
    codes[0, 0] = (0, 255, 0)  # Display P3's green: far outside sRGB's gamut
    icc = rgb_icc(curv_gamma(1.8), P3_COLORANTS)
    Image.fromarray(codes).save(tmp_path / "p8.png", icc_profile=icc)
    deep = codes.astype(np.uint16) * 257  # the same colours at 16 bits
    write_png16(tmp_path / "p16.png", deep, (b"iCCP", b"x\0\0" + zlib.compress(icc)))
    expected = reference(deep, decode=lambda v: v ** gamma_of(1.8), weights=P3_LUMA)
    got8 = load_image(tmp_path / "p8.png")
    # Not rounded to 8-bit sRGB (up to 0.0045 off) nor clipped to its gamut.
    np.testing.assert_allclose(got8, expected, rtol=0, atol=2e-4)
    np.testing.assert_allclose(load_image(tmp_path / "p16.png"), got8, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("h", "w"), [(1, 1), (1, 2), (2, 1), (3, 3), (5, 7), (1, 9), (9, 1), (9, 9)]
)
@pytest.mark.parametrize("colour_type", [2, 6, 4])
def test_tiny_interlaced_16bit_pngs_with_empty_adam7_passes(tmp_path, colour_type, h, w):
    c = CHANNELS[colour_type]
    samples = np.random.default_rng(h * 31 + w).integers(0, 65536, (h, w, c), dtype=np.uint16)
    samples.reshape(-1, c)[0] = 0
    samples.reshape(-1, c)[-1] = 65535
    path = tmp_path / "tiny.png"
    write_png16(path, samples, interlace=True)
    weights = LUMA if c >= 3 else (1.0,)
    np.testing.assert_allclose(
        load_image(path), reference(samples, weights=weights), rtol=0, atol=1e-12
    )


def test_16bit_tiff_with_unspecified_fourth_sample_ignores_it(tmp_path):
    samples = random_samples(4)
    path = tmp_path / "rgbx.tif"
    write_tiff(path, samples, ">", deflate=True, extra_samples=0)
    got = load_image(path)
    np.testing.assert_allclose(got, reference(samples[..., :3]), rtol=0, atol=1e-12)
    assert got[0, 0] < got[0, 1]


def _mft2_linear(colorants, swap: bool) -> bytes:
    """An ICC lut16Type (A2B0) table: linear R, G, B (B, G, R when ``swap``) to PCS XYZ.

    A 2-point grid interpolates a linear map exactly; XYZ is encoded 1.0 = 0x8000.
    """
    m = np.array(colorants).T
    head = b"mft2" + bytes(4) + bytes([3, 3, 2, 0])
    head += b"".join(struct.pack(">i", 65536 * (i % 4 == 0)) for i in range(9))
    ramp = struct.pack(">HHHHHHHH", 2, 2, 0, 65535, 0, 65535, 0, 65535)
    grid = []
    for r, g, b in itertools.product((0, 1), repeat=3):
        grid += [min(65535, round(v * 32768)) for v in m @ ((b, g, r) if swap else (r, g, b))]
    return head + ramp + struct.pack(f">{len(grid)}H", *grid) + ramp[4:]


@needs_lcms
def test_profile_with_matrix_and_a2b0_table_follows_the_table(tmp_path):
    # littleCMS converts by A2B0 when a profile has both; the table swaps red and blue.
    tags = {b"wtpt": xyz_tag(D50), b"A2B0": _mft2_linear(srgb_colorants(), swap=True)}
    for ch, xyz in zip("rgb", srgb_colorants(), strict=True):
        tags[f"{ch}XYZ".encode()] = xyz_tag(xyz)
        tags[f"{ch}TRC".encode()] = curv_gamma(1.0)
    codes = np.random.default_rng(3).integers(0, 256, (5, 6, 3), dtype=np.uint8)
    codes[0, :3] = np.eye(3, dtype=np.uint8) * 255  # red, green, blue
    path = tmp_path / "a2b.png"
    Image.fromarray(codes).save(path, icc_profile=icc(b"RGB ", tags))
    expected = (codes[..., ::-1] / 255.0) @ LUMA  # linear and swapped, then Rec. 709
    # Through 8-bit sRGB: within half an 8-bit code (0.0045 of full scale near white).
    np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=5e-3)


@needs_lcms
def test_lut_profile_keeps_alpha_and_16bit_colour_key(tmp_path):
    profile = icc(b"RGB ", {b"wtpt": xyz_tag(D50), b"A2B0": _mft2_linear(srgb_colorants(), False)})
    rgba = np.array([[[255, 255, 255, 255], [255, 255, 255, 51], [0, 0, 255, 128]]], np.uint8)
    Image.fromarray(rgba).save(tmp_path / "a.png", icc_profile=profile)
    iccp = b"x\0\0" + zlib.compress(profile)
    expected = (rgba[0, :, :3] / 255.0) @ LUMA * rgba[0, :, 3] / 255.0
    np.testing.assert_allclose(load_image(tmp_path / "a.png")[0], expected, rtol=0, atol=5e-3)
    # The key's 8-bit high bytes (156) and low bytes (64) are both other pixels' colours.
    deep = np.array([[[40000] * 3, [156 * 257] * 3, [64 * 257] * 3, [30000, 20000, 10000]]])
    key = (b"tRNS", struct.pack(">3H", *deep[0, 0]))
    write_png16(tmp_path / "k.png", deep.astype(np.uint16), (b"iCCP", iccp), key)
    expected = (deep[0] / 65535.0) @ LUMA
    expected[0] = 0.0  # the key colour: transparent, and only it
    np.testing.assert_allclose(load_image(tmp_path / "k.png")[0], expected, rtol=0, atol=5e-3)


@needs_lcms
def test_16bit_rgb_with_lut_profile_reads_between_8bit_codes(tmp_path):
    # littleCMS converts 8-bit codes: 16-bit ones 257 c read as the 8-bit file, and those
    # between move in a straight line from one code's picture to the next's.
    profile = icc(b"RGB ", {b"wtpt": xyz_tag(D50), b"A2B0": _mft2_linear(srgb_colorants(), True)})
    iccp = (b"iCCP", b"x\0\0" + zlib.compress(profile))
    codes = np.random.default_rng(23).integers(0, 256, (4, 9, 4), dtype=np.uint8)
    Image.fromarray(codes).save(tmp_path / "rgba8.png", icc_profile=profile)
    write_png16(tmp_path / "rgba16.png", codes.astype(np.uint16) * 257, iccp)
    eight = load_image(tmp_path / "rgba8.png")
    np.testing.assert_array_equal(load_image(tmp_path / "rgba16.png"), eight)
    green = np.arange(0, 65536, 61, dtype=np.uint16)
    ramp16 = np.zeros((1, len(green), 3), np.uint16)
    ramp16[..., 0], ramp16[..., 1], ramp16[..., 2] = 257 * 30, green, 257 * 220
    write_png16(tmp_path / "ramp16.png", ramp16, iccp)
    ramp8 = np.zeros((1, 256, 3), np.uint8)
    ramp8[..., 0], ramp8[..., 1], ramp8[..., 2] = 30, np.arange(256), 220
    Image.fromarray(ramp8).save(tmp_path / "ramp8.png", icc_profile=profile)
    expected = np.interp(green / 257.0, np.arange(256), load_image(tmp_path / "ramp8.png")[0])
    np.testing.assert_allclose(load_image(tmp_path / "ramp16.png")[0], expected, rtol=0, atol=1e-12)


def test_16bit_png_is_read_without_spare_copies(tmp_path):
    # Python-visible memory at the peak: the file's bytes (6 bytes a pixel, incompressible)
    # and the 16-bit samples (6) with two 8-bit planes (3 each) while decoding, then the
    # samples, the luminance (8) and a few rows in hand. A spare copy of the luminance, or
    # the file's bytes kept past decoding, would pass the budget.
    h, w = 4000, 250
    samples = random_samples(3, shape=(h, w))
    rows = samples.astype(">u2").reshape(h, -1).view(np.uint8)
    body = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()  # filter None
    head = _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
    idat = _chunk(b"IDAT", zlib.compress(body, 1))
    path = tmp_path / "big.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + head + idat + _chunk(b"IEND", b""))
    peak = peak_of_a_second_load(path)
    assert peak < path.stat().st_size + h * w * 14
