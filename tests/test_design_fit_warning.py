"""Design warns when the machine it times cannot reach the whole layout, as toolpath will.

The references are the toolpath stage's own: its counts of what the envelope leaves out
(``plan_toolpath``) and the warning ``scratchfab toolpath --force`` prints for the same
layout and machine.
"""

from __future__ import annotations

from pathlib import Path

from conftest import cli_run, design_sun_and_moon, write_pipeline
from cut_said import cut_sentence, cut_warning

from scratchfab.bundled import bundled_dir
from scratchfab.machine.profile import load_profile
from scratchfab.model.design import load_design
from scratchfab.model.scratches import load_scratches
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline
from scratchfab.toolpath.plan import plan_toolpath

DEMO = bundled_dir("demo")
PROFILE = bundled_dir("machine_profiles") / "grbl-3018-diamond.toml"


def _design(job: Path, board: str, capsys, *extra: str) -> list[str]:
    """``scratchfab design`` on the demo's sun and house filling the board: its lines."""
    images = [str(DEMO / "sun.png"), str(DEMO / "house.png")]
    argv = ["design", *images, "--board", board, "--count", "400", "--resolution", "24"]
    code, out, err = cli_run([*argv, "--fit", "cover", *extra, "--out", str(job)], capsys)
    assert code == 0, err
    return out.splitlines()


def test_a_board_wider_than_the_travel_is_warned_of_in_the_toolpaths_words(tmp_path, capsys):
    """320 x 100 mm on the 3018 (300 x 180 mm of travel): the owner's board."""
    job = tmp_path / "job"
    warning = cut_warning(_design(job, "320x100", capsys))
    assert warning is not None
    design = load_design(job / "design" / "design.toml", require_views=False)
    scratches = load_scratches(job / "design" / "scratches.csv", design.scratch)
    stats = plan_toolpath(scratches, design.board, load_profile("grbl-3018-diamond")).stats
    assert stats["outside_count"] > 0  # the case is one: scratches lie beyond X 0
    assert (
        f"{stats['outside_count']} of 400 scratches lie outside the machine's envelope (not cut) "
        f"and {stats['clipped_count']} are clipped to it" in warning
    )
    assert "make the board at most 300 x 180 mm" in warning
    # the toolpath stage's own warning for the same layout, word for word
    code, out, err = cli_run(
        ["toolpath", str(job), "--machine", "grbl-3018-diamond", "--force"], capsys
    )
    assert code == 0, err
    said = [line for line in (out + err).splitlines() if "cannot reach the whole" in line]
    assert said == [f"{warning} (see preview.png)"]
    # the time is the part it reaches, and says so
    assert " of the part it reaches (" in cut_sentence(
        _design(tmp_path / "again", "320x100", capsys)
    )


def test_a_board_within_reach_is_not_warned_of_and_its_cut_line_is_wrapped(tmp_path, capsys):
    out = design_sun_and_moon(tmp_path / "job", "100x100", 400, capsys).splitlines()
    assert cut_warning(out) is None
    assert not any("cannot reach" in line for line in out)
    start = next(i for i, line in enumerate(out) if line.startswith("  cut: "))
    block = out[start : start + 4]
    assert block[0].startswith("  cut: 400 scratches, ") and block[0].endswith(" m of cut")
    assert block[1].startswith("    about ")
    assert block[3].startswith("    --count lays fewer")
    assert max(map(len, block)) < 200, block


def test_a_board_wholly_outside_is_designed_with_the_toolpaths_refusal_said(tmp_path, capsys):
    """Design keeps the layout (another machine may hold it) and says what toolpath will say."""
    text = PROFILE.read_text(encoding="utf-8")
    assert "offset_mm = [-220.0, -150.0]" in text
    away = tmp_path / "away.toml"
    away.write_text(text.replace("offset_mm = [-220.0, -150.0]", "offset_mm = [-600.0, -150.0]"))
    job = tmp_path / "job"
    lines = _design(job, "100x100", capsys, "--machine", str(away))
    warning = cut_warning(lines)
    assert warning is not None and (job / "design" / "scratches.csv").is_file()
    code, _, err = cli_run(["toolpath", str(job), "--machine", str(away)], capsys)
    assert code != 0
    refusal = err.strip().removeprefix("error: ")
    assert refusal and warning == f"warning: the toolpath stage will refuse this layout: {refusal}"
    assert "no time estimate on machine " in cut_sentence(lines)


def test_run_until_design_warns_once_before_design(tmp_path):
    """README: a board the envelope cuts short is warned of once, before the first stage that
    runs, also when --until stops before toolpath; the design stage does not say it again."""
    path = write_pipeline(tmp_path, edits={"width_mm = 30.0": "width_mm = 400.0"})
    said: list[str] = []
    run_pipeline(load_pipeline(path), tmp_path / "job", until="design", say=said.append)
    assert said[0].startswith("warning: the 400 x 30 mm board (corners "), said[:2]
    assert said[1] == "[design] running"
    warnings = [s for s in said if "reaches beyond" in s or "cannot reach the whole" in s]
    assert warnings == said[:1], warnings
    # the design stage timed the part within reach all the same
    assert " of the part it reaches (" in cut_sentence(said, indent="    ")
    assert cut_warning(said, indent="    ") is None
