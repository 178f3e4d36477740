"""A rerun of a job's design.toml on an edited board names the values kept from the old one.

The quick form chooses the scratch count, the cameras' and the light's distance and the
views' resolution by the board; a design.toml keeps them when its board is edited. The
rerun says so once, with what the quick form would choose (from quick.py's constants),
and changes nothing.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from PIL import Image

from scratchfab.cli import main
from scratchfab.design.quick import BASE_DISTANCE_MM, COUNT_PER_MM2, DEFAULT_RESOLUTION
from scratchfab.model.design import load_design


@pytest.fixture()
def job(tmp_path: Path, capsys) -> Path:
    """Two pictures designed by the quick form on an 80 x 60 mm board, 40 scratches."""
    images = []
    for name, spot in (("a", (4, 4, 12, 12)), ("b", (20, 10, 30, 20))):
        image = Image.new("L", (40, 30), 200)
        image.paste(40, spot)
        image.save(tmp_path / f"{name}.png")
        images.append(str(tmp_path / f"{name}.png"))
    folder = tmp_path / "job"
    main(["design", *images, "--board", "80x60", "--count", "40", "--out", str(folder)])
    capsys.readouterr()
    return folder


def _board(toml: Path, width: float, height: float) -> None:
    """The user's edit: another board size in the job's design.toml."""
    text = toml.read_text(encoding="utf-8")
    text = re.sub(r"(?m)^width_mm = 80\.0$", f"width_mm = {width}", text, count=1)
    text = re.sub(r"(?m)^height_mm = 60\.0$", f"height_mm = {height}", text, count=1)
    toml.write_text(text, encoding="utf-8")


def _notes(out: str) -> list[str]:
    return [line.strip() for line in out.splitlines() if line.strip().startswith("note: the board")]


def _quick_count(width: float, height: float) -> int:
    return round(COUNT_PER_MM2 * width * height)


def test_an_edited_board_names_the_kept_values_and_what_the_quick_form_would_choose(job, capsys):
    toml = job / "design" / "design.toml"
    before = load_design(toml)
    _board(toml, 200.0, 100.0)
    main(["design", str(toml), "--out", str(job)])
    far = round(BASE_DISTANCE_MM * 200 / 100 / 10)  # cm: the quick form scales past 100 mm
    wide = [DEFAULT_RESOLUTION, round(DEFAULT_RESOLUTION / 2)]
    kept = list(before.views[0].resolution)
    assert _notes(capsys.readouterr().out) == [
        "note: the board is now 200 x 100 mm; kept from the 80 x 60 mm one: [scratch] count "
        f"40 (the quick form lays {_quick_count(200, 100)} here); the cameras' and the "
        f"light's {round(BASE_DISTANCE_MM / 10)} cm (it stands them at {far} cm); resolution "
        f"{kept} (it would use {wide}); change them in {toml} if you want"
    ]
    after = load_design(toml)  # nothing changed but the board
    assert after.scratch.count == before.scratch.count == 40
    assert [v.resolution for v in after.views] == [v.resolution for v in before.views]
    assert [v.position_mm for v in after.views] == [v.position_mm for v in before.views]
    # The file now records its board: a plain rerun has nothing to say.
    main(["design", str(toml), "--out", str(job)])
    assert _notes(capsys.readouterr().out) == []


def test_the_same_shape_larger_names_what_differs_and_not_what_was_given(job, capsys):
    """160 x 120 mm: the pictures fit as they were, the recorded board tells the change;
    the resolution is the quick form's for this shape too, and a --count given is not kept."""
    toml = job / "design" / "design.toml"
    _board(toml, 160.0, 120.0)
    main(["design", str(toml), "--count", "50", "--out", str(job)])
    far = round(BASE_DISTANCE_MM * 160 / 100 / 10)
    assert _notes(capsys.readouterr().out) == [
        "note: the board is now 160 x 120 mm; kept from the 80 x 60 mm one: the cameras' and "
        f"the light's {round(BASE_DISTANCE_MM / 10)} cm (it stands them at {far} cm); change "
        f"them in {toml} if you want"
    ]


def test_a_file_that_records_no_board_is_told_by_its_reshaped_pictures(job, capsys):
    """A design.toml written before the heading recorded the board: a new shape still shows
    (the board pictures are made anew), the old size is not known."""
    toml = job / "design" / "design.toml"
    text = toml.read_text(encoding="utf-8")
    assert "; board 80 x 60 mm.\n" in text
    toml.write_text(text.replace("; board 80 x 60 mm.\n", ".\n"), encoding="utf-8")
    _board(toml, 200.0, 100.0)
    main(["design", str(toml), "--out", str(job)])
    notes = _notes(capsys.readouterr().out)
    assert len(notes) == 1
    assert notes[0].startswith("note: the board is now 200 x 100 mm; kept from the earlier board: ")
    assert f"(the quick form lays {_quick_count(200, 100)} here)" in notes[0]
    # Same shape, no record: nothing to tell it by, nothing said.
    text = toml.read_text(encoding="utf-8")
    toml.write_text(text.replace("; board 200 x 100 mm.\n", ".\n"), encoding="utf-8")
    text = toml.read_text(encoding="utf-8")
    toml.write_text(
        text.replace("width_mm = 200.0\n", "width_mm = 400.0\n").replace(
            "height_mm = 100.0\n", "height_mm = 200.0\n"
        ),
        encoding="utf-8",
    )
    main(["design", str(toml), "--out", str(job)])
    assert _notes(capsys.readouterr().out) == []
