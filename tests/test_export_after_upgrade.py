"""A toolpath planned by an earlier scratchfab stays current over the first rerun of design.

That version recorded design.toml in toolpath.json by its bytes alone (no
``fields_sha256``) and wrote each view's fov_deg as auto's number; design now writes
``"auto"`` and its own heading, so the bytes differ though the design is the same. Export
compares what the plan holds of the design (the board's size, the tool) where the record
has nothing else: the same goes through, another board is refused.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import cli_said
from test_design_digest import QUICK, _as_the_version_before

from scratchfab.fileio import file_sha256
from scratchfab.model.job import JobLayout

BUNDLED = "grbl-3018-diamond"


def _design(job: Path, capsys: pytest.CaptureFixture[str], *more: str) -> None:
    code, said = cli_said(["design", *QUICK, *more, "--out", str(job)], capsys)
    assert code == 0, said


def _export(job: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    return cli_said(["export", str(job), "--format", "gcode"], capsys)


@pytest.fixture
def job(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    """A quick-form job as the earlier scratchfab left it: optimized, planned, recorded."""
    folder = tmp_path / "job"
    _design(folder, capsys)
    _as_the_version_before(folder)
    code, said = cli_said(["toolpath", str(folder), "--machine", BUNDLED, "--passes", "0"], capsys)
    assert code == 0, said
    file = JobLayout(folder).toolpath_json
    data = json.loads(file.read_text())
    design = data["inputs"]["design"]
    assert design["sha256"] == file_sha256(JobLayout(folder).design.design_toml)
    del design["fields_sha256"]  # the earlier record: the bytes' digest alone
    file.write_text(json.dumps(data, indent=1))
    return folder


def test_the_first_rerun_of_design_leaves_an_earlier_plan_current(job, capsys):
    toml = JobLayout(job).design.design_toml
    before = file_sha256(toml)
    _design(job, capsys)
    assert file_sha256(toml) != before and '"auto"' in toml.read_text()
    code, said = _export(job, capsys)
    assert code == 0 and "warning" not in said and "note" not in said, said


@pytest.mark.parametrize("edit", ["board", "tool"])
def test_another_board_or_tool_still_refuses_an_earlier_plan(job, capsys, edit):
    toml = JobLayout(job).design.design_toml
    if edit == "board":
        _design(job, capsys, "--board", "30x28")
    else:  # by hand: the machine cuts 0.1 mm
        text = toml.read_text()
        assert text.count("\nwidth_mm = 0.1\n") == 1
        toml.write_text(text.replace("\nwidth_mm = 0.1\n", "\nwidth_mm = 0.2\n"))
    code, said = _export(job, capsys)
    assert code == 2 and f"{toml} changed since" in said, said
    assert not JobLayout(job).export_file("gcode").exists()
