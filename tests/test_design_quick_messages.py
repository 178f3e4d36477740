"""The quick form's limits and what its messages advise: each piece of advice, followed, works.

The quick form places its views itself (scratchfab.design.quick), so its messages name
options (--count, --board, fewer images) or the design.toml, never a key it has no file for.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_said

from scratchfab.cli import main
from scratchfab.design import quick
from scratchfab.design.feasibility import check_feasibility, glint_limit_deg
from scratchfab.design.quick import COUNT_CAP, COUNT_PER_MM2, quick_design, quick_mapping
from scratchfab.model.design import design_from_mapping

GLINT_WORDS = "mirrors the light"


def _design(args: list[str], capsys) -> tuple[int, str]:
    """Exit code (0: ran through) and everything said."""
    return cli_said(["design", *args], capsys)


def _least_tilt_deg(design, samples: int = 121) -> float:
    """The smallest half-vector tilt (deg) over a dense grid of the board, edges included,
    computed here from the camera and light positions alone."""
    hw, hh = design.board.width_mm / 2, design.board.height_mm / 2
    x, y = np.meshgrid(np.linspace(-hw, hw, samples), np.linspace(-hh, hh, samples))
    p = np.stack([x, y, np.zeros_like(x)], axis=-1)
    least = 90.0
    for view in design.views:
        wi = np.asarray(design.light_for(view)) - p
        wo = np.asarray(view.camera_position) - p
        h = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
        h = h + wo / np.linalg.norm(wo, axis=-1, keepdims=True)
        tilt = np.degrees(np.arccos(h[..., 2] / np.linalg.norm(h, axis=-1)))
        least = min(least, float(tilt.min()))
    return least


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
@pytest.mark.parametrize("board", [(100.0, 100.0), (30.0, 30.0), (600.0, 600.0), (400.0, 40.0)])
def test_the_quick_form_never_glints_so_no_option_is_advised_for_it(n, board):
    """Its one tool and a distance that grows with boards above 100 mm keep every
    half-vector of every view above the glint limit, on any board and up to 8 images
    (a smaller --board, once advised, could not have helped)."""
    design = quick_design([f"v{i}.png" for i in range(n)], board)
    tool = design.scratch
    limit = glint_limit_deg(tool.width_mm, tool.depth_mm, design.board.roughness)
    assert _least_tilt_deg(design) > limit + 1.0


def test_a_quick_design_that_glints_advises_a_design_toml_not_an_option():
    """Were a quick-form view to glint, the message sends its user to a design.toml (where
    the cameras and light can move), not to an option that cannot move them."""
    data = quick_mapping(["sun.png"], (100.0, 100.0))
    distance = data["views"][0]["distance_mm"]
    data["light"]["position_mm"] = [0.0, 0.02 * distance, distance]  # beside the camera
    report = check_feasibility(design_from_mapping(data, quick.SOURCE, Path.cwd()))
    said = [m for m in report.errors + report.warnings if GLINT_WORDS in m]
    assert len(said) == 1
    assert "design from a design.toml" in said[0] and "move the camera or the light" in said[0]
    assert "--board" not in said[0]


def test_views_too_close_are_one_error_naming_the_pairs_and_how_many_images_fit(white, tmp_path):
    """Ten images: one error naming the pairs (not one per pair), advising at most N images;
    N images then design without it, N + 1 do not."""
    report = check_feasibility(quick_design([white] * 10, (100.0, 100.0)))
    errors = [e for e in report.errors if "indistinguishable" in e]
    assert len(errors) == 1
    (error,) = errors
    assert error.count("indistinguishable") == 1 and error.count("give fewer images") == 1
    assert error.startswith("views 'w' and 'w_2' are indistinguishable, as are 'w_2' and 'w_3'")
    pairs = int(re.search(r"\((\d+) pairs\)", error).group(1))
    named = re.findall(r"'(w(?:_\d+)?)' and '(w(?:_\d+)?)'", error)
    more = re.search(r"and (\d+) more pairs", error)
    assert pairs == len(named) + (int(more.group(1)) if more else 0)
    most = int(re.search(r"give fewer images \(at most (\d+)\)$", error).group(1))
    assert 1 <= most < 10
    fewer = check_feasibility(quick_design([white] * most, (100.0, 100.0)))
    assert not [e for e in fewer.errors if "indistinguishable" in e]
    one_more = check_feasibility(quick_design([white] * (most + 1), (100.0, 100.0)))
    assert [e for e in one_more.errors if "indistinguishable" in e]


def test_a_file_design_with_several_close_pairs_says_move_them_once():
    """A design file's close pairs: one error, one piece of advice for them all."""
    data = quick_mapping([f"v{i}.png" for i in range(10)], (100.0, 100.0))
    report = check_feasibility(design_from_mapping(data, "scene.toml", Path.cwd()))
    (error,) = [e for e in report.errors if "indistinguishable" in e]
    assert error.endswith("; move the views of each pair apart")
    assert "give fewer images" not in error


def test_default_count_is_capped_on_large_boards_with_a_line_saying_how_to_ask_for_more(
    white, tmp_path, capsys, monkeypatch
):
    """0.5 per mm^2 stays for boards up to the cap (100 x 100 mm: 5000, 600 x 600 mm:
    180000, as before); a larger board gets the cap and a line naming the --count that
    lays them all."""
    assert quick_design([white], (100.0, 100.0)).scratch.count == 5000
    assert quick_design([white], (30.0, 20.0)).scratch.count == round(COUNT_PER_MM2 * 600)
    side = math.sqrt(COUNT_CAP / COUNT_PER_MM2)
    assert quick_design([white], (side, side)).scratch.count == COUNT_CAP
    assert quick_design([white], (600.0, 600.0)).scratch.count == 180_000 < COUNT_CAP
    assert quick_design([white], (1000.0, 1000.0)).scratch.count == COUNT_CAP
    assert quick_design([white], (1000.0, 1000.0), count=30).scratch.count == 30
    # 10 m square: 50 million at 0.5 per mm^2 was refused (scratch.count's most is 1e7)
    assert quick_design([white], (10000.0, 10000.0)).scratch.count == COUNT_CAP

    # The command line, with a cap small enough for a quick layout: the line, its --count.
    monkeypatch.setattr(quick, "COUNT_CAP", 50)
    common = [str(white), "--resolution", "8", "--board", "20x20"]
    code, said = _design([*common, "--out", str(tmp_path / "a")], capsys)
    assert code == 0
    (note,) = [line for line in said.splitlines() if "the default's most" in line]
    assert note.startswith("quick form: 50 scratches")
    assert "50 scratches on a 20 x 20 mm board" in said
    wanted = int(re.search(r"give --count (\d+) for all of them$", note).group(1))
    assert wanted == round(COUNT_PER_MM2 * 20 * 20)
    code, said = _design([*common, "--count", str(wanted), "--out", str(tmp_path / "b")], capsys)
    assert code == 0 and "the default's most" not in said
    assert f"{wanted} scratches on a 20 x 20 mm board" in said
    code, said = _design([*common[:-1], "10x10", "--out", str(tmp_path / "c")], capsys)
    assert code == 0 and "the default's most" not in said
    assert f"{round(COUNT_PER_MM2 * 100)} scratches on a 10 x 10 mm board" in said


def test_crowding_error_and_overlap_warning_name_each_others_count(white, tmp_path, capsys):
    """Too many scratches: the error counts them at their shortest, the warning at the
    lengths the targets give them; each names the other's count, and following the
    warning's count ends both."""
    common = [str(white), "--board", "20x20", "--resolution", "16"]
    code, said = _design([*common, "--count", "1400", "--out", str(tmp_path / "a")], capsys)
    assert code == 2
    (warning,) = [line for line in said.splitlines() if "will overlap" in line]
    error = said.strip().splitlines()[-1]
    soft = int(re.search(r"give --count at most (\d+) \(the crowding error's", warning).group(1))
    hard = int(re.search(r"the crowding error's (\d+) counts", warning).group(1))
    assert re.search(rf"\b{soft} fit: the overlap warning's count\)", error)
    assert f"give --count at most {hard} or a larger --board" in error
    assert soft < hard < 1400
    code, said = _design([*common, "--count", str(soft), "--out", str(tmp_path / "b")], capsys)
    assert code == 0 and "will overlap" not in said and "error:" not in said


def test_help_names_the_default_counts_cap(capsys):
    main(["design", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"quick form: {COUNT_PER_MM2:g} per mm^2, at most {COUNT_CAP})" in text
