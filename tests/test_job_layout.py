"""JobLayout against SPEC section 6, and against the files the stages really write."""

from __future__ import annotations

import inspect
import json
import os
import re
import shlex
from pathlib import Path

import pytest
from conftest import pasted_words, write_pipeline

from scratchfab.cli import main
from scratchfab.machine.sender_journal import default_journal_path
from scratchfab.model.job import DesignFolder, JobLayout, job_inputs, stale_layout_warning
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline

#: SPEC section 6's table, transcribed, with the files the stages add beside it. Every
#: path JobLayout and DesignFolder name has a row here (checked below), so a new one
#: cannot appear without a row.
SPEC_SECTION_6 = {
    "design.path": "design",
    "design.design_toml": "design/design.toml",
    "design.targets_dir": "design/targets",
    "design.target_png(sun)": "design/targets/sun.png",
    "design.target_npy(sun)": "design/targets/sun.npy",
    "design.initial_scratches": "design/scratches.csv",
    "design.boards_dir": "design/board",
    "design.board_png(sun)": "design/board/sun.png",
    "design.feasibility_png(sun)": "design/feasibility_sun.png",
    "design.feasibility_json": "design/feasibility.json",
    "optimize_dir": "optimize",
    "optimized_scratches": "optimize/scratches.csv",
    "unpruned_scratches": "optimize/scratches_unpruned.csv",
    "optimize_renders": "optimize/renders",
    "optimize_log": "optimize/log.csv",
    "optimize_summary": "optimize/summary.json",
    "optimize_checkpoint": "optimize/checkpoint.npz",
    "loss_png": "optimize/loss.png",
    "side_by_side_png": "optimize/side_by_side.png",
    "verify_dir": "verify",
    "verify_metrics": "verify/metrics.json",
    "verify_diff_png(sun)": "verify/diff/sun.png",
    "render_dir": "render",
    "toolpath_dir": "toolpath",
    "toolpath_json": "toolpath/toolpath.json",
    "toolpath_preview": "toolpath/preview.png",
    "export_dir": "export",
    "export_file(gcode)": "export/board.gcode",
    "export_file(dxf)": "export/board.dxf",
    "export_file(svg)": "export/board.svg",
    "stream_dir": "stream",
    "journal": "stream/journal.jsonl",
    "report_html": "report.html",
    "run_lock": ".run.lock",
}


def _lookup(layout: JobLayout, key: str) -> Path:
    """The path ``key`` (a row name of :data:`SPEC_SECTION_6`) names in ``layout``."""
    owner: object = layout
    if key.startswith("design."):
        owner, key = layout.design, key.removeprefix("design.")
    name, _, arg = key.partition("(")
    value = getattr(owner, name)
    return value(arg.rstrip(")")) if arg else value


def _path_names(cls: type) -> set[str]:
    """The public paths a layout class names: its properties and one-argument methods."""
    names = set()
    for name, member in vars(cls).items():
        if name.startswith("_") or isinstance(member, classmethod):
            continue
        if isinstance(member, property) or (
            inspect.isfunction(member) and len(inspect.signature(member).parameters) == 2
        ):
            names.add(name)
    return names - {"relative"}


@pytest.mark.parametrize("root", [Path("job"), Path("/abs/some job")])
def test_every_layout_path_is_the_spec_table_row(root):
    layout = JobLayout(root)
    for key, rel in SPEC_SECTION_6.items():
        path = _lookup(layout, key)
        # As the caller named the job: messages show relative jobs as relative.
        assert path == root / rel, key
        assert str(path) == str(root) + "/" + rel, key
        assert layout.relative(path) == rel, key
    rows = {k.partition("(")[0] for k in SPEC_SECTION_6}
    assert {n for n in rows if not n.startswith("design.")} == _path_names(JobLayout) - {
        "design",
        "export_files",
    }
    assert {n.removeprefix("design.") for n in rows if n.startswith("design.")} == (
        _path_names(DesignFolder) | {"path"}
    ) - {"digested"}
    assert layout.design.digested == (
        root / "design/design.toml",
        root / "design/scratches.csv",
    )


def test_export_file_owner_and_journal(tmp_path):
    job = tmp_path / "J"
    gcode = job / "export" / "board.gcode"
    found = JobLayout.for_export_file(gcode)
    assert found is not None and found.root == job
    assert JobLayout.for_export_file(Path("export/board.gcode")) == JobLayout(Path("."))
    for elsewhere in (tmp_path / "board.gcode", job / "exports" / "b.nc", Path("board.gcode")):
        assert JobLayout.for_export_file(elsewhere) is None, elsewhere
    assert default_journal_path(gcode) == (tmp_path / "J/stream/journal.jsonl").resolve()
    assert default_journal_path(tmp_path / "x.nc") == (tmp_path / "x.nc.journal.jsonl").resolve()


#: The tiny pipeline, smaller still, pruned, writing every format.
EDITS = {
    "count = 250": "count = 150",
    "resolution = [24, 24]": "resolution = [16, 16]",
    "iterations = 4": "iterations = 2\nprune_tolerance = 0.5",
    "spp = 256": "spp = 16",
}


@pytest.fixture(scope="module")
def demo_like_job(tmp_path_factory) -> Path:
    """A small two-view job made by every stage of ``scratchfab run`` (demo-like)."""
    folder = tmp_path_factory.mktemp("layout")
    path = write_pipeline(folder, formats='["gcode", "dxf", "svg"]', edits=EDITS)
    job = folder / "job"
    result = run_pipeline(load_pipeline(path), job, say=lambda _: None)
    assert result.ran == ["design", "optimize", "verify", "toolpath", "export", "stream"]
    main(["render", str(job)])
    return job


def test_stages_write_where_the_layout_says(demo_like_job):
    job = demo_like_job
    layout = JobLayout(job)
    views = ("disc", "bar")
    named_files = [
        layout.design.design_toml,
        layout.design.initial_scratches,
        layout.design.feasibility_json,
        *(layout.design.target_npy(v) for v in views),
        *(layout.design.target_png(v) for v in views),
        *(layout.design.board_png(v) for v in views),
        *(layout.design.feasibility_png(v) for v in views),
        layout.optimized_scratches,
        layout.unpruned_scratches,
        layout.optimize_log,
        layout.optimize_summary,
        layout.optimize_checkpoint,
        layout.loss_png,
        layout.side_by_side_png,
        layout.verify_metrics,
        *(layout.verify_diff_png(v) for v in views),
        layout.toolpath_json,
        layout.toolpath_preview,
        *(layout.export_file(fmt) for fmt in ("gcode", "dxf", "svg")),
        layout.journal,
        layout.report_html,
        layout.run_lock,
    ]
    # The `render` layout (SPEC section 4): <view>.npy and <view>.png in each such folder.
    render_layouts = [layout.optimize_renders, layout.verify_dir, layout.render_dir]
    rendered = [d / f"{v}.{ext}" for d in render_layouts for v in views for ext in ("npy", "png")]
    for path in named_files + rendered:
        assert path.is_file(), layout.relative(path)
    assert layout.export_files() == sorted(layout.export_file(f) for f in ("dxf", "gcode", "svg"))
    # Nothing the stages wrote lies outside what the layout names (the manifest is the
    # runner's own record).
    written = {p for p in job.rglob("*") if p.is_file()}
    unnamed = written - set(named_files) - set(rendered) - {job / "manifest.json"}
    assert not unnamed, sorted(layout.relative(p) for p in unnamed)
    # Each stage reads its inputs where the layout says the stage before wrote them.
    assert job_inputs(job) == (layout.design.design_toml, layout.optimized_scratches)
    assert default_journal_path(layout.export_file("gcode")) == layout.journal.resolve()


@pytest.mark.skipif(os.name == "nt", reason="the POSIX shell's quoting")
def test_stale_layout_warning_command_pastes_as_the_job_folder(tmp_path):
    job = tmp_path / "job $(touch PWNED) 'it's' `touch PWNED2`"
    layout = JobLayout(job)
    for path in (*layout.design.digested, layout.optimized_scratches):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("x\n")
    digests = {p.name: "made from another design" for p in layout.design.digested}
    layout.optimize_summary.write_text(json.dumps({"design_sha256": digests}))
    warning = stale_layout_warning(job)
    assert warning is not None
    found = re.search(r"rerun `(.*)` for the current design$", warning)
    assert found
    words = shlex.split(found.group(1))  # an independent reader of the quoting
    assert words == ["scratchfab", "optimize", str(job)]
    assert pasted_words(found.group(1), tmp_path) == words  # and the shell agrees
    assert not list(tmp_path.rglob("PWNED*"))  # nothing ran
