"""The cut line's way to fewer scratches never sends a maker to edit a bundled file.

A bundled pipeline lives inside the installed package (an edit there is lost on the next
install): its count is set in a copy. The reference is the bundled folder's own path.
"""

from __future__ import annotations

from dataclasses import replace

from conftest import cli_run
from cut_said import cut_sentence

from scratchfab.bundled import bundled_dir
from scratchfab.design.stage import run_design
from scratchfab.pipeline.config import load_pipeline

DEMO_PIPELINE = bundled_dir("pipelines") / "demo.toml"


def _cut_line(lines: list[str]) -> str:
    return cut_sentence(lines)


def test_design_demo_names_a_copy_of_the_bundled_pipeline(tmp_path, capsys):
    code, out, _ = cli_run(
        ["design", "demo", "--count", "40", "--resolution", "16", "--out", str(tmp_path / "j")],
        capsys,
    )
    assert code == 0, out
    line = _cut_line(out.splitlines())
    assert "--count or [scratch] count in a copy of " in line, line
    assert str(DEMO_PIPELINE.parent.name) in line  # the bundled file, as found


def test_run_demos_design_names_a_copy_and_no_count_option(tmp_path):
    pipe = load_pipeline(DEMO_PIPELINE)
    said: list[str] = []
    design = replace(pipe.design, source=str(pipe.path))
    design = replace(design, scratch=replace(design.scratch, count=40))
    run_design(design, tmp_path / "j", resolution=None, progress=said.append, machine=pipe.profile)
    line = _cut_line(said)
    assert "; [scratch] count in a copy of " in line and "--count" not in line, line


def test_a_users_own_file_is_named_as_it_is(tmp_path, capsys):
    mine = tmp_path / "mine.toml"
    text = DEMO_PIPELINE.read_text(encoding="utf-8")
    mine.write_text(
        text.replace("../demo/", f"{bundled_dir('demo').as_posix()}/"), encoding="utf-8"
    )
    code, out, _ = cli_run(
        ["design", str(mine), "--count", "40", "--resolution", "16", "--out", str(tmp_path / "j")],
        capsys,
    )
    assert code == 0, out
    line = _cut_line(out.splitlines())
    assert f"--count or [scratch] count in {mine} lays fewer" in line, line
