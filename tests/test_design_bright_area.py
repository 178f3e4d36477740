"""The mostly-bright warning measures a picture over its own part of the board.

A 4:3 photo of dark text on a light ground fitted (``contain``) to a square board gets
black bars over a quarter of it; the board's mean is the picture's times 3/4, so a
picture of mean 0.65 reads 0.49 on the board and would slip under the 0.5 threshold
that was measured on pictures filling their board.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import cli_run
from PIL import Image

from scratchfab.design.stage import BRIGHT_TARGET_MEAN


def _text_picture(width: int, height: int) -> np.ndarray:
    """8-bit dark bands ("lines of text") over 35 % of a white picture's rows."""
    rows = np.arange(height)
    dark = (rows * 20 // height) % 20 < 7  # 7 of every 20 rows' worth
    picture = np.full((height, width), 255, np.uint8)
    picture[dark] = 0
    return picture


def _linear_mean(codes: np.ndarray) -> float:
    """Mean linear brightness of 8-bit sRGB codes, decoded here."""
    v = codes.astype(np.float64) / 255.0
    return float(np.mean(np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)))


def _board_mean(job: Path, name: str) -> float:
    """The mean linear brightness of a view's 16-bit board picture, bars included."""
    v = np.asarray(Image.open(job / "design" / "board" / f"{name}.png"), np.float64) / 65535.0
    return float(np.mean(np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)))


def _warned(out: str) -> dict[str, str]:
    return {line.split("'")[1]: line for line in out.splitlines() if "mostly bright" in line}


@pytest.fixture
def pictures(tmp_path: Path) -> dict[str, np.ndarray]:
    made = {
        "square": _text_picture(120, 120),
        "photo": _text_picture(160, 120),  # 4:3, letterboxed on a square board
        "square_inv": 255 - _text_picture(120, 120),
        "photo_inv": 255 - _text_picture(160, 120),
    }
    for name, codes in made.items():
        Image.fromarray(codes).save(tmp_path / f"{name}.png")
    return made


def test_dark_text_on_light_warns_at_1_1_and_4_3_and_its_inverse_at_neither(
    tmp_path, capsys, pictures
):
    job = tmp_path / "job"
    code, out, _ = cli_run(
        ["design", *(str(tmp_path / f"{n}.png") for n in pictures), "--board", "60x60",
         "--count", "200", "--resolution", "24", "--out", str(job)],
        capsys,
    )  # fmt: skip
    assert code == 0
    own = {name: _linear_mean(codes) for name, codes in pictures.items()}
    # the case at hand: over the picture above the threshold, on the board (bars) below it
    assert own["photo"] > BRIGHT_TARGET_MEAN > _board_mean(job, "photo")
    assert own["square_inv"] < BRIGHT_TARGET_MEAN and own["photo_inv"] < BRIGHT_TARGET_MEAN
    warned = _warned(out)
    assert sorted(warned) == ["photo", "square"]
    # the figure named is the picture's own mean (resampling moves it a little)
    assert f"mean linear brightness {own['square']:.2f} on the board" in warned["square"]
    found = warned["photo"].split("mean linear brightness ")[1]
    assert abs(float(found.split()[0]) - own["photo"]) < 0.01
    assert "the fit's black bars" in warned["photo"]
    assert f"{_board_mean(job, 'photo'):.2f} with them" in warned["photo"]


def test_a_rerun_from_the_design_file_still_measures_without_the_bars(tmp_path, capsys, pictures):
    """The board picture a rerun reads has the bars in it; they are still left out."""
    job = tmp_path / "job"
    args = ["--board", "60x60", "--count", "200", "--resolution", "24"]
    code, first, _ = cli_run(
        ["design", str(tmp_path / "photo.png"), *args, "--out", str(job)], capsys
    )
    assert code == 0 and "photo" in _warned(first)
    code, again, _ = cli_run(
        ["design", str(job / "design" / "design.toml"), "--out", str(job)], capsys
    )
    assert code == 0
    # the same figures; the advice names the file's key now
    assert _warned(again)["photo"].split("; ")[0] == _warned(first)["photo"].split("; ")[0]
    assert "the fit's black bars left out" in _warned(again)["photo"]
