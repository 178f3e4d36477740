"""The mostly-bright warning names what inverts that view alone.

With several targets, ``--invert`` turns every view's picture negative, a light one too:
the warning names the view's ``invert = true`` instead, and the command ``run`` (which
takes no ``--invert``) is never told to use it.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scratchfab.cli import main
from scratchfab.design.stage import run_design
from scratchfab.model.design import load_design

BOARD = ["--board", "30x20", "--resolution", "16x12", "--count", "40"]


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def pictures() -> tuple[Path, Path]:
    """A dark-on-white logo (mostly bright) and a light-on-dark mark (not)."""
    logo = np.full((36, 48), 255, np.uint8)
    logo[6:30, 6:10] = logo[6:30, 16:20] = logo[16:20, 6:20] = 0
    mark = np.zeros((36, 48), np.uint8)
    mark[8:28, 10:38] = 230
    paths = Path("logo.png"), Path("mark.png")
    for path, pixels in zip(paths, (logo, mark), strict=True):
        Image.fromarray(pixels).save(path)
    return paths


def _warning(out: str, view: str) -> str:
    found = re.search(rf"warning: target '{view}' is mostly bright[^\n]*", out)
    assert found, out
    return found.group(0)


def test_the_quick_form_with_two_targets_names_the_views_own_invert(pictures, capsys):
    logo, mark = pictures
    main(["design", str(logo), str(mark), *BOARD, "--out", "a"])
    out = capsys.readouterr().out
    said = _warning(out, "logo")
    assert "mostly bright" not in out.replace(said, "")  # the light mark is not warned of
    assert "views[0] invert = true in the job's design/design.toml" in said
    assert "--invert would turn all 2 views negative" in said
    assert "design again with --invert" not in said
    # The advice works: the job's design file, its logo view inverted, designs the logo
    # negative and leaves the light mark as it was.
    toml = Path("a/design/design.toml")
    text = toml.read_text()
    first = text.index("invert = false", text.index('name = "logo"'))
    toml.write_text(text[:first] + "invert = true" + text[first + len("invert = false") :])
    assert [v.invert for v in load_design(toml).views] == [True, False]
    main(["design", str(toml), "--out", "b"])
    assert "mostly bright" not in capsys.readouterr().out
    for view, same in (("logo", False), ("mark", True)):
        a, b = (np.asarray(Image.open(f"{j}/design/targets/{view}.png")) for j in "ab")
        assert np.array_equal(a, b) is same


def test_one_quick_target_is_still_told_the_option(pictures, capsys):
    main(["design", str(pictures[0]), *BOARD, "--out", "a"])
    said = _warning(capsys.readouterr().out, "logo")
    assert said.endswith("to invert a dark-on-white image, design again with --invert")


def test_a_pipelines_design_is_told_its_views_key_not_the_option(pictures, capsys):
    """``run`` designs from the pipeline file, and takes no --invert."""
    main(["design", *map(str, pictures), *BOARD, "--out", "a"])
    capsys.readouterr()
    design = load_design(Path("a/design/design.toml"))
    lines: list[str] = []
    run_design(replace(design, source="art.toml"), Path("b"), progress=lines.append)
    said = _warning("\n".join(lines), "logo")
    assert said.endswith("design again with views[0] invert = true in art.toml")
