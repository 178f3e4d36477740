"""A rerun of a job's design.toml on a board of another shape fits the first image anew."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scratchfab.cli import main

QUICK = ["--count", "40", "--resolution", "12"]


@pytest.fixture()
def wide(tmp_path: Path) -> Path:
    """A 2:1 picture: a grey field with a dark square, no black anywhere."""
    path = tmp_path / "in" / "wide.png"
    path.parent.mkdir()
    image = Image.new("L", (40, 20), 200)
    image.paste(40, (16, 6, 24, 14))
    image.save(path)
    return path


def _picture(job: Path) -> np.ndarray:
    return np.asarray(Image.open(job / "design" / "board" / "wide.png"))


def _reshape(toml: Path, width: float) -> None:
    """The user's edit: another board width in the job's design.toml."""
    text = toml.read_text(encoding="utf-8")
    assert text.count("width_mm = 30.0\n") == 1
    toml.write_text(text.replace("width_mm = 30.0\n", f"width_mm = {width}\n"), encoding="utf-8")


@pytest.mark.parametrize("gamma", ["1", "2"])
def test_a_wider_board_fits_the_first_image_anew(wide, tmp_path, capsys, gamma):
    """The picture equals one a design made from the image on that board, options and all;
    fitting the old square picture again would put its black bars inside the new ones."""
    job, fresh = tmp_path / "job", tmp_path / "fresh"
    main(["design", str(wide), "--board", "30x30", *QUICK, "--gamma", gamma, "--out", str(job)])
    assert _picture(job)[0].max() == 0  # contain on a square board: a black bar on top
    toml = job / "design" / "design.toml"
    _reshape(toml, 60.0)
    capsys.readouterr()
    main(["design", str(toml), "--out", str(job)])
    out = capsys.readouterr().out
    picture = job / "design" / "board" / "wide.png"
    assert (
        f"target 'wide': {picture} was made for a board of another shape; made anew from "
        f"{wide.resolve()}, fitted to this 60 x 30 mm board" in out
    )
    main(["design", str(wide), "--board", "60x30", *QUICK, "--gamma", gamma, "--out", str(fresh)])
    np.testing.assert_array_equal(_picture(job), _picture(fresh))
    assert _picture(job).min() > 0  # no bar left
    lines = toml.read_text(encoding="utf-8").splitlines()
    named = lines.index(f"# wide: {picture}")
    assert lines[named + 1].endswith(
        f"made from {wide.resolve()} (fit = contain, gamma = {gamma}, contrast = 1)"
    )
    assert lines[named + 2].startswith("#   refitted from that image")

    # The picture now fits the board: a plain rerun uses it as it is and says nothing.
    main(["design", str(toml), "--out", str(job)])
    assert "made anew" not in capsys.readouterr().out
    np.testing.assert_array_equal(_picture(job), _picture(fresh))
    assert not [
        line for line in toml.read_text(encoding="utf-8").splitlines() if "refitted" in line
    ]


def test_the_same_shape_keeps_the_picture(wide, tmp_path, capsys):
    """A larger board of the same shape reads the board picture as before."""
    job = tmp_path / "job"
    main(["design", str(wide), "--board", "30x30", *QUICK, "--out", str(job)])
    before = _picture(job)
    toml = job / "design" / "design.toml"
    text = toml.read_text(encoding="utf-8")
    toml.write_text(text.replace(" = 30.0\n", " = 45.0\n"), encoding="utf-8")
    capsys.readouterr()
    main(["design", str(toml), "--out", str(job)])
    assert "made anew" not in capsys.readouterr().out
    np.testing.assert_array_equal(_picture(job), before)


def test_a_missing_first_image_is_named(wide, tmp_path, capsys):
    job = tmp_path / "job"
    main(["design", str(wide), "--board", "30x30", *QUICK, "--out", str(job)])
    toml = job / "design" / "design.toml"
    _reshape(toml, 60.0)
    wide.unlink()
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["design", str(toml), "--out", str(job)])
    err = capsys.readouterr().err.strip()
    assert info.value.code == 2 and "\n" not in err
    picture = job / "design" / "board" / "wide.png"
    assert err.startswith(
        f"error: {toml}: views[0].target ('wide'): {picture} is the board picture an earlier "
        "design made for a board of another shape (256 x 256 pixels, this board is 60 x 30 mm)"
    )
    assert str(wide.resolve()) in err and "set the target to that image" in err
    assert _picture(job).shape == (256, 256)  # nothing written
