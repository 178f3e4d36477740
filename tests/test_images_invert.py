"""``load_image(path, invert=True)``: the colours turn negative, a transparent ground stays black.

The reference is worked out by hand for each pixel: straight alpha ``a`` composited over
black in linear light, after the colour's sRGB-encoded value ``e`` is inverted, gives
``a * eotf(1 - e)``; an opaque image inverted is the image with its codes inverted.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from test_images import LUMA, curv_gamma, eotf, needs_lcms, rgb_icc, srgb_colorants
from test_images_deep import write_png16

from scratchfab.design.images import load_image
from scratchfab.design.targets import invert_picture

#: Grey code (of 255) and alpha (of 255) of each 8-bit test pixel, and what it shows.
GREY_PIXELS = [
    (0, 255),  # black logo, opaque: inverted white
    (0, 0),  # transparent ground: black either way
    (255, 0),  # transparent white: black either way
    (0, 128),  # black, half transparent: half of white
    (64, 200),
    (255, 255),  # opaque white: inverted black
    (128, 51),
]
#: An opaque-ish colour pixel (R, G, B, alpha).
COLOUR_PIXEL = (200, 30, 90, 100)


def oetf(y: float) -> float:
    """IEC 61966-2-1 sRGB encoding, written out independently of the code under test."""
    return 12.92 * y if y <= 0.0031308 else 1.055 * y ** (1 / 2.4) - 0.055


def _expected(grey: float, alpha: float, invert: bool) -> float:
    """A grey of encoded value ``grey`` with straight alpha ``alpha``, both in [0, 1]."""
    return alpha * eotf(1.0 - grey if invert else grey)


@pytest.mark.parametrize("invert", [False, True])
def test_8bit_rgba_inverts_the_colour_then_composites_over_black(tmp_path, invert):
    rgba = np.array([[[c, c, c, a] for c, a in GREY_PIXELS] + [COLOUR_PIXEL]], dtype=np.uint8)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    expected = [_expected(c / 255, a / 255, invert) for c, a in GREY_PIXELS]
    r, g, b, a = COLOUR_PIXEL
    y = float(LUMA @ [eotf(r / 255), eotf(g / 255), eotf(b / 255)])
    expected.append(a / 255 * (eotf(1.0 - oetf(y)) if invert else y))
    got = load_image(tmp_path / "a.png", invert=invert)
    np.testing.assert_allclose(got[0], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("invert", [False, True])
def test_8bit_grey_with_alpha_and_palette_transparency(tmp_path, invert):
    la = np.array([GREY_PIXELS], dtype=np.uint8)
    Image.fromarray(la, "LA").save(tmp_path / "la.png")
    expected = [_expected(c / 255, a / 255, invert) for c, a in GREY_PIXELS]
    np.testing.assert_allclose(load_image(tmp_path / "la.png", invert)[0], expected, atol=1e-12)
    # a palette whose entry 1 is transparent (tRNS): its black stays black inverted
    pal = Image.fromarray(np.array([[0, 1, 2]], dtype=np.uint8), "P")
    pal.putpalette([0, 0, 0, 0, 0, 0, 40, 40, 40])
    pal.save(tmp_path / "p.png", transparency=bytes([255, 0, 255]))
    expected = [_expected(0, 1, invert), 0.0, _expected(40 / 255, 1, invert)]
    np.testing.assert_allclose(load_image(tmp_path / "p.png", invert)[0], expected, atol=1e-12)


@pytest.mark.parametrize("channels", [2, 4])
@pytest.mark.parametrize("invert", [False, True])
def test_16bit_alpha_inverts_at_16_bits(tmp_path, channels, invert):
    """Grey with alpha and RGBA PNGs: 16-bit codes, no rounding to 8 bits on the way."""
    pixels = [(0, 65535), (0, 0), (65535, 0), (1000, 65535), (30000, 12345), (65535, 65535)]
    grey = np.array([c for c, _ in pixels], dtype=np.uint16)
    alpha = np.array([a for _, a in pixels], dtype=np.uint16)
    samples = np.stack([grey] * (channels - 1) + [alpha], axis=-1)[None]
    write_png16(tmp_path / "a.png", samples)
    expected = [_expected(c / 65535, a / 65535, invert) for c, a in pixels]
    np.testing.assert_allclose(load_image(tmp_path / "a.png", invert)[0], expected, atol=1e-12)


@needs_lcms
def test_rgba_with_a_matrix_profile_inverts_before_compositing(tmp_path):
    """A linear-curve profile: grey code c is linear c / 255, inverted in sRGB's encoding."""
    rgba = np.array([[[c, c, c, a] for c, a in GREY_PIXELS]], dtype=np.uint8)
    icc = rgb_icc(curv_gamma(1.0), srgb_colorants())
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png", icc_profile=icc)
    expected = [a / 255 * eotf(1.0 - oetf(c / 255)) for c, a in GREY_PIXELS]
    np.testing.assert_allclose(load_image(tmp_path / "a.png", True)[0], expected, atol=1e-4)


@pytest.mark.parametrize("mode", ["L", "RGB"])
def test_an_image_without_alpha_inverts_as_before(tmp_path, mode):
    """Opaque: the codes inverted by hand, and bit for bit the luminance inverted afterwards."""
    rng = np.random.default_rng(11)
    codes = rng.integers(0, 256, (9, 13) if mode == "L" else (9, 13, 3), dtype=np.uint8)
    Image.fromarray(codes, mode).save(tmp_path / "a.png")
    Image.fromarray(255 - codes, mode).save(tmp_path / "by_hand.png")
    got = load_image(tmp_path / "a.png", invert=True)
    np.testing.assert_array_equal(got, invert_picture(load_image(tmp_path / "a.png")))
    if mode == "L":  # a colour's luminance inverted is no inverted colour's luminance
        np.testing.assert_allclose(got, load_image(tmp_path / "by_hand.png"), rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            load_image(tmp_path / "a.png"), np.vectorize(eotf)(codes / 255), rtol=0, atol=1e-12
        )
