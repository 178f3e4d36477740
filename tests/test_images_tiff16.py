"""16-bit TIFFs Pillow reads at 8 bits or not at all: CMYK, premultiplied alpha, grey+alpha."""

from __future__ import annotations

import itertools
import struct

import numpy as np
import pytest
from PIL import Image, TiffImagePlugin, UnidentifiedImageError
from test_images import (
    cmyk_k_only_icc,
    cmyk_lut_icc,
    curv_gamma,
    eotf,
    gamma_of,
    gray_icc,
    needs_lcms,
)
from test_images_deep import (
    peak_of_a_second_load,
    random_samples,
    reference,
    write_png16,
    write_tiff,
)

from scratchfab.design.images import load_image
from scratchfab.errors import ConfigError

#: Byte order, deflate (libtiff decodes) or not (Pillow's raw reader), rows per strip.
LAYOUTS = [("<", False, None), (">", False, 2), ("<", True, None), (">", True, 4)]


def premultiplied(straight: np.ndarray) -> np.ndarray:
    """Colour times alpha (the last sample), rounded to 16-bit codes, as associated alpha."""
    s = straight.astype(np.float64)
    out = straight.copy()
    out[..., :-1] = np.round(s[..., :-1] * s[..., -1:] / 65535)
    return out


def reference_premultiplied(stored: np.ndarray, weights) -> np.ndarray:
    """Luminance of associated-alpha samples, pixel by pixel: colour / alpha, decoded, x alpha."""
    h, w, _ = stored.shape
    out = np.zeros((h, w))
    for r in range(h):
        for col in range(w):
            *colour, alpha = (int(v) for v in stored[r, col])
            if alpha:
                straight = (min(c / alpha, 1.0) for c in colour)
                lum = sum(wt * eotf(v) for wt, v in zip(weights, straight, strict=True))
                out[r, col] = lum * alpha / 65535
    return out


def with_edge_alphas(stored: np.ndarray) -> np.ndarray:
    """Samples whose first pixels have alpha 0 (with and without colour) and 1 and full."""
    stored = stored.copy()
    stored[0, 0, :] = 0
    stored[0, 1, :-1], stored[0, 1, -1] = 500, 0  # colour where nothing shows: still black
    stored[0, 2, :-1], stored[0, 2, -1] = 1, 1  # colour = alpha: white at the faintest alpha
    stored[0, 3, -1] = 65535
    return stored


@pytest.mark.parametrize(("order", "deflate", "rows"), LAYOUTS)
def test_16bit_grey_and_alpha_tiff_keeps_every_bit(tmp_path, order, deflate, rows):
    samples = random_samples(2)
    path = tmp_path / "la.tif"
    write_tiff(path, samples, order, deflate, rows)
    got = load_image(path)
    np.testing.assert_allclose(got, reference(samples, weights=(1.0,)), rtol=0, atol=1e-12)
    # Read without leaving Pillow's table of TIFF layouts changed: alone, it still refuses.
    with pytest.raises(UnidentifiedImageError):
        Image.open(path)
    assert not any(key[4] == (16, 16) for key in TiffImagePlugin.OPEN_INFO)


@pytest.mark.parametrize(("order", "deflate", "rows"), LAYOUTS)
def test_16bit_grey_tiff_with_associated_alpha_is_divided_out(tmp_path, order, deflate, rows):
    stored = with_edge_alphas(premultiplied(random_samples(2, seed=11)))
    path = tmp_path / "la_assoc.tif"
    write_tiff(path, stored, order, deflate, rows, extra_samples=1)
    expected = reference_premultiplied(stored, (1.0,))
    got = load_image(path)
    # Straight colour rounded to a 16-bit code: half a code times the curve's slope (<2.3).
    np.testing.assert_allclose(got, expected, rtol=0, atol=2e-5)
    assert got[0, 1] == 0.0 and got[0, 2] == pytest.approx(1 / 65535, abs=1e-12)


def test_16bit_grey_tiff_with_unspecified_second_sample_ignores_it(tmp_path):
    samples = random_samples(2)
    path = tmp_path / "lx.tif"
    write_tiff(path, samples, ">", deflate=True, extra_samples=0)
    np.testing.assert_allclose(
        load_image(path), reference(samples[..., :1], weights=(1.0,)), rtol=0, atol=1e-12
    )


def test_16bit_grey_and_alpha_tiff_orientation_turns_it_upright(tmp_path):
    samples = random_samples(2, shape=(6, 10))
    path = tmp_path / "turned.tif"
    write_tiff(path, samples, "<", deflate=True, orientation=8)
    expected = np.rot90(reference(samples, weights=(1.0,)), 1)
    np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=1e-12)


@needs_lcms
def test_16bit_grey_and_alpha_tiff_with_gray_profile(tmp_path):
    samples = random_samples(2)
    path = tmp_path / "la_icc.tif"
    write_tiff(path, samples, ">", icc=gray_icc(curv_gamma(1.8)))
    expected = reference(samples, decode=lambda v: v ** gamma_of(1.8), weights=(1.0,))
    np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=3e-5)


@pytest.mark.parametrize(("order", "deflate", "rows"), LAYOUTS)
def test_16bit_rgb_tiff_with_associated_alpha_is_divided_out(tmp_path, order, deflate, rows):
    stored = with_edge_alphas(premultiplied(random_samples(4, seed=12)))
    path = tmp_path / "rgba_assoc.tif"
    write_tiff(path, stored, order, deflate, rows, extra_samples=1)
    with Image.open(path) as im:  # what Pillow alone gives: 8 bits
        assert im.mode == "RGBA"
    expected = reference_premultiplied(stored, (0.2126, 0.7152, 0.0722))
    got = load_image(path)
    np.testing.assert_allclose(got, expected, rtol=0, atol=2e-5)
    assert got[0, 1] == 0.0 and got[0, 2] == pytest.approx(1 / 65535, abs=1e-12)


def test_16bit_rgb_tiff_with_associated_alpha_inverts_the_straight_colour(tmp_path):
    # Half-transparent mid grey: straight 0.5 inverts to 0.5, then composites at half.
    stored = np.array([[[16384, 16384, 16384, 32768], [0, 0, 0, 32768]]], np.uint16)
    path = tmp_path / "inv.tif"
    write_tiff(path, stored, extra_samples=1)
    got = load_image(path, invert=True)[0]
    np.testing.assert_allclose(got, [eotf(0.5) * 32768 / 65535, 32768 / 65535], atol=2e-5)


def naive_cmyk_luminance(cmyk: np.ndarray) -> np.ndarray:
    """Pillow's conversion without a profile, R = (1 - C)(1 - K), in floats, then Rec. 709."""
    ink = cmyk / 65535.0
    rgb = (1.0 - ink[..., :3]) * (1.0 - ink[..., 3:])
    return np.vectorize(eotf)(rgb) @ np.array([0.2126, 0.7152, 0.0722])


@pytest.mark.parametrize(("order", "deflate", "rows"), LAYOUTS)
def test_16bit_cmyk_tiff_without_profile_keeps_every_bit(tmp_path, order, deflate, rows):
    cmyk = random_samples(4, seed=13)
    cmyk[0, :4] = (0, 0, 0, 1000)  # black ink 1000 and 1001 codes: one 8-bit code
    cmyk[0, 1, 3] = 1001
    path = tmp_path / "cmyk.tif"
    write_tiff(path, cmyk, order, deflate, rows, photometric=5)
    with Image.open(path) as im:  # what Pillow alone gives: 8 bits
        assert im.mode == "CMYK"
    got = load_image(path)
    np.testing.assert_allclose(got, naive_cmyk_luminance(cmyk), rtol=0, atol=2e-5)
    assert got[0, 0] > got[0, 1]


def colourful_cmyk_icc() -> bytes:
    """A CMYK profile in which every ink darkens and tints (a 2-point grid, multilinear)."""
    c, m, y, k = np.meshgrid(*[np.arange(2)] * 4, indexing="ij")
    grid = np.stack(
        [
            255 - 60 * c - 45 * m - 25 * y - 120 * k,
            128 - 50 * c + 60 * m,
            128 - 30 * c - 70 * y + 10 * m,
        ],
        axis=-1,
    )
    return cmyk_lut_icc(grid.astype(np.uint8))


def cmyk8_file(path, codes: np.ndarray, profile: bytes):
    """An 8-bit CMYK TIFF written by Pillow (read by the 8-bit path: an independent one)."""
    h, w, _ = codes.shape
    Image.frombytes("CMYK", (w, h), codes.astype(np.uint8).tobytes()).save(
        path, icc_profile=profile
    )
    return path


@needs_lcms
def test_16bit_cmyk_tiff_with_profile_goes_through_its_table(tmp_path):
    k = np.arange(0, 65536, 4369, dtype=np.uint16)  # 16 steps, each 17 8-bit codes
    cmyk = np.zeros((3, len(k), 4), np.uint16)
    cmyk[..., 3] = k
    path = tmp_path / "cmyk_icc.tif"
    write_tiff(path, cmyk, ">", deflate=True, photometric=5, icc=cmyk_k_only_icc())
    # The profile makes L* = 100 (1 - K); CIE 1976 L* back to relative luminance Y.
    lstar = 100.0 * (1.0 - k / 65535.0)
    expected = np.where(lstar > 8.0, ((lstar + 16.0) / 116.0) ** 3, lstar / 903.3)
    got = load_image(path)
    np.testing.assert_allclose(got, np.repeat(expected[None], 3, 0), atol=0.005)
    assert np.abs(got[0] - naive_cmyk_luminance(cmyk[:1])[0]).max() > 0.02


@needs_lcms
def test_16bit_cmyk_with_profile_of_8bit_codes_reads_as_the_8bit_file(tmp_path):
    codes = np.random.default_rng(21).integers(0, 256, (7, 11, 4))
    codes[0, :4] = [[0, 0, 0, 0], [255, 255, 255, 255], [0, 255, 0, 255], [255, 0, 255, 0]]
    path = tmp_path / "cmyk16.tif"
    write_tiff(path, codes.astype(np.uint16) * 257, "<", photometric=5, icc=colourful_cmyk_icc())
    eight = cmyk8_file(tmp_path / "cmyk8.tif", codes, colourful_cmyk_icc())
    np.testing.assert_array_equal(load_image(path), load_image(eight))


@needs_lcms
def test_16bit_cmyk_with_profile_moves_linearly_between_codes_of_one_ink(tmp_path):
    # Only black varies: between two 8-bit codes the picture moves in a straight line.
    k = np.arange(0, 65536, 97, dtype=np.uint16)
    cmyk = np.zeros((1, len(k), 4), np.uint16)
    cmyk[..., :3] = (257 * 77, 257 * 10, 257 * 200)
    cmyk[..., 3] = k
    path = tmp_path / "ramp16.tif"
    write_tiff(path, cmyk, ">", deflate=True, photometric=5, icc=colourful_cmyk_icc())
    ramp = np.zeros((1, 256, 4), np.int64)
    ramp[..., :3] = (77, 10, 200)
    ramp[..., 3] = np.arange(256)
    at_codes = load_image(cmyk8_file(tmp_path / "ramp8.tif", ramp, colourful_cmyk_icc()))[0]
    expected = np.interp(k / 257.0, np.arange(256), at_codes)
    np.testing.assert_allclose(load_image(path)[0], expected, rtol=0, atol=1e-12)


@needs_lcms
def test_16bit_cmyk_with_profile_stays_within_its_8bit_cell(tmp_path):
    cmyk = random_samples(4, shape=(5, 40), seed=22)
    path = tmp_path / "cell16.tif"
    write_tiff(path, cmyk, "<", photometric=5, icc=colourful_cmyk_icc())
    got = load_image(path).ravel()
    # The 16 corners of each pixel's cell of 8-bit codes, read as an 8-bit file.
    below = np.minimum(cmyk.reshape(-1, 4) // 257, 254)
    steps = np.array(list(itertools.product((0, 1), repeat=4)))
    corners = below[:, None, :] + steps[None]
    at = load_image(cmyk8_file(tmp_path / "cell8.tif", corners, colourful_cmyk_icc()))
    assert np.all(got >= at.min(axis=1) - 1e-12) and np.all(got <= at.max(axis=1) + 1e-12)
    # Not the high bytes' picture: the low bytes move it within the cell.
    high = load_image(cmyk8_file(tmp_path / "high8.tif", cmyk >> 8, colourful_cmyk_icc())).ravel()
    assert np.mean(got != high) > 0.9


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("deflate", [False, True])
def test_16bit_white_is_zero_grey_tiff_is_inverted_like_8bit(tmp_path, deflate, order):
    # PhotometricInterpretation 0: code 0 is white. Pillow inverts 8-bit such files itself
    # and refuses big-endian 16-bit ones.
    codes = np.array([[[0], [10], [200], [255]]], np.uint8)
    write_tiff(tmp_path / "w8.tif", codes, order, deflate, photometric=0)
    write_tiff(tmp_path / "w16.tif", codes.astype(np.uint16) * 257, order, deflate, photometric=0)
    expected = [eotf(1.0 - c / 255) for c in codes.ravel()]
    np.testing.assert_allclose(load_image(tmp_path / "w8.tif")[0], expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(load_image(tmp_path / "w16.tif")[0], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("order", ["<", ">"])
def test_16bit_white_is_zero_grey_tiff_keeps_its_16_bits(tmp_path, order):
    codes = np.array([[[0], [1], [257], [40000], [65534], [65535]]], np.uint16)
    path = tmp_path / "w16.tif"
    write_tiff(path, codes, order, rows_per_strip=1, photometric=0)
    expected = [eotf(1.0 - int(c) / 65535) for c in codes.ravel()]
    np.testing.assert_allclose(load_image(path)[0], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("order", ["<", ">"])
def test_float_white_is_zero_grey_tiff_is_inverted(tmp_path, order):
    # A float v in [0, 1] stands for 1 - v, as 8-bit code c for 255 - c.
    values = np.array([[[0.0], [0.04], [0.5], [0.9], [1.0]]], np.float32)
    path = tmp_path / "wf.tif"
    write_tiff(path, values, order, photometric=0)
    expected = [eotf(1.0 - float(v)) for v in values.ravel()]
    np.testing.assert_allclose(load_image(path)[0], expected, rtol=0, atol=1e-7)


@needs_lcms
def test_float_white_is_zero_grey_tiff_with_linear_profile(tmp_path):
    values = np.linspace(0.0, 1.0, 11, dtype=np.float32)[None, :, None]
    path = tmp_path / "wfl.tif"
    write_tiff(path, values, "<", photometric=0, icc=gray_icc(curv_gamma(1.0)))
    np.testing.assert_allclose(load_image(path)[0], 1.0 - values.ravel(), rtol=0, atol=3e-5)


def test_16bit_white_is_zero_grey_and_alpha_tiff_inverts_only_the_grey(tmp_path):
    samples = random_samples(2)
    path = tmp_path / "wla.tif"
    write_tiff(path, samples, ">", deflate=True, photometric=0)
    inverted = samples.copy()
    inverted[..., 0] = 65535 - samples[..., 0]
    np.testing.assert_allclose(
        load_image(path), reference(inverted, weights=(1.0,)), rtol=0, atol=1e-12
    )


@pytest.mark.parametrize(
    ("order", "rows", "tile"), [("<", None, None), (">", 3, None), ("<", None, (16, 16))]
)
@pytest.mark.parametrize("c", [3, 4])
def test_uncompressed_16bit_tiff_of_separate_planes(tmp_path, c, order, rows, tile):
    # Pillow reads these planes' bytes as 8-bit samples: a wrong picture, not a coarse one.
    samples = random_samples(c, shape=(20, 35))
    path = tmp_path / "planar.tif"
    write_tiff(path, samples, order, rows_per_strip=rows, planar=True, tile=tile)
    np.testing.assert_allclose(load_image(path), reference(samples), rtol=0, atol=1e-12)


@pytest.mark.parametrize("extra", [0, 1])
def test_uncompressed_16bit_planes_with_unspecified_or_associated_fourth(tmp_path, extra):
    stored = with_edge_alphas(premultiplied(random_samples(4, seed=14)))
    path = tmp_path / "planar_x.tif"
    write_tiff(path, stored, ">", rows_per_strip=4, extra_samples=extra, planar=True)
    if extra == 0:
        expected = reference(stored[..., :3])
        np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=1e-12)
    else:
        expected = reference_premultiplied(stored, (0.2126, 0.7152, 0.0722))
        np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=2e-5)


def test_uncompressed_16bit_cmyk_planes(tmp_path):
    cmyk = random_samples(4, seed=15)
    path = tmp_path / "planar_cmyk.tif"
    write_tiff(path, cmyk, "<", rows_per_strip=5, photometric=5, planar=True)
    np.testing.assert_allclose(load_image(path), naive_cmyk_luminance(cmyk), rtol=0, atol=2e-5)


@pytest.mark.parametrize("compression", ["deflate", "lzw", "packbits"])
@pytest.mark.parametrize(
    ("order", "rows", "tile", "c"),
    [("<", 4, None, 3), (">", None, None, 4), (">", None, (16, 16), 3), ("<", None, (16, 32), 4)],
)
def test_compressed_16bit_planes_read_like_the_same_16bit_png(
    tmp_path, compression, order, rows, tile, c
):
    # libtiff hands Pillow each compressed plane's high bytes, whatever it is asked for.
    samples = random_samples(c, shape=(20, 35), seed=16)
    tif, png = tmp_path / "planar_z.tif", tmp_path / "same.png"
    write_tiff(
        tif, samples, order, rows_per_strip=rows, planar=True, tile=tile, compression=compression
    )
    write_png16(png, samples)
    got = load_image(tif)
    np.testing.assert_array_equal(got, load_image(png))
    # Not the 8-bit picture: the low bytes count.
    assert np.abs(got - reference((samples >> 8) * 257)).max() > 1e-4


def test_compressed_16bit_cmyk_planes(tmp_path):
    cmyk = random_samples(4, seed=17)
    path = tmp_path / "planar_cmyk_z.tif"
    write_tiff(path, cmyk, ">", rows_per_strip=2, photometric=5, planar=True, compression="lzw")
    np.testing.assert_allclose(load_image(path), naive_cmyk_luminance(cmyk), rtol=0, atol=2e-5)


@pytest.mark.parametrize("planar", [False, True])
def test_corrupt_compressed_tiff_fails_with_one_line(tmp_path, planar):
    # libtiff may still print its own reason on stderr after our line (Pillow turns off
    # only its warnings): the process's stderr is left alone.
    samples = random_samples(3, shape=(40, 50), seed=3)
    path = tmp_path / "cut.tif"
    write_tiff(path, samples, "<", rows_per_strip=8, planar=planar, compression="lzw")
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(ConfigError, match=r"cut.tif: corrupt or truncated image \(") as info:
        load_image(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("tile", [None, (16, 16)])
def test_16bit_planes_without_byte_counts_read_like_the_same_png(tmp_path, tile):
    # Pillow's raw reader needs no StripByteCounts; rows per strip 2**32 - 1 is one strip.
    samples = random_samples(3, shape=(20, 35), seed=18)
    tif, png = tmp_path / "nocounts.tif", tmp_path / "same.png"
    rows = None if tile else 2**32 - 1
    write_tiff(tif, samples, ">", rows_per_strip=rows, planar=True, tile=tile, byte_counts=False)
    write_png16(png, samples)
    np.testing.assert_array_equal(load_image(tif), load_image(png))


@pytest.mark.parametrize(
    ("tag", "value", "says"),
    [
        (273, 10**6, "truncated"),  # a strip past the file's end
        (323, 0, "strips or tiles of 16 x 0 pixels"),  # TileLength
        (278, 3, "12 strip or tile offsets for 3 planes"),  # RowsPerStrip 3, not 6
    ],
)
def test_malformed_16bit_planes_fail_with_one_line(tmp_path, tag, value, says):
    path = tmp_path / "bad.tif"
    tile = (16, 16) if tag == 323 else None
    samples = random_samples(3, shape=(20, 35))
    write_tiff(path, samples, "<", rows_per_strip=6, planar=True, tile=tile)
    data = bytearray(path.read_bytes())
    count = struct.unpack_from("<H", data, 8)[0]
    entries = [10 + 12 * i for i in range(count)]
    at = next(e for e in entries if struct.unpack_from("<H", data, e)[0] == tag)
    kind, n, where = struct.unpack_from("<HII", data, at + 2)
    # the last strip, or the tag's one value
    struct.pack_into("<I", data, where + 4 * (n - 1) if n > 1 else at + 8, value)
    path.write_bytes(bytes(data))
    with pytest.raises(ConfigError, match=rf"bad.tif: corrupt or truncated image \(.*{says}"):
        load_image(path)


@pytest.mark.parametrize("compression", [None, "deflate"])
def test_16bit_grey_and_alpha_planes_read_like_the_same_png(tmp_path, compression):
    # Compressed, libtiff refused Pillow's decode of the whole ("decoder error -2").
    samples = random_samples(2, shape=(20, 35), seed=19)
    tif, png = tmp_path / "planar_la.tif", tmp_path / "same.png"
    write_tiff(tif, samples, "<", rows_per_strip=6, planar=True, compression=compression)
    write_png16(png, samples)
    np.testing.assert_array_equal(load_image(tif), load_image(png))


@pytest.mark.parametrize("compression", [None, "deflate"])
def test_16bit_planes_are_read_without_spare_copies(tmp_path, compression):
    # Python-visible memory at the peak: the file's bytes and the 16-bit samples (6 bytes
    # a pixel each), one plane's small TIFF (2, or less compressed) and a band of rows;
    # later the samples, the luminance (8) and a few rows. A copy of the whole file (the
    # planes' directories appended to it: 22 bytes a pixel) would pass the budget.
    h, w = 4000, 250
    samples = random_samples(3, shape=(h, w), seed=20)
    path = tmp_path / "big_planes.tif"
    write_tiff(path, samples, "<", rows_per_strip=64, planar=True, compression=compression)
    peak = peak_of_a_second_load(path)
    assert peak < path.stat().st_size + h * w * 11
