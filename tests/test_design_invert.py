"""``design --invert`` and a view's ``invert = true``: the target turned negative, as by hand.

The reference is the image inverted the way an image editor does it (8-bit code 255 - c),
then designed without the option: the board picture, the camera targets and the layout
must be the same.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from PIL import Image

from scratchfab.cli import main
from scratchfab.design.quick import quick_mapping
from scratchfab.model.design import load_design
from scratchfab.model.job import JobLayout

BOARD = ["--board", "30x20", "--resolution", "16x12", "--count", "40"]


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    main(args)
    return capsys.readouterr().out


def _logo() -> np.ndarray:
    """An 8-bit grey picture: dark letters and a grey ramp on white (mostly bright)."""
    rng = np.random.default_rng(7)
    img = np.full((36, 48), 255, dtype=np.uint8)
    img[6:30, 6:10] = 0  # an H
    img[6:30, 16:20] = 0
    img[16:20, 6:20] = 0
    img[6:30, 26:30] = 20  # an I
    img[32:36, :] = np.linspace(0, 255, 48).astype(np.uint8)
    img[0:4, 30:48] = rng.integers(0, 256, (4, 18), dtype=np.uint8)
    return img


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def pictures(tmp_path: Path) -> tuple[Path, Path]:
    """The picture, and the same picture inverted by hand, both named logo.png."""
    image, by_hand = tmp_path / "image" / "logo.png", tmp_path / "by_hand" / "logo.png"
    for path, pixels in ((image, _logo()), (by_hand, 255 - _logo())):
        path.parent.mkdir()
        Image.fromarray(pixels).save(path)
    return image, by_hand


def _made(job: Path, view: str = "logo") -> tuple[np.ndarray, np.ndarray, str]:
    """A job's board picture (16-bit codes), camera target and initial layout."""
    folder = JobLayout(job).design
    board = np.asarray(Image.open(folder.board_png(view)))
    return board, np.load(folder.target_npy(view)), folder.initial_scratches.read_text()


def _assert_same(a: Path, b: Path, view: str = "logo", b_view: str = "logo") -> None:
    board_a, target_a, layout_a = _made(a, view)
    board_b, target_b, layout_b = _made(b, b_view)
    np.testing.assert_array_equal(board_a, board_b)
    np.testing.assert_array_equal(target_a, target_b)
    assert layout_a == layout_b


def _inverted_as_by_hand(image: Path, by_hand: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """Design ``image`` with --invert (job a) and ``by_hand`` without (job b), with gamma
    and contrast too; assert the jobs alike; what the inverted design printed."""
    tone = ["--gamma", "1.4", "--contrast", "1.2"]
    inverted = _run(["design", str(image), *BOARD, *tone, "--invert", "--out", "a"], capsys)
    _run(["design", str(by_hand), *BOARD, *tone, "--out", "b"], capsys)
    _assert_same(Path("a"), Path("b"))
    return inverted


def test_invert_gives_the_picture_inverted_by_hand(pictures, capsys):
    """With gamma and contrast too: the inversion comes first, as an editor's would."""
    image, by_hand = pictures
    inverted = _inverted_as_by_hand(image, by_hand, capsys)
    assert "mostly bright" not in inverted
    # the job's design.toml names the inverted board picture: a rerun keeps it as it is
    text = (Path("a") / "design" / "design.toml").read_text()
    assert "invert = false" in text
    assert "#   inverted (1 - its sRGB-encoded value) before the options above" in text
    assert not load_design(Path("a") / "design" / "design.toml").views[0].invert


def test_the_mostly_bright_warning_names_the_option(pictures, capsys):
    image, by_hand = pictures
    out = _run(["design", str(image), *BOARD, "--out", "a"], capsys)
    assert re.search(r"warning: target 'logo' is mostly bright .*design again with --invert", out)
    out = _run(["design", str(by_hand), *BOARD, "--invert", "--out", "b"], capsys)
    assert re.search(
        r"warning: target 'logo' is mostly bright .*it was inverted \(--invert\): leave that "
        "off for an image that is light on dark already",
        out,
    )


@pytest.fixture
def transparent_logo(tmp_path: Path) -> tuple[Path, Path]:
    """A dark logo on a transparent ground, and by hand its white logo on black, opaque."""
    grey = _logo()
    opaque = grey < 128  # the logo's strokes (codes 0 and 20) and the ramp's dark end
    rgba = np.zeros((*grey.shape, 4), dtype=np.uint8)
    rgba[..., :3] = np.where(opaque, grey, 255)[..., None]  # white under the transparency
    rgba[..., 3] = np.where(opaque, 255, 0)
    image, by_hand = (tmp_path / "transparent" / name / "logo.png" for name in ("a", "b"))
    image.parent.mkdir(parents=True)
    by_hand.parent.mkdir()
    Image.fromarray(rgba, "RGBA").save(image)
    Image.fromarray(np.where(opaque, 255 - grey, 0).astype(np.uint8)).save(by_hand)
    return image, by_hand


def test_a_dark_logo_on_a_transparent_ground_inverted_turns_white_on_the_bare_board(
    transparent_logo, capsys
):
    """The colours are inverted, then composited over black: the ground stays black."""
    image, by_hand = transparent_logo
    out = _inverted_as_by_hand(image, by_hand, capsys)
    assert "warning: target" not in out


def test_a_dark_logo_on_a_transparent_ground_is_refused_naming_invert(tmp_path, capsys):
    """Its strokes (codes 0 and 20) below the black limit, the ground transparent."""
    grey = _logo()
    rgba = np.zeros((*grey.shape, 4), dtype=np.uint8)
    rgba[..., :3] = grey[..., None]
    rgba[..., 3] = np.where(grey <= 20, 255, 0)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "logo.png")
    with pytest.raises(SystemExit):
        main(["design", str(tmp_path / "logo.png"), *BOARD, "--out", "a"])
    err = capsys.readouterr().err
    assert "the picture is black on the board" in err
    assert (
        "a dark logo on a transparent ground: make the logo white, or design again with "
        "--invert" in err
    )


def test_a_transparent_ground_is_named_bare_board_inverted_or_not(tmp_path, capsys):
    """A fully transparent picture, inverted, is still black: refused, then uniform if forced."""
    Image.fromarray(np.zeros((36, 48, 4), dtype=np.uint8), "RGBA").save(tmp_path / "clear.png")
    clear = str(tmp_path / "clear.png")
    with pytest.raises(SystemExit):
        main(["design", clear, *BOARD, "--invert", "--out", "a"])
    err = capsys.readouterr().err
    assert "(brightest 0.000, inverted by --invert)" in err
    assert "(leave --invert off for one that is light on dark already)" in err
    out = _run(["design", clear, *BOARD, "--invert", "--force", "--out", "a"], capsys)
    assert re.search(
        r"warning: target 'clear' is uniform .*transparent pixels read as black \(bare "
        r"board\), inverted or not",
        out,
    )


def test_a_views_invert_key_inverts_that_view_alone(pictures, capsys):
    """invert = true under one view of a design file; the other view's picture is kept."""
    image, by_hand = pictures
    data = quick_mapping([image, image], (30.0, 20.0), 40, (16, 12))
    data["views"][1]["invert"] = True
    names = [v["name"] for v in data["views"]]
    Path("design.toml").write_text(tomli_w.dumps(data))
    out = _run(["design", "design.toml", "--out", "a"], capsys)
    assert "mostly bright (mean linear brightness" in out and "views[0] invert = true" in out
    data["views"][1]["target"] = str(by_hand)
    data["views"][1].pop("invert")
    Path("by_hand.toml").write_text(tomli_w.dumps(data))
    _run(["design", "by_hand.toml", "--out", "b"], capsys)
    _assert_same(Path("a"), Path("b"), names[1], names[1])
    _assert_same(Path("a"), Path("b"), names[0], names[0])


@pytest.mark.parametrize("kind", ["opaque", "transparent"])
def test_a_rerun_on_a_board_of_another_shape_inverts_the_first_image_again(
    kind, pictures, transparent_logo, capsys
):
    """The board picture is made anew from the image the first design inverted.

    A transparent ground stays black in the picture made anew too.
    """
    image, by_hand = pictures if kind == "opaque" else transparent_logo
    tone = ["--gamma", "0.8"]
    _run(["design", str(image), *BOARD, *tone, "--invert", "--out", "a"], capsys)
    _run(["design", str(by_hand), *BOARD, *tone, "--out", "b"], capsys)
    for job in ("a", "b"):
        file = Path(job) / "design" / "design.toml"
        text = re.sub(r"(?m)^width_mm = 30\.0$", "width_mm = 18.0", file.read_text(), count=1)
        file.write_text(text)
        out = _run(["design", str(file), "--out", job], capsys)
        assert "was made for a board of another shape; made anew from" in out
    _assert_same(Path("a"), Path("b"))
