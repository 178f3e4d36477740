from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, features
from PIL.PngImagePlugin import PngInfo

from scratchfab.cli import main
from scratchfab.design.images import linear_to_srgb, load_image, srgb_to_linear
from scratchfab.errors import ConfigError, ScratchfabError


def eotf(v: float) -> float:
    """IEC 61966-2-1 sRGB decoding, written out independently of the code under test."""
    return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4


def test_srgb_eotf_is_exact_piecewise_and_inverts():
    codes = np.arange(256) / 255.0
    expected = np.array([eotf(float(v)) for v in codes])
    np.testing.assert_allclose(srgb_to_linear(codes), expected, rtol=0, atol=1e-15)
    # The two pieces meet continuously near the threshold and the encoder inverts them.
    lin = np.linspace(0, 1, 10001)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(lin)), lin, atol=1e-12)


def test_luminance_of_primaries_and_gray(tmp_path):
    rgb = np.zeros((1, 4, 3), np.uint8)
    rgb[0, 0] = (255, 0, 0)
    rgb[0, 1] = (0, 255, 0)
    rgb[0, 2] = (0, 0, 255)
    rgb[0, 3] = (128, 128, 128)
    Image.fromarray(rgb).save(tmp_path / "p.png")
    lum = load_image(tmp_path / "p.png")
    np.testing.assert_allclose(lum[0, :3], [0.2126, 0.7152, 0.0722], atol=1e-12)
    assert lum[0, 3] == pytest.approx(eotf(128 / 255), abs=1e-12)


def test_16bit_png_keeps_its_precision(tmp_path):
    codes = np.array([[0, 1000, 1001, 32768, 65535]], dtype=np.uint16)
    Image.fromarray(codes).save(tmp_path / "deep.png")
    assert Image.open(tmp_path / "deep.png").mode.startswith("I")
    lum = load_image(tmp_path / "deep.png")
    expected = [eotf(c / 65535) for c in codes[0]]
    np.testing.assert_allclose(lum[0], expected, atol=1e-12)
    assert lum[0, 1] < lum[0, 2]  # codes 1000 and 1001 stay apart (not squashed to 8 bits)


def test_palette_png_with_transparency_is_black_where_transparent(tmp_path):
    img = Image.new("P", (4, 2), 0)
    img.putpalette([255, 255, 255, 0, 0, 0] + [0] * (254 * 3))
    img.putpixel((0, 0), 1)  # index 1 is black, index 0 white
    img.info["transparency"] = 0
    img.save(tmp_path / "pal.png", transparency=0)
    lum = load_image(tmp_path / "pal.png")
    assert lum.shape == (2, 4)
    # Index 0 (white but fully transparent) composites to black; index 1 is black anyway.
    assert np.all(lum == 0.0)
    # The same palette without transparency is white.
    img2 = Image.new("P", (4, 2), 0)
    img2.putpalette([255, 255, 255] + [0] * (255 * 3))
    img2.save(tmp_path / "pal2.png")
    assert np.allclose(load_image(tmp_path / "pal2.png"), 1.0)


def test_rgba_alpha_scales_to_black(tmp_path):
    rgba = np.zeros((1, 2, 4), np.uint8)
    rgba[0, 0] = (255, 255, 255, 255)
    rgba[0, 1] = (255, 255, 255, 51)
    Image.fromarray(rgba).save(tmp_path / "a.png")
    lum = load_image(tmp_path / "a.png")
    np.testing.assert_allclose(lum[0], [1.0, 51 / 255], atol=1e-12)


def test_cmyk_jpeg_reads_as_luminance(tmp_path):
    img = Image.new("CMYK", (32, 16), (0, 0, 0, 0))  # no ink: white
    img.paste((0, 0, 0, 255), (16, 0, 32, 16))  # full black ink on the right
    img.save(tmp_path / "cmyk.jpg", quality=95)
    assert Image.open(tmp_path / "cmyk.jpg").mode == "CMYK"
    lum = load_image(tmp_path / "cmyk.jpg")
    assert lum.shape == (16, 32)
    assert lum[:, :12].mean() > 0.9
    assert lum[:, 20:].mean() < 0.05


def test_exif_rotated_jpeg_is_turned_upright(tmp_path):
    # Stored 40 wide x 20 high with the left half white; orientation 6 means "turn 90
    # degrees clockwise to display", which brings the stored left edge to the top.
    arr = np.zeros((20, 40, 3), np.uint8)
    arr[:, :20] = 255
    img = Image.fromarray(arr)
    exif = Image.Exif()
    exif[0x0112] = 6
    img.save(tmp_path / "rot.jpg", exif=exif.tobytes(), quality=95)
    lum = load_image(tmp_path / "rot.jpg")
    assert lum.shape == (40, 20)
    assert lum[:16].mean() > 0.9
    assert lum[24:].mean() < 0.05


def test_one_pixel_image(tmp_path):
    Image.new("L", (1, 1), 200).save(tmp_path / "one.png")
    lum = load_image(tmp_path / "one.png")
    assert lum.shape == (1, 1)
    assert lum[0, 0] == pytest.approx(eotf(200 / 255), abs=1e-12)


def _corrupt_png(path: Path) -> None:
    buf = io.BytesIO()
    Image.fromarray(np.arange(64 * 64, dtype=np.uint32).reshape(64, 64).astype(np.uint8)).save(
        buf, format="PNG"
    )
    data = buf.getvalue()
    path.write_bytes(data[: len(data) // 2])


BAD_FILES = [
    ("corrupt.png", _corrupt_png, "corrupt or truncated image"),
    ("missing.png", None, "image file not found"),
    ("text.png", lambda p: p.write_text("this is not a picture\n"), "not an image file"),
    ("empty.png", lambda p: p.write_bytes(b""), "empty file"),
]


@pytest.mark.parametrize(("name", "make", "message"), BAD_FILES)
def test_bad_image_files_fail_with_one_line_naming_the_file(tmp_path, name, make, message):
    path = tmp_path / name
    if make is not None:
        make(path)
    with pytest.raises(ConfigError) as info:
        load_image(path)
    text = str(info.value)
    assert str(path) in text and message in text
    assert "\n" not in text


@pytest.mark.parametrize(("name", "make", "message"), BAD_FILES[:3])
def test_cli_reports_bad_images_on_one_line_and_writes_nothing(
    tmp_path, capsys, name, make, message
):
    good = tmp_path / "good.png"
    Image.new("L", (8, 8), 255).save(good)
    bad = tmp_path / name
    if make is not None:
        make(bad)
    job = tmp_path / "job"
    with pytest.raises(SystemExit) as info:
        main(["design", str(good), str(bad), "--board", "40x40", "--out", str(job)])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error: ")
    assert str(bad) in err and message in err
    assert not (job / "design").exists()


@pytest.mark.parametrize(
    ("ext", "kwargs"),
    [
        ("tif", {}),
        ("bmp", {}),
        ("gif", {}),
        ("webp", {"lossless": True}),
        ("jpg", {"quality": 100}),
    ],
)
def test_other_formats_read_like_png(tmp_path, ext, kwargs):
    if ext == "webp" and not features.check("webp"):
        pytest.skip("Pillow built without WebP")
    arr = np.zeros((12, 16, 3), np.uint8)
    arr[:, :8] = (200, 200, 200)
    arr[3:6, 10:14] = (90, 90, 90)
    Image.fromarray(arr).save(tmp_path / "ref.png")
    Image.fromarray(arr).save(tmp_path / f"x.{ext}", **kwargs)
    ref = load_image(tmp_path / "ref.png")
    got = load_image(tmp_path / f"x.{ext}")
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, atol=0.02 if ext == "jpg" else 1e-12)


# -- colour spaces the files declare (ICC profiles, PNG gAMA / cHRM / sRGB) -----------------

D50 = (0.9642, 1.0, 0.8249)
#: Display P3 colorants as Apple's "Display P3" profile stores them (D50-adapted).
P3_COLORANTS = (
    (0.51512, 0.24120, -0.00105),
    (0.29198, 0.69225, 0.04189),
    (0.15710, 0.06657, 0.78407),
)
#: Luminance of linear Display P3 R, G, B (D65), as published with the colour space.
P3_LUMA = (0.2289746, 0.6917385, 0.0792869)


def opened(path: Path) -> Image.Image:
    """The decoded image, its file closed (Pillow's own reading, for references)."""
    with Image.open(path) as im:
        im.load()
        return im


def _s15(v: float) -> bytes:
    return struct.pack(">i", round(v * 65536))


def icc(
    space: bytes, tags: dict[bytes, bytes], device_class: bytes = b"mntr", pcs: bytes = b"XYZ "
) -> bytes:
    """A hand-built ICC v2.1 profile (ICC.1:2001-04 header and tag table, no description)."""
    start = 128 + 4 + 12 * len(tags)
    table, body = b"", b""
    for sig, data in tags.items():
        table += sig + struct.pack(">II", start + len(body), len(data))
        body += data + bytes(-len(data) % 4)
    head = struct.pack(">I4xI", start + len(body), 0x02100000) + device_class + space + pcs
    head += bytes(12) + b"acsp" + bytes(28) + b"".join(_s15(c) for c in D50)
    return head + bytes(128 - len(head)) + struct.pack(">I", len(tags)) + table + body


def curv_gamma(gamma: float) -> bytes:
    """A 'curv' tag holding one u8Fixed8 exponent; returns the bytes (see gamma_of)."""
    return b"curv" + bytes(4) + struct.pack(">IH", 1, round(gamma * 256))


def gamma_of(gamma: float) -> float:
    """The exponent a curv tag really stores (u8Fixed8: 1.8 becomes 461/256)."""
    return round(gamma * 256) / 256


def xyz_tag(xyz) -> bytes:
    return b"XYZ " + bytes(4) + b"".join(_s15(c) for c in xyz)


def gray_icc(trc: bytes, device_class: bytes = b"mntr") -> bytes:
    return icc(b"GRAY", {b"wtpt": xyz_tag(D50), b"kTRC": trc}, device_class)


def rgb_icc(trc: bytes, colorants) -> bytes:
    tags = {b"wtpt": xyz_tag(D50)}
    for ch, xyz in zip("rgb", colorants, strict=True):
        tags[f"{ch}XYZ".encode()] = xyz_tag(xyz)
        tags[f"{ch}TRC".encode()] = trc
    return icc(b"RGB ", tags)


def srgb_colorants():
    from PIL import ImageCms

    p = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).profile
    return [c[0] for c in (p.red_colorant, p.green_colorant, p.blue_colorant)]


def png_with_chunks(path: Path, image: Image.Image, **chunks: bytes) -> None:
    info = PngInfo()
    for name, data in chunks.items():
        info.add(name.encode(), data)
    image.save(path, pnginfo=info)


needs_lcms = pytest.mark.skipif(not features.check("littlecms2"), reason="Pillow lacks littleCMS")


@needs_lcms
@pytest.mark.parametrize("gamma", [1.0, 1.8, 2.2])
@pytest.mark.parametrize("ext", ["png", "tif", "jpg"])
def test_gray_gamma_profiles_decode_by_their_curve(tmp_path, gamma, ext):
    codes = np.repeat(np.arange(256, dtype=np.uint8)[None, :], 8 if ext == "jpg" else 1, 0)
    path = tmp_path / f"g.{ext}"
    extra = {"quality": 100, "subsampling": 0} if ext == "jpg" else {}
    Image.fromarray(codes).save(path, icc_profile=gray_icc(curv_gamma(gamma)), **extra)
    stored = np.asarray(opened(path), dtype=np.float64) / 255.0  # JPEG: what it decodes to
    got = load_image(path)
    np.testing.assert_allclose(got, stored ** gamma_of(gamma), rtol=0, atol=3e-5)
    if gamma != 2.2:  # and not what sRGB decoding would give
        assert np.abs(got - srgb_to_linear(stored)).max() > 0.04


@needs_lcms
def test_16bit_gray_with_profile_keeps_16bit_precision(tmp_path):
    codes = np.arange(0, 65536, 7, dtype=np.uint16)[None, :]
    Image.fromarray(codes).save(tmp_path / "g16.png", icc_profile=gray_icc(curv_gamma(1.8)))
    got = load_image(tmp_path / "g16.png")
    # 8-bit squashing would be off by up to ~4e-3 here.
    np.testing.assert_allclose(got[0], (codes[0] / 65535) ** gamma_of(1.8), rtol=0, atol=3e-5)


@needs_lcms
def test_float_tiff_with_gray_profile(tmp_path):
    values = np.linspace(0.0, 1.0, 1001, dtype=np.float32)[None, :]
    path = tmp_path / "f.tif"
    Image.fromarray(values, mode="F").save(path, icc_profile=gray_icc(curv_gamma(1.8)))
    assert opened(path).mode == "F" and "icc_profile" in opened(path).info
    got = load_image(path)
    np.testing.assert_allclose(got[0], values[0].astype(float) ** gamma_of(1.8), atol=3e-5)


@needs_lcms
def test_dot_gain_table_profile_follows_its_table(tmp_path):
    # A Photoshop-style "Dot Gain 20%" printer gray profile: ink k = 1 - v spreads to
    # k + 0.8 k (1 - k) (50 % ink prints as 70 %), sampled in a 256-entry curv table.
    v = np.linspace(0.0, 1.0, 256)
    k = 1.0 - v
    table = np.round((1.0 - (k + 0.8 * k * (1.0 - k))) * 65535).astype(">u2")
    trc = b"curv" + bytes(4) + struct.pack(">I", len(table)) + table.tobytes()
    codes = np.arange(256, dtype=np.uint8)[None, :]
    Image.fromarray(codes).save(tmp_path / "dg.png", icc_profile=gray_icc(trc, b"prtr"))
    got = load_image(tmp_path / "dg.png")
    np.testing.assert_allclose(got[0], table / 65535.0, atol=3e-5)
    assert got[0, 128] == pytest.approx(0.3, abs=0.01)  # 50 % gray prints as 70 % ink


def test_srgb_profile_reads_like_no_profile(tmp_path):
    from PIL import ImageCms

    if not features.check("littlecms2"):
        pytest.skip("Pillow lacks littleCMS")
    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    arr = np.random.default_rng(7).integers(0, 256, (32, 48, 3), dtype=np.uint8)
    Image.fromarray(arr).save(tmp_path / "plain.png")
    Image.fromarray(arr).save(tmp_path / "tagged.png", icc_profile=srgb)
    rgba = np.dstack([arr, np.full(arr.shape[:2], 128, np.uint8)])
    Image.fromarray(rgba).save(tmp_path / "tagged_a.png", icc_profile=srgb)
    plain = load_image(tmp_path / "plain.png")
    np.testing.assert_allclose(load_image(tmp_path / "tagged.png"), plain, atol=1e-3)
    np.testing.assert_allclose(load_image(tmp_path / "tagged_a.png"), plain * 128 / 255, atol=1e-3)
    # An sRGB-curve gray profile (tabulated) reads like the untagged gray image.
    lut = np.round(srgb_to_linear(np.linspace(0, 1, 4096)) * 65535).astype(">u2")
    trc = b"curv" + bytes(4) + struct.pack(">I", 4096) + lut.tobytes()
    Image.fromarray(arr[..., 1]).save(tmp_path / "g.png", icc_profile=gray_icc(trc))
    Image.fromarray(arr[..., 1]).save(tmp_path / "g0.png")
    np.testing.assert_allclose(
        load_image(tmp_path / "g.png"), load_image(tmp_path / "g0.png"), atol=1e-4
    )


@needs_lcms
def test_rgb_gamma_profile_with_srgb_primaries(tmp_path):
    arr = np.random.default_rng(3).integers(0, 256, (40, 40, 3), dtype=np.uint8)
    path = tmp_path / "apple.jpg"
    Image.fromarray(arr).save(
        path, quality=100, subsampling=0, icc_profile=rgb_icc(curv_gamma(1.8), srgb_colorants())
    )
    stored = np.asarray(opened(path).convert("RGB"), dtype=np.float64) / 255.0
    expected = (stored ** gamma_of(1.8)) @ LUMA
    got = load_image(path)
    # littleCMS writes 8-bit sRGB: half a code is at most 0.0045 of linear full scale.
    np.testing.assert_allclose(got, expected, atol=0.005)
    assert np.abs(got - expected).mean() < 1e-3
    assert np.abs(got - srgb_to_linear(stored) @ LUMA).max() > 0.05


@needs_lcms
def test_display_p3_photo_gets_p3_luminance(tmp_path):
    # Colours inside sRGB's gamut, so that the conversion to sRGB does not clip.
    lin = np.array([[0.8, 0.1, 0.1], [0.1, 0.6, 0.2], [0.3, 0.3, 0.9], [0.5, 0.5, 0.5]])
    codes = np.round(linear_to_srgb(lin) * 255).astype(np.uint8)
    Image.fromarray(np.repeat(codes[None], 4, 0)).save(
        tmp_path / "p3.png", icc_profile=rgb_icc(SRGB_CURV, P3_COLORANTS)
    )
    expected = srgb_to_linear(codes / 255.0) @ np.array(P3_LUMA)
    got = load_image(tmp_path / "p3.png")
    np.testing.assert_allclose(got, np.repeat(expected[None], 4, 0), atol=3e-3)
    assert abs(got[0, 0] - srgb_to_linear(codes[0] / 255.0) @ LUMA) > 0.01  # red is brighter


#: sRGB tone curve as a tabulated curv tag (for profiles whose TRC is sRGB's).
SRGB_CURV = (
    b"curv"
    + bytes(4)
    + struct.pack(">I", 4096)
    + np.round(srgb_to_linear(np.linspace(0, 1, 4096)) * 65535).astype(">u2").tobytes()
)
LUMA = np.array([0.2126, 0.7152, 0.0722])


@pytest.mark.parametrize("bits", [8, 16])
def test_png_gama_decodes_with_its_exponent(tmp_path, bits):
    top = 255 if bits == 8 else 65535
    codes = np.linspace(0, top, 300).round().astype(np.uint8 if bits == 8 else np.uint16)[None]
    for gama, exponent in ((100000, 1.0), (45455, 100000 / 45455), (55556, 100000 / 55556)):
        path = tmp_path / f"g{gama}_{bits}.png"
        png_with_chunks(path, Image.fromarray(codes), gAMA=struct.pack(">I", gama))
        assert opened(path).info["gamma"] == gama / 100000
        got = load_image(path)
        np.testing.assert_allclose(got[0], (codes[0] / top) ** exponent, rtol=0, atol=1e-12)


def test_png_srgb_or_iccp_chunk_overrides_gama(tmp_path):
    codes = np.arange(256, dtype=np.uint8)[None]
    png_with_chunks(
        tmp_path / "s.png", Image.fromarray(codes), sRGB=b"\x00", gAMA=struct.pack(">I", 100000)
    )
    np.testing.assert_allclose(load_image(tmp_path / "s.png")[0], srgb_to_linear(codes[0] / 255))
    if features.check("littlecms2"):
        info = PngInfo()
        info.add(b"gAMA", struct.pack(">I", 100000))
        Image.fromarray(codes).save(
            tmp_path / "i.png", pnginfo=info, icc_profile=gray_icc(curv_gamma(1.8))
        )
        got = load_image(tmp_path / "i.png")[0]
        np.testing.assert_allclose(got, (codes[0] / 255) ** gamma_of(1.8), atol=3e-5)


def _chrm(white, red, green, blue) -> bytes:
    return struct.pack(">8I", *(round(c * 100000) for xy in (white, red, green, blue) for c in xy))


def test_png_chrm_primaries_set_the_luminance_weights(tmp_path):
    eye = np.eye(3, dtype=np.uint8)[None] * 255  # pure R, G, B
    srgb = _chrm((0.3127, 0.3290), (0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
    p3 = _chrm((0.3127, 0.3290), (0.680, 0.320), (0.265, 0.690), (0.150, 0.060))
    linear = struct.pack(">I", 100000)
    png_with_chunks(tmp_path / "s.png", Image.fromarray(eye), cHRM=srgb, gAMA=linear)
    png_with_chunks(tmp_path / "p.png", Image.fromarray(eye), cHRM=p3)
    np.testing.assert_allclose(load_image(tmp_path / "s.png")[0], LUMA, atol=1e-4)
    np.testing.assert_allclose(load_image(tmp_path / "p.png")[0], P3_LUMA, atol=1e-4)
    # A D50 white: equal R, G, B stays the gray it is.
    gray = np.full((1, 3, 3), 200, np.uint8)
    d50 = _chrm((0.3457, 0.3585), (0.7347, 0.2653), (0.1596, 0.8404), (0.0366, 0.0001))
    png_with_chunks(tmp_path / "d.png", Image.fromarray(gray), cHRM=d50, gAMA=linear)
    np.testing.assert_allclose(load_image(tmp_path / "d.png")[0], 200 / 255, atol=1e-9)


def cmyk_k_only_icc() -> bytes:
    """A CMYK printer profile whose lut8 A2B0 makes L* = 100 (1 - K), a* = b* = 0."""
    grid = np.zeros((2, 2, 2, 2, 3), np.uint8)
    grid[..., 0, 0] = 255  # no black ink: L* = 100
    grid[..., 1:] = 128  # a* = b* = 0
    return cmyk_lut_icc(grid)


def cmyk_lut_icc(grid: np.ndarray) -> bytes:
    """A CMYK printer profile whose lut8 A2B0 is ``grid``: L*, a*, b* codes at each corner.

    2-point grid per ink (C slowest, K fastest), identity input and output tables.
    """
    identity = np.arange(256, dtype=np.uint8).tobytes()
    matrix = b"".join(_s15(float(i == j)) for i in range(3) for j in range(3))
    a2b0 = b"mft1" + bytes(4) + bytes([4, 3, 2, 0]) + matrix
    a2b0 += identity * 4 + grid.tobytes() + identity * 3
    return icc(b"CMYK", {b"wtpt": xyz_tag(D50), b"A2B0": a2b0}, b"prtr", pcs=b"Lab ")


@needs_lcms
def test_cmyk_jpeg_with_profile_goes_through_its_table(tmp_path):
    k = np.arange(0, 256, 17, dtype=np.uint8)
    cmyk = np.zeros((4, len(k), 4), np.uint8)
    cmyk[..., 3] = k
    path = tmp_path / "swop.tif"
    Image.fromarray(cmyk, mode="CMYK").save(path, icc_profile=cmyk_k_only_icc())
    lstar = 100.0 * (1.0 - k / 255.0)
    # CIE 1976 L* back to relative luminance Y.
    expected = np.where(lstar > 8.0, ((lstar + 16.0) / 116.0) ** 3, lstar / 903.3)
    got = load_image(path)
    np.testing.assert_allclose(got, np.repeat(expected[None], 4, 0), atol=0.005)
    naive = srgb_to_linear(1.0 - k / 255.0)  # what Pillow's own CMYK conversion gives
    assert np.abs(got[0] - naive).max() > 0.02


@needs_lcms
def test_gray_with_alpha_and_profile(tmp_path):
    la = np.zeros((1, 3, 2), np.uint8)
    la[0, :, 0] = (255, 128, 128)
    la[0, :, 1] = (255, 255, 51)
    Image.fromarray(la, mode="LA").save(tmp_path / "la.png", icc_profile=gray_icc(curv_gamma(1.0)))
    got = load_image(tmp_path / "la.png")[0]
    np.testing.assert_allclose(got, [1.0, 128 / 255, 128 / 255 * 51 / 255], atol=3e-5)


def _corrupt_iccp(path: Path) -> None:
    # Pillow does not write an iCCP chunk from pnginfo: splice one in after IHDR by hand.
    buf = io.BytesIO()
    Image.new("L", (4, 4), 9).save(buf, format="PNG")
    png = buf.getvalue()
    body = b"iCCP" + b"bad\x00\x00this is not zlib data"
    chunk = struct.pack(">I", len(body) - 4) + body + struct.pack(">I", zlib.crc32(body))
    path.write_bytes(png[:33] + chunk + png[33:])  # 8-byte signature + 25-byte IHDR
    assert "icc_profile" in opened(path).info


def _jpeg_with_icc(data: bytes, mode: str = "L"):
    def make(path: Path) -> None:
        Image.new(mode, (8, 8), 100 if mode == "L" else (100, 50, 20)).save(
            path, format="JPEG", icc_profile=data
        )

    return make


BAD_COLOUR = [
    (
        "garbage.jpg",
        _jpeg_with_icc(b"not an ICC profile at all " * 8),
        "embedded ICC profile is corrupt",
    ),
    (
        "cmyk_on_gray.jpg",
        _jpeg_with_icc(icc(b"CMYK", {b"wtpt": xyz_tag(D50)}, b"prtr")),
        "describes CMYK colours but the image is grayscale",
    ),
    (
        "gray_on_rgb.jpg",
        _jpeg_with_icc(gray_icc(curv_gamma(1.8)), "RGB"),
        "describes GRAY colours but the image is RGB",
    ),
    ("link.jpg", _jpeg_with_icc(icc(b"GRAY", {}, b"link")), "'link' profile"),
    (
        "no_trc.jpg",
        _jpeg_with_icc(icc(b"RGB ", {b"wtpt": xyz_tag(D50)}), "RGB"),
        "littleCMS cannot use",
    ),
    (
        "lab.tif",
        lambda p: Image.new("LAB", (4, 4)).save(p, icc_profile=icc(b"Lab ", {}, b"spac")),
        "its pixels are LAB",
    ),
    ("bad_iccp.png", _corrupt_iccp, "iCCP chunk (embedded ICC profile) is corrupt"),
    (
        "gamma0.png",
        lambda p: png_with_chunks(p, Image.new("L", (4, 4)), gAMA=bytes(4)),
        "gAMA chunk is 0.0",
    ),
    (
        "flat.png",
        lambda p: png_with_chunks(
            p, Image.new("RGB", (4, 4)), cHRM=_chrm((0.3, 0.3), (0.2, 0.2), (0.4, 0.4), (0.6, 0.3))
        ),
        "cHRM chunk",
    ),
]


@pytest.mark.parametrize(("name", "make", "message"), BAD_COLOUR)
def test_bad_colour_declarations_fail_with_one_line(tmp_path, name, make, message):
    if name.endswith((".jpg", ".tif")) and not features.check("littlecms2"):
        pytest.skip("Pillow lacks littleCMS")
    path = tmp_path / name
    make(path)
    with pytest.raises(ConfigError) as info:
        load_image(path)
    text = str(info.value)
    assert str(path) in text and message in text and "expected" in text
    assert "\n" not in text


def test_cli_reports_a_bad_profile_on_one_line(tmp_path, capsys):
    good = tmp_path / "good.png"
    Image.new("L", (8, 8), 255).save(good)
    bad = tmp_path / "bad.jpg"
    BAD_COLOUR[0][1](bad)
    with pytest.raises(SystemExit) as info:
        main(["design", str(good), str(bad), "--board", "40x40", "--out", str(tmp_path / "job")])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error: ") and str(bad) in err


def test_profile_without_littlecms_is_an_error_not_ignored(tmp_path, monkeypatch):
    path = tmp_path / "p.jpg"
    _jpeg_with_icc(gray_icc(curv_gamma(1.8)))(path)
    monkeypatch.setattr(features, "check", lambda name: name != "littlecms2")
    with pytest.raises(ScratchfabError, match="without littleCMS") as info:
        load_image(path)
    assert str(path) in str(info.value)
