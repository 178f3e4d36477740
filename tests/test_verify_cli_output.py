"""`verify-render` run on its own lays out its lines as `render` does: a heading at the
margin, a view's lines under it, indented; inside `run` the whole sits under its stage."""

from __future__ import annotations

import re

from conftest import cli_said, write_pipeline

from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline


def _layout(said: str) -> list[tuple[int, str]]:
    """Each line's indent and its first word (what kind of line it is)."""
    return [
        (len(line) - len(line.lstrip(" ")), line.split()[0])
        for line in said.splitlines()
        if line.strip()
    ]


def test_verify_render_alone_indents_as_render_does(tmp_path, capsys):
    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    run_pipeline(load_pipeline(path), job, until="design")
    code, rendered = cli_said(["render", str(job)], capsys)
    assert code == 0, rendered
    code, verified = cli_said(["verify-render", str(job), "--spp", "16"], capsys)
    assert code == 0, verified
    # The reference: render's heading and closing line at the margin, its views under it.
    shown = _layout(rendered)
    assert shown[0] == (0, "rendering") and shown[-1] == (0, "wrote"), rendered
    assert {indent for indent, word in shown if word == "view"} == {2}, rendered
    lines = _layout(verified)
    assert lines[0] == (0, "verifying") and lines[-1] == (0, "wrote"), verified
    views = [indent for indent, word in lines if word == "verify"]
    assert len(views) >= 4 and set(views) == {2}, verified  # 2 views: a render, a metric each


def test_in_a_run_the_verify_lines_sit_under_the_stage(tmp_path):
    path = write_pipeline(tmp_path, edits={"spp = 256": "spp = 16"})
    said: list[str] = []
    run_pipeline(load_pipeline(path), tmp_path / "job", until="verify", say=said.append)
    first = said.index("[verify] running")
    last = next(i for i, line in enumerate(said) if line.startswith("[verify] done"))
    lines = said[first + 1 : last]
    assert re.match(r"  verifying \S+ \(\d+ scratches\) against ", lines[0]), lines
    details = [line for line in lines if line.lstrip().startswith("verify ")]
    assert details and all(line.startswith("    verify ") for line in details), lines


def test_a_sample_count_rounded_up_to_the_grid_says_what_was_asked(tmp_path, capsys):
    """``--spp 20`` takes two batches of 12 (a 3 x 4 grid each): the line says 24 spp and
    that 20 were asked; ``--spp 16`` (two 2 x 4 grids) says nothing more."""
    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    run_pipeline(load_pipeline(path), job, until="design")
    for asked, taken in ((20, 24), (16, 16)):
        code, said = cli_said(["verify-render", str(job), "--spp", str(asked)], capsys)
        assert code == 0, said
        lines = [line for line in said.splitlines() if " px, " in line]
        assert lines, said
        for line in lines:
            assert f" px, {taken} spp" in line, line
            assert (f"({asked} asked" in line) == (asked != taken), line
