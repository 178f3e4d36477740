"""A toolpath planned from the design's initial layout, before optimize ever ran.

`toolpath JOB` once said only a note and planned a 10-hour cut of the unoptimized layout;
export and the G-code said nothing of it. It now warns, naming the optimize to run; the
plan goes ahead (the initial layout is a board too), and export's line and the G-code
header say it is not optimized, wherever the file goes. After optimize, none of it.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import cli_said, pasted_words

from scratchfab.export.gcode import HEADER_LINES, NOT_OPTIMIZED, gcode_lines, read_header
from scratchfab.model.job import JobLayout
from scratchfab.toolpath import Toolpath
from scratchfab.toolpath.inputs import initial_layout

BUNDLED = "grbl-3018-diamond"
MARK = "from the design's initial layout (not optimized)"


@pytest.fixture()
def job(tmp_path: Path, white: Path, capsys) -> Path:
    """A tiny quick-form design, not optimized (seeded)."""
    folder = tmp_path / "job"
    argv = ["design", str(white), "--board", "40x40", "--out", str(folder)]
    code, said = cli_said([*argv, "--count", "150", "--seed", "1"], capsys)
    assert code == 0, said
    return folder


def plan(capsys, *argv: str) -> tuple[int, str]:
    return cli_said(["toolpath", *argv, "--machine", BUNDLED, "--passes", "0"], capsys)


def header(gcode: Path) -> list[str]:
    """The G-code's lines up to its first move."""
    lines = gcode.read_text().splitlines()
    first_move = next(k for k, line in enumerate(lines) if line.startswith(("G0", "G1")))
    return lines[:first_move]


def test_before_optimize_toolpath_warns_export_and_the_header_say_so(job, tmp_path, capsys):
    initial = JobLayout(job).design.initial_scratches
    code, said = plan(capsys, str(job))
    assert code == 0, said  # planned: cutting the initial layout may be meant
    warning = [line for line in said.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1, said
    assert f"{initial} is the design's initial layout, not optimized" in warning[0]
    assert f"optimize has not run on {job}" in warning[0]
    command = warning[0].split("`")[1]
    assert pasted_words(command, tmp_path) == ["scratchfab", "optimize", str(job)]
    tp = Toolpath.load(JobLayout(job).toolpath_json)
    assert initial_layout(tp) == initial

    gcode = JobLayout(job).export_file("gcode")
    code, said = cli_said(["export", str(job), "-f", "gcode"], capsys)
    assert code == 0 and f"wrote {gcode} for machine" in said and MARK in said, said
    lines = header(gcode)
    assert f"({NOT_OPTIMIZED}: from the initial layout of the design)" in lines
    assert len(lines) <= HEADER_LINES and all(len(line) <= 79 for line in lines)
    assert read_header(lines).not_optimized
    code, said = cli_said(["export", str(job), "-f", "svg"], capsys)
    assert code == 0 and MARK in said, said

    # A job moved whole keeps its record (relative paths): the copy says it too.
    moved = tmp_path / "moved"
    shutil.copytree(job, moved)
    code, said = cli_said(["export", str(moved), "-o", str(tmp_path / "copy.gcode")], capsys)
    assert code == 0 and MARK in said, said
    assert read_header(header(tmp_path / "copy.gcode")).not_optimized

    # The command it names, run: then no warning, no mark.
    code, said = cli_said(command.split()[1:] + ["--iterations", "2"], capsys)
    assert code == 0, said
    code, said = plan(capsys, str(job))
    assert code == 0 and "warning" not in said and "initial layout" not in said, said
    code, said = cli_said(["export", str(job), "-f", "gcode"], capsys)
    assert code == 0 and "initial layout" not in said, said
    lines = header(gcode)
    assert not read_header(lines).not_optimized
    assert not any(NOT_OPTIMIZED in line for line in lines)


def test_the_initial_layout_given_as_files_after_optimize_names_the_optimized_one(
    job, tmp_path, capsys
):
    layout = JobLayout(job)
    code, said = cli_said(["optimize", str(job), "--iterations", "2"], capsys)
    assert code == 0, said
    out = tmp_path / "given"
    files = ["--scratches", str(layout.design.initial_scratches)]
    files += ["--design", str(layout.design.design_toml), "--out", str(out)]
    code, said = plan(capsys, *files)
    assert code == 0, said
    expected = f"({job}'s optimized layout is {layout.optimized_scratches})"
    assert expected in said and "scratchfab optimize" not in said, said
    exported = ["--toolpath", str(out / "toolpath.json"), "-o", str(tmp_path / "b.gcode")]
    code, said = cli_said(["export", *exported], capsys)
    assert code == 0 and MARK in said, said
    # The optimized layout given as files: no word of it.
    files[1] = str(layout.optimized_scratches)
    code, said = plan(capsys, *files)
    assert code == 0 and "initial layout" not in said, said
    assert initial_layout(Toolpath.load(out / "toolpath.json")) is None


def test_a_narrow_header_keeps_the_bare_mark(job, capsys):
    """A machine with short lines: the comment is not cut, the bare key still reads back."""
    code, said = plan(capsys, str(job))
    assert code == 0, said
    tp = Toolpath.load(JobLayout(job).toolpath_json)
    narrow = replace(tp.profile, gcode=replace(tp.profile.gcode, max_line_length=30))
    lines = gcode_lines(tp, narrow)
    assert f"({NOT_OPTIMIZED})" in lines[:HEADER_LINES]
    assert read_header(lines).not_optimized
    # Planned in memory (no file to read the record's paths against): no mark.
    assert initial_layout(replace(tp, file=None)) is None


def test_export_says_how_many_lines_stream_will_send(job, capsys):
    """A maker read 7510 lines from export and 7506 from stream: export now gives both,
    the file's lines and those sent (every line but comments and blank ones, counted
    here by hand; the sender's own count is the reference stream prints)."""
    from scratchfab.machine.sender_program import load_program

    assert plan(capsys, str(job))[0] == 0
    gcode = JobLayout(job).export_file("gcode")
    code, said = cli_said(["export", str(job), "-f", "gcode"], capsys)
    assert code == 0, said
    lines = gcode.read_text().splitlines()
    by_hand = [line for line in lines if line.strip() and not line.startswith("(")]
    assert len(by_hand) < len(lines)  # the header's comments
    assert len(by_hand) == len(load_program(gcode).blocks)
    assert f"{len(lines)} lines ({len(by_hand)} sent to the machine), " in said
