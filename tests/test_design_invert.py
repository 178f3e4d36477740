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


def test_invert_gives_the_picture_inverted_by_hand(pictures, capsys):
    """With gamma and contrast too: the inversion comes first, as an editor's would."""
    image, by_hand = pictures
    tone = ["--gamma", "1.4", "--contrast", "1.2"]
    inverted = _run(["design", str(image), *BOARD, *tone, "--invert", "--out", "a"], capsys)
    _run(["design", str(by_hand), *BOARD, *tone, "--out", "b"], capsys)
    _assert_same(Path("a"), Path("b"))
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


def test_a_dark_logo_on_a_transparent_ground_inverted_says_what_became_of_the_ground(
    tmp_path, capsys
):
    """Transparent pixels read black, so inverted they turn white with the logo: all white."""
    rgba = np.zeros((36, 48, 4), dtype=np.uint8)
    rgba[6:30, 6:20, 3] = 255  # an opaque black block on a transparent ground
    Image.fromarray(rgba).save(tmp_path / "logo.png")
    logo = str(tmp_path / "logo.png")
    out = _run(["design", logo, *BOARD, "--fit", "cover", "--invert", "--out", "a"], capsys)
    board, _target, _layout = _made(Path("a"))
    assert board.min() == board.max() == 65535  # white everywhere on the board
    assert re.search(
        r"warning: target 'logo' is uniform .*transparent pixels read as black, and "
        "inverting turns them white",
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


def test_a_rerun_on_a_board_of_another_shape_inverts_the_first_image_again(pictures, capsys):
    """The board picture is made anew from the image the first design inverted."""
    image, by_hand = pictures
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
