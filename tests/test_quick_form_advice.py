"""The quick form's feasibility messages: what its user can change (options, not keys)."""

from __future__ import annotations

import math
import re

from conftest import cli_said

from scratchfab.design.feasibility import usable_area
from scratchfab.model.design import Board


def _design(args: list[str], capsys) -> tuple[int, str]:
    """Exit code (0: ran through) and everything said."""
    return cli_said(["design", *args, "--resolution", "16"], capsys)


def test_crowding_advises_count_and_board_options(tmp_path, white, capsys):
    """Too many scratches: the error starts 'quick form:' and names --count and --board."""
    code, said = _design(
        [str(white), "--board", "20x20", "--count", "1400", "--out", str(tmp_path / "j")], capsys
    )
    assert code == 2
    fits = math.floor(usable_area(Board(width_mm=20.0, height_mm=20.0)) / (2.0 * 0.1))
    error = said.strip().splitlines()[-1]
    assert error.startswith("error: quick form: 1400 scratches of at least 2 x 0.1 mm")
    assert f"give --count at most {fits} or a larger --board (use --force" in error
    assert "[scratch]" not in error and "<quick form>" not in said


def test_views_too_close_advise_fewer_images(tmp_path, white, capsys):
    """Views the quick form cannot keep apart: fewer images, not 'move one of the views'."""
    code, said = _design([str(white)] * 20 + ["--out", str(tmp_path / "j")], capsys)
    assert code == 2
    error = said.strip().splitlines()[-1]
    assert error.startswith("error: quick form: views 'w' and 'w_2' are indistinguishable")
    assert "give fewer images" in error and "move one of the views" not in error


def test_overlap_warning_advice_brings_the_coverage_to_one(tmp_path, white, capsys):
    """The count and the max_length_mm the warning names each end the warning: the count
    given as --count, the length in the design.toml the quick form wrote."""
    code, said = _design(
        [str(white)] * 2 + ["--board", "20x20", "--count", "600", "--out", str(tmp_path / "a")],
        capsys,
    )
    assert code == 0
    (warning,) = [line for line in said.splitlines() if "will overlap" in line]
    assert "[scratch] count" not in warning
    fits, longest = re.search(
        r"give --count at most (\d+), or set \[scratch\] max_length_mm to at most ([\d.]+) "
        r"in the design.toml it writes and design from that file$",
        warning,
    ).groups()
    code, said = _design(
        [str(white)] * 2 + ["--board", "20x20", "--count", fits, "--out", str(tmp_path / "b")],
        capsys,
    )
    assert code == 0 and "will overlap" not in said
    toml = tmp_path / "a" / "design" / "design.toml"
    text = toml.read_text(encoding="utf-8")
    assert "max_length_mm = 12.0" in text
    toml.write_text(text.replace("max_length_mm = 12.0", f"max_length_mm = {longest}"))
    code, said = _design([str(toml), "--out", str(tmp_path / "c")], capsys)
    assert code == 0 and "will overlap" not in said
