"""`export` refuses a toolpath planned from other inputs than the job holds now.

Through the CLI: a toolpath, then optimize's layout rewritten, the design or the machine
profile edited, or a toolpath refused after a good one; the refusal must name what
changed and a toolpath command that, run as written, makes the export go through.
"""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from conftest import cli_said, make_design
from test_toolpath import make_job

from scratchfab.errors import ScratchfabError
from scratchfab.export import export
from scratchfab.machine.profile import load_profile
from scratchfab.model.scratches import load_scratches
from scratchfab.toolpath import Toolpath

BUNDLED = "grbl-3018-diamond"


def files_of(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` by relative path, with its bytes."""
    if not folder.exists():
        return {}
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*")}


def toolpath(job: Path, machine: str | Path, capsys, *more: str) -> tuple[int, str]:
    return cli_said(
        ["toolpath", str(job), "--machine", str(machine), "--passes", "0", *more], capsys
    )


def export_gcode(job: Path, capsys, *more: str) -> tuple[int, str]:
    return cli_said(["export", str(job), "--format", "gcode", *more], capsys)


def refused(job: Path, capsys, *named: str) -> str:
    """Export is refused (exit 2, one line, the export folder as it was); what it said."""
    before = files_of(job / "export")
    code, said = export_gcode(job, capsys)
    assert code == 2, said
    assert len(said.strip().splitlines()) == 1, said
    assert "nothing written" in said and "--force" in said
    for name in named:
        assert name in said, (name, said)
    assert files_of(job / "export") == before
    return said


def rerun_said(said: str, capsys) -> None:
    """Run the toolpath command a refusal names, as a person pastes it."""
    command = said.split("rerun `")[1].split("`")[0]
    words = shlex.split(command)
    assert words[:2] == ["scratchfab", "toolpath"], command
    code, out = cli_said([*words[1:], "--passes", "0"], capsys)
    assert code == 0, out


def rewrite_layout(job: Path, keep: int) -> None:
    """Write a new optimized layout: the first ``keep`` scratches of the initial one."""
    design = make_design()
    initial = load_scratches(job / "design" / "scratches.csv", design.scratch, design.board)
    initial.subset(np.arange(keep)).save(job / "optimize" / "scratches.csv", design.scratch)


def write_profile(path: Path, **tables: dict) -> Path:
    """The bundled 3018 profile with ``tables``' keys changed, written to ``path``."""
    table = load_profile(BUNDLED).to_table()
    for name, values in tables.items():
        table[name].update(values)
    path.write_text(tomli_w.dumps(table))
    return path


def test_optimize_again_refuses_then_the_named_toolpath_makes_it_current(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=True)
    assert toolpath(job, BUNDLED, capsys)[0] == 0
    code, said = export_gcode(job, capsys)
    assert code == 0 and "note:" not in said and "warning" not in said, said
    rewrite_layout(job, 50)  # optimize ran again
    said = refused(job, capsys, str(job / "optimize" / "scratches.csv"), "changed since")
    assert f"--machine {BUNDLED}" in said
    rerun_said(said, capsys)
    assert Toolpath.load(job / "toolpath" / "toolpath.json").stats["input_count"] == 50
    code, said = export_gcode(job, capsys)
    assert code == 0 and "warning" not in said, said


def test_a_layout_picked_otherwise_is_refused_and_the_same_bytes_again_are_current(
    rng, tmp_path, capsys
):
    job = make_job(tmp_path, rng, optimize=False)
    assert toolpath(job, BUNDLED, capsys)[0] == 0
    rewrite_layout(job, 60)  # optimize has run since: the job's layout is now its own
    said = refused(job, capsys, "layout is now", str(job / "design" / "scratches.csv"))
    shutil.rmtree(job / "optimize")  # back to the initial layout, bytes as planned
    assert export_gcode(job, capsys)[0] == 0
    # An edit by hand to the CSV the toolpath was planned from, a single byte.
    csv = job / "design" / "scratches.csv"
    csv.write_bytes(csv.read_bytes().replace(b"0.1", b"0.10", 1))
    said = refused(job, capsys, f"{csv} changed since")
    rerun_said(said, capsys)
    assert export_gcode(job, capsys)[0] == 0
    csv.unlink()  # no layout left at all: said once
    said = refused(job, capsys)
    assert said.count("no scratch layout") == 1, said


def test_a_refused_toolpath_after_a_good_one_leaves_export_refused(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=True)
    profile = write_profile(tmp_path / "my.toml")
    assert toolpath(job, profile, capsys)[0] == 0
    assert export_gcode(job, capsys)[0] == 0
    # The board moved on the bed (half of it off the machine): toolpath refuses ...
    write_profile(profile, board={"offset_mm": [-20.0, -150.0]})
    plan = files_of(job / "toolpath")
    code, said = toolpath(job, profile, capsys)
    assert code == 2 and "nothing written" in said and files_of(job / "toolpath") == plan
    # ... and the earlier plan, for the board where it was, is not exported.
    said = refused(job, capsys, str(profile), "board.offset_mm = [-20.0, -150.0]")
    assert "(planned: [-220.0, -150.0])" in said
    # The design edited: a board that no longer fits the travel, refused the same way.
    write_profile(profile)
    assert export_gcode(job, capsys)[0] == 0  # the profile as planned again
    make_design(size_mm=300.0).save(job / "design" / "design.toml")
    code, said = toolpath(job, profile, capsys)
    assert code == 2, said
    refused(job, capsys, str(job / "design" / "design.toml"))
    # --force exports the earlier plan, with the warning.
    code, said = export_gcode(job, capsys, "--force")
    assert code == 0 and "warning: exported as planned" in said and "design.toml" in said


def test_feeds_edited_in_the_profile_refuse_unless_exported_for_it(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=True)
    profile = write_profile(tmp_path / "my.toml")
    assert toolpath(job, profile, capsys)[0] == 0
    write_profile(profile, feeds={"engrave_mm_min": 123.0})
    refused(job, capsys, "feeds.engrave_mm_min = 123.0 (planned: 600.0)")
    # Written for the profile as it is now: its feeds, the planned strokes.
    code, said = export_gcode(job, capsys, "--machine", str(profile))
    assert code == 0, said
    assert "F123" in (job / "export" / "board.gcode").read_text()
    # A comment added changes the file's bytes but not the profile: still current.
    write_profile(profile)
    with profile.open("a") as handle:
        handle.write("# a comment\n")
    assert export_gcode(job, capsys)[0] == 0


def test_an_old_toolpath_without_a_record_exports_with_a_note(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=True)
    assert toolpath(job, BUNDLED, capsys)[0] == 0
    file = job / "toolpath" / "toolpath.json"
    data = json.loads(file.read_text())
    del data["inputs"]
    file.write_text(json.dumps(data))
    rewrite_layout(job, 50)  # cannot be told: no record
    code, said = export_gcode(job, capsys)
    assert code == 0, said
    assert "note:" in said and "records no inputs" in said
    assert f"scratchfab toolpath {job} --machine {BUNDLED}" in said
    assert (job / "export" / "board.gcode").is_file()


def test_a_job_moved_whole_keeps_its_record(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=True)
    assert toolpath(job, BUNDLED, capsys)[0] == 0
    moved = tmp_path / "elsewhere" / "renamed"
    shutil.copytree(job, moved)
    shutil.rmtree(job)
    code, said = export_gcode(moved, capsys)
    assert code == 0 and "note" not in said, said
    rewrite_layout(moved, 30)
    refused(moved, capsys, str(moved / "optimize" / "scratches.csv"))


def test_given_files_are_checked_where_they_lie(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=True)
    mine = tmp_path / "mine.csv"
    shutil.copy(job / "design" / "scratches.csv", mine)
    out = tmp_path / "plan"
    given = ["--scratches", str(mine), "--design", str(job / "design" / "design.toml")]
    code, said = cli_said(
        ["toolpath", "--machine", BUNDLED, *given, "--out", str(out), "--passes", "0"], capsys
    )
    assert code == 0, said
    args = ["export", "--toolpath", str(out / "toolpath.json"), "-o", str(tmp_path / "b.gcode")]
    # The job's own optimized layout is not the one asked for: not compared.
    assert cli_said(args, capsys)[0] == 0
    mine.write_text(mine.read_text() + "\n")
    code, said = cli_said(args, capsys)
    assert code == 2 and f"{mine} changed since" in said, said
    assert f"--scratches {mine}" in said and f"--out {out}" in said
    rerun_said(said, capsys)
    assert cli_said(args, capsys)[0] == 0


def test_the_library_checks_when_told_and_forced_reports_what_changed(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=True)
    assert toolpath(job, BUNDLED, capsys)[0] == 0
    rewrite_layout(job, 50)
    tp = Toolpath.load(job / "toolpath" / "toolpath.json")
    with pytest.raises(ScratchfabError, match="changed since.*give --yes to export"):
        export(tp, None, tmp_path / "b.gcode", refuse_stale="--yes")
    assert not (tmp_path / "b.gcode").exists()
    stats = export(tp, None, tmp_path / "a.gcode", refuse_stale="--yes", force=True)
    assert stats["stale"] is not None and "changed since" in stats["stale"]
    # Not told (the runner, whose manifest replans a stale toolpath): not checked.
    assert export(tp, None, tmp_path / "c.gcode")["stale"] is None
    assert (tmp_path / "a.gcode").read_bytes() == (tmp_path / "c.gcode").read_bytes()


@pytest.mark.parametrize(
    "inputs",
    [
        [],
        {"scratches": {"file": 1}},
        {"scratches": {}, "design": {}},
        {
            "scratches": {"file": "a.csv", "sha256": "0"},
            "design": {"file": "d.toml", "sha256": "0", "fields_sha256": 1},
        },
    ],
)
def test_a_malformed_record_is_one_line(rng, tmp_path, capsys, inputs):
    job = make_job(tmp_path, rng, optimize=True)
    assert toolpath(job, BUNDLED, capsys)[0] == 0
    file = job / "toolpath" / "toolpath.json"
    data = json.loads(file.read_text())
    data["inputs"] = inputs
    file.write_text(json.dumps(data))
    code, said = export_gcode(job, capsys)
    assert code == 2 and "malformed toolpath (inputs" in said and str(file) in said, said
    assert len(said.strip().splitlines()) == 1


def test_a_design_written_again_with_the_same_design_is_current(rng, tmp_path, capsys):
    """A rerun of design rewrites design.toml's heading comment and target paths (and may
    change the count it laid, which the CSV supersedes): export goes on, as optimize's stale
    note and --resume do; an edit to the board is still refused."""
    job = make_job(tmp_path, rng, optimize=True)
    assert toolpath(job, BUNDLED, capsys)[0] == 0
    toml = job / "design" / "design.toml"
    text = toml.read_text()
    assert "count = 200" in text
    again = "# Resolved by `scratchfab design` from another file\n" + text
    toml.write_text(again.replace("count = 200", "count = 150"))
    code, said = export_gcode(job, capsys)
    assert code == 0 and "warning" not in said and "note" not in said, said
    toml.write_text(again.replace("margin_mm = 1.0", "margin_mm = 2.0"))
    refused(job, capsys, f"{toml} changed since")


def test_a_toolpath_taken_away_from_its_job_exports_with_a_note(rng, tmp_path, capsys):
    """toolpath.json copied alone (to the machine's computer, say) has no job around it to
    check: it exports with a note, as a toolpath of given files moved away does, instead of
    a refusal whose toolpath command has no job to plan."""
    job = make_job(tmp_path, rng, optimize=True)
    assert toolpath(job, BUNDLED, capsys)[0] == 0
    alone = tmp_path / "elsewhere" / "deeper"
    alone.mkdir(parents=True)
    shutil.copy(job / "toolpath" / "toolpath.json", alone)
    out = tmp_path / "b.gcode"
    args = ["export", "--toolpath", str(alone / "toolpath.json"), "-o", str(out)]
    code, said = cli_said(args, capsys)
    assert code == 0, said
    assert (
        f"note: {alone / 'toolpath.json'}: the job folder it names, {tmp_path / 'elsewhere'},"
        in said
    )
    assert "not checked" in said and "warning" not in said
    assert export_gcode(job, capsys)[0] == 0
    assert out.read_bytes() == (job / "export" / "board.gcode").read_bytes()
