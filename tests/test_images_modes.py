"""Everyday image files read as they are meant: orientation, transparency, LAB, refusals."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_images import eotf
from test_images_deep import random_samples, reference, write_png16

from scratchfab.cli import main
from scratchfab.design.images import load_image
from scratchfab.errors import ConfigError


def upright(stored: np.ndarray, orientation: int) -> np.ndarray:
    """The picture as displayed, by the EXIF 2.3 definitions of tag 0x0112 (rows, columns)."""
    return {
        1: lambda a: a,
        2: lambda a: a[:, ::-1],  # mirrored left to right
        3: lambda a: a[::-1, ::-1],  # half a turn
        4: lambda a: a[::-1],  # mirrored top to bottom
        5: lambda a: a.T,  # mirrored, then a quarter turn anticlockwise: the transpose
        6: lambda a: a[::-1].T,  # a quarter turn clockwise
        7: lambda a: a[::-1, ::-1].T,  # mirrored, then a quarter turn clockwise
        8: lambda a: a[:, ::-1].T,  # a quarter turn anticlockwise
    }[orientation](stored)


def exif_bytes(orientation: int) -> bytes:
    exif = Image.Exif()
    exif[0x0112] = orientation
    return exif.tobytes()


@pytest.mark.parametrize("orientation", range(1, 9))
def test_png_exif_orientation_all_eight(tmp_path, orientation):
    stored = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20  # every pixel different
    path = tmp_path / "o.png"
    Image.fromarray(stored).save(path, exif=exif_bytes(orientation))
    expected = np.vectorize(lambda v: eotf(v / 255))(upright(stored, orientation))
    np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_16bit_png_exif_orientation_all_eight(tmp_path, orientation):
    samples = random_samples(3, shape=(3, 5))
    path = tmp_path / "o16.png"
    write_png16(path, samples, (b"eXIf", exif_bytes(orientation)))
    np.testing.assert_allclose(
        load_image(path), upright(reference(samples), orientation), rtol=0, atol=1e-12
    )


@pytest.mark.parametrize("orientation", [3, 6, 8])
def test_phone_jpeg_orientation(tmp_path, orientation):
    # Blocks of 16 pixels (whole JPEG blocks), each its own grey: 2 rows by 3 columns.
    levels = np.array([[0, 60, 120], [180, 240, 30]], np.uint8)
    stored = np.kron(levels, np.ones((16, 16), np.uint8))
    path = tmp_path / "phone.jpg"
    Image.fromarray(stored).convert("RGB").save(
        path, exif=exif_bytes(orientation), quality=100, subsampling=0
    )
    got = load_image(path)
    expected_levels = upright(levels, orientation)
    assert got.shape == (16 * expected_levels.shape[0], 16 * expected_levels.shape[1])
    centres = got[8::16, 8::16]
    expected = np.vectorize(lambda v: eotf(v / 255))(expected_levels)
    np.testing.assert_allclose(centres, expected, atol=0.01)


def test_16bit_png_colour_key_is_transparent(tmp_path):
    rgb = np.array([[[1000, 2000, 3000], [5, 6, 7], [5, 6, 8]]], np.uint16)
    path = tmp_path / "key.png"
    write_png16(path, rgb, (b"tRNS", struct.pack(">3H", 5, 6, 7)))
    expected = reference(rgb)
    expected[0, 1] = 0.0  # the key colour: transparent, the bare board
    np.testing.assert_allclose(load_image(path), expected, rtol=0, atol=1e-12)


def test_16bit_gray_png_colour_key_is_transparent(tmp_path):
    gray = np.array([[0, 30000, 65535]], np.uint16)
    path = tmp_path / "gkey.png"
    Image.fromarray(gray).save(path, transparency=65535)
    np.testing.assert_allclose(load_image(path)[0], [0.0, eotf(30000 / 65535), 0.0], atol=1e-12)


def test_8bit_colour_key_and_partial_palette_alpha(tmp_path):
    rgb = np.array([[[255, 255, 255], [255, 0, 0]]], np.uint8)
    Image.fromarray(rgb).save(tmp_path / "k.png", transparency=(255, 255, 255))
    np.testing.assert_allclose(load_image(tmp_path / "k.png")[0], [0.0, 0.2126], atol=1e-12)
    pal = Image.new("P", (3, 1))
    pal.putpalette([255, 255, 255] * 2 + [0, 0, 0])
    pal.putdata([0, 1, 2])
    pal.save(tmp_path / "p.png", transparency=bytes([0, 128, 255]))
    np.testing.assert_allclose(load_image(tmp_path / "p.png")[0], [0.0, 128 / 255, 0.0], atol=1e-12)


def test_gray_with_alpha_without_profile(tmp_path):
    la = np.array([[[255, 255], [255, 51], [128, 255]]], np.uint8)
    Image.fromarray(la, mode="LA").save(tmp_path / "la.png")
    np.testing.assert_allclose(
        load_image(tmp_path / "la.png")[0], [1.0, 51 / 255, eotf(128 / 255)], atol=1e-12
    )


def test_lab_tiff_uses_its_lightness(tmp_path):
    stored = np.array([[0, 20, 128, 255]], np.uint8)  # L* = stored * 100 / 255
    lab = np.stack([stored, np.full_like(stored, 30), np.full_like(stored, 200)], axis=-1)
    path = tmp_path / "lab.tif"
    Image.fromarray(lab, mode="LAB").save(path)

    def cie_y(lstar: float) -> float:  # CIE 1976: L* = 116 f(Y) - 16, linear below 0.008856
        return ((lstar + 16) / 116) ** 3 if lstar > 8 else lstar * 27 / 24389

    expected = [cie_y(int(v) * 100 / 255) for v in stored[0]]
    np.testing.assert_allclose(load_image(path)[0], expected, rtol=1e-12, atol=1e-12)


def _heic(path: Path) -> None:
    path.write_bytes(struct.pack(">I", 24) + b"ftypheic" + bytes(4) + b"mif1heic" + bytes(64))


UNREADABLE = [
    ("photo.heic", _heic, "HEIF/HEIC"),
    ("doc.pdf", lambda p: p.write_bytes(b"%PDF-1.7\n" + bytes(64)), "PDF"),
    ("art.svg", lambda p: p.write_text('<?xml version="1.0"?>\n<svg width="10"/>'), "SVG"),
    ("hdr.exr", lambda p: p.write_bytes(b"\x76\x2f\x31\x01" + bytes(64)), "OpenEXR"),
    (
        "page.png",
        lambda p: p.write_text("\n<!DOCTYPE html>\n<html><body>404</body></html>"),
        "HTML",
    ),
    ("meta.xmp", lambda p: p.write_text('<?xml version="1.0"?>\n<x:xmpmeta/>'), "XML document"),
    (
        "drawn.svg",  # a long preamble (licence comment) before <svg>
        lambda p: p.write_text('<?xml version="1.0"?>\n<!-- ' + "x" * 1500 + " -->\n<svg/>"),
        "SVG",
    ),
]


@pytest.mark.parametrize(("name", "make", "what"), UNREADABLE)
def test_files_pillow_cannot_read_say_what_they_seem(tmp_path, name, make, what):
    path = tmp_path / name
    make(path)
    with pytest.raises(ConfigError) as info:
        load_image(path)
    text = str(info.value)
    assert text.startswith(f"{path}: not an image file Pillow can read (")
    assert what in text.split(";")[0]
    assert "expected PNG, JPEG" in text and "\n" not in text


def test_cli_names_the_heic_file_on_one_line(tmp_path, capsys):
    bad = tmp_path / "IMG_0001.heic"
    _heic(bad)
    with pytest.raises(SystemExit) as info:
        main(["design", str(bad), "--board", "40x40", "--out", str(tmp_path / "job")])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(bad) in err and "HEIF/HEIC" in err
