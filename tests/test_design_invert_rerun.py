"""``design JOB/design/design.toml --invert``: a rerun inverts the picture, not the bars.

The earlier design's ``contain`` fit put black bars (bare board) beside the picture;
inverted with it they turned white, to be cut. The reference is the picture inverted by
hand and designed the same way: its bars are black by construction. On the picture's
own part the two agree to the resampling (inverting before or after it differs a little).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_design_invert import BOARD, _logo, _run

from scratchfab.model.job import JobLayout


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)


def _board_picture(job: str) -> np.ndarray:
    """A job's board picture as 16-bit codes."""
    return np.asarray(Image.open(JobLayout(Path(job)).design.board_png("logo")), np.float64)


def _narrow(job: str) -> None:
    """The job's design.toml for an 18 x 20 mm board (bars above and below, made anew)."""
    file = Path(job) / "design" / "design.toml"
    text = re.sub(r"(?m)^width_mm = 30\.0$", "width_mm = 18.0", file.read_text(), count=1)
    assert text != file.read_text()
    file.write_text(text)


def _picture() -> np.ndarray:
    """The logo with codes 30 to 225: no pixel of it, or of it inverted, is black."""
    return np.clip(_logo(), 30, 225).astype(np.uint8)


def _inside(mask: np.ndarray) -> np.ndarray:
    """``mask`` less its edge: a pixel whose four neighbours are in it too."""
    inner = mask.copy()
    inner[1:] &= mask[:-1]
    inner[:-1] &= mask[1:]
    inner[:, 1:] &= mask[:, :-1]
    inner[:, :-1] &= mask[:, 1:]
    return inner


@pytest.mark.parametrize("shape", ["same", "another"])
def test_a_rerun_with_invert_keeps_the_earlier_bars_black(shape, capsys):
    """The 48 x 36 px picture on 30 x 20 mm has bars left and right; on 18 x 20 mm, made
    anew from the image, bars above and below too."""
    Path("image").mkdir()
    Path("by_hand").mkdir()
    Image.fromarray(_picture()).save("image/logo.png")
    Image.fromarray(255 - _picture()).save("by_hand/logo.png")
    _run(["design", "image/logo.png", *BOARD, "--out", "a"], capsys)
    _run(["design", "by_hand/logo.png", *BOARD, "--out", "b"], capsys)
    if shape == "another":
        _narrow("a")
        _narrow("b")
        out = _run(["design", "b/design/design.toml", "--out", "b2"], capsys)
        assert "made anew from" in out
        reference = _board_picture("b2")
    else:
        reference = _board_picture("b")
    out = _run(["design", "a/design/design.toml", "--invert", "--out", "a2"], capsys)
    assert ("made anew from" in out) == (shape == "another")
    inverted = _board_picture("a2")
    assert inverted.shape == reference.shape
    # the bars: black in the reference (the picture has no black), less the pixels on
    # their edge, which the resampling shares between picture and bar
    bars = _inside(reference == 0)
    assert bars.mean() > 0.05, bars.mean()  # the fits did add bars
    assert inverted[bars].max() == 0, "a bar of the earlier fit was inverted to white"
    # the picture's own part: as the image inverted by hand, to the resampling (which
    # inverting before or after changes at the letters' edges)
    picture = _inside(reference > 0)
    assert np.median(np.abs(inverted - reference)[picture]) / 65535 < 0.02
    if shape == "same":  # the earlier board picture inverted by hand, code 65535 - c
        np.testing.assert_allclose(inverted[picture], 65535 - _board_picture("a")[picture], atol=2)
