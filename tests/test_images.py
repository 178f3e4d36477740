from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, features

from scratchfab.cli import main
from scratchfab.design.images import linear_to_srgb, load_image, srgb_to_linear
from scratchfab.errors import ConfigError


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
