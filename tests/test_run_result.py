"""``RunResult``'s verify metrics and toolpath figures, read from what the stages wrote.

The references are independent of ``metrics.json``'s and ``toolpath.json``'s readers:
rho and PSNR measured again on the verify renders and the targets, the toolpath's
figures measured on its strokes.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import write_pipeline

from scratchfab.metrics import quality_report
from scratchfab.model.job import JobLayout
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import ToolpathFigures, VerifyMetrics, run_pipeline
from scratchfab.toolpath import Toolpath, estimate_time
from scratchfab.toolpath.order import tour_travel


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny pipeline with a gate every view passes, run to the toolpath stage."""
    folder = tmp_path_factory.mktemp("result")
    path = write_pipeline(folder, min_rho=-0.5)
    job = folder / "job"
    return path, job, run_pipeline(load_pipeline(path), job, until="toolpath")


def test_the_verify_metrics_are_the_renders_against_their_targets(run):
    _, job, result = run
    layout = JobLayout(job)
    metrics = result.verify
    assert metrics is not None and metrics.file == layout.verify_metrics
    names = [view.name for view in load_pipeline(run[0]).design.views]
    assert [view.name for view in metrics.views] == names
    renders = {n: np.load(layout.verify_dir / f"{n}.npy") for n in names}
    targets = {n: np.load(layout.design.target_npy(n)) for n in names}
    measured = quality_report(renders, targets)["views"]
    for view in metrics.views:
        assert view.rho == pytest.approx(measured[view.name]["rho"], abs=1e-6)
        assert view.psnr == pytest.approx(measured[view.name]["psnr"], abs=1e-4)
        assert view.passed is (view.rho >= -0.5)
        assert metrics.view(view.name) is view
    assert metrics.min_rho == -0.5 and metrics.passed is True
    with pytest.raises(KeyError, match="no view 'nope'"):
        metrics.view("nope")


def test_the_toolpath_figures_are_its_strokes(run):
    _, job, result = run
    figures = result.toolpath
    assert figures is not None
    planned = Toolpath.load(JobLayout(job).toolpath_json)
    strokes = planned.strokes
    assert figures.strokes == len(strokes) > 0
    assert figures.strokes_id == planned.strokes_id
    assert figures.cut_mm == pytest.approx(np.hypot(*(strokes[:, 1] - strokes[:, 0]).T).sum())
    start = np.asarray(planned.profile.start_mm)
    assert figures.travel_mm == pytest.approx(tour_travel(strokes[:, 0], strokes[:, 1], start))
    assert figures.estimated_s == pytest.approx(estimate_time(strokes, planned.profile))
    rows = len((JobLayout(job).optimized_scratches).read_text().splitlines()) - 1
    assert figures.scratches == rows
    assert figures.left_out == figures.clipped == 0  # the tiny board lies inside the travel


def test_a_skipped_stage_still_gives_its_figures_and_one_not_run_none(run):
    path, job, first = run
    again = run_pipeline(load_pipeline(path), job, until="toolpath")
    assert again.ran == [] and again.skipped == ["design", "optimize", "verify", "toolpath"]
    assert again.verify == first.verify and again.toolpath == first.toolpath
    short = run_pipeline(load_pipeline(path), job, until="optimize")
    assert short.verify is None and short.toolpath is None


def write_metrics(tmp_path, views, gate=None, names=None):
    data = {"views": views, **({"gate": gate} if gate else {})}
    if names is not None:
        data["names"] = names
    file = tmp_path / "metrics.json"
    file.write_text(json.dumps(data))
    return file


def test_a_failing_an_unchecked_and_an_ungated_view(tmp_path):
    views = {"a": {"rho": 0.9, "psnr": 20.0}, "b": {"rho": 0.4, "psnr": 9.5}, "c": {}}
    gate = {"min_rho": 0.8, "passed": False, "failing": ["b"], "unchecked": ["c"]}
    got = VerifyMetrics.read(write_metrics(tmp_path, views, gate, ["c", "a", "b"]))
    assert got is not None
    assert [(v.name, v.rho, v.psnr, v.passed) for v in got.views] == [
        ("c", None, None, None),
        ("a", 0.9, 20.0, True),
        ("b", 0.4, 9.5, False),
    ]
    assert got.passed is False and got.min_rho == 0.8
    ungated = VerifyMetrics.read(write_metrics(tmp_path, views))
    assert ungated is not None and ungated.passed is None and ungated.min_rho is None
    assert [v.passed for v in ungated.views] == [None, None, None]
    assert [v.name for v in ungated.views] == ["a", "b", "c"]  # no names: the file's order


def test_a_perfect_view_s_psnr_is_infinite(tmp_path):
    file = tmp_path / "metrics.json"
    file.write_text('{"views": {"a": {"rho": 1.0, "psnr": Infinity}}}')
    got = VerifyMetrics.read(file)
    assert got is not None and got.views[0].psnr == math.inf


@pytest.mark.parametrize("text", [None, "{not json", "[]", '{"views": 3}'])
def test_an_unreadable_file_gives_none(tmp_path, text):
    file = tmp_path / "metrics.json"
    if text is not None:
        file.write_text(text)
    assert VerifyMetrics.read(file) is None
    assert ToolpathFigures.read(file) is None


def _job_copy_at_min_rho(run, tmp_path, min_rho: str):
    """A copy of the run's job and a pipeline file beside its targets with another min_rho."""
    import shutil

    path, job, _ = run
    copy = tmp_path / "job"
    shutil.copytree(job, copy)
    changed = path.with_name(f"min_rho_{min_rho}.toml")
    changed.write_text(path.read_text().replace("min_rho = -0.5", f"min_rho = {min_rho}"))
    assert changed.read_text() != path.read_text()
    return changed, copy


def test_a_failing_gate_s_error_carries_the_metrics_a_result_would_hold(run, tmp_path):
    """The gate ends the run with VerifyGateError, so no RunResult: the error holds them."""
    from scratchfab.verify.verify import VerifyGateError

    strict, copy = _job_copy_at_min_rho(run, tmp_path, "0.9999")
    with pytest.raises(VerifyGateError) as info:
        run_pipeline(load_pipeline(strict), copy, until="toolpath")
    metrics = info.value.metrics
    assert isinstance(metrics, VerifyMetrics) and metrics.file == JobLayout(copy).verify_metrics
    layout = JobLayout(copy)
    names = [view.name for view in metrics.views]
    renders = {n: np.load(layout.verify_dir / f"{n}.npy") for n in names}
    targets = {n: np.load(layout.design.target_npy(n)) for n in names}
    measured = quality_report(renders, targets)["views"]
    for view in metrics.views:  # the reference: measured again, not metrics.json's figure
        assert view.rho == pytest.approx(measured[view.name]["rho"], abs=1e-6)
        assert view.passed is (measured[view.name]["rho"] >= 0.9999)
    assert metrics.min_rho == 0.9999 and metrics.passed is False
    assert info.value.view in [v.name for v in metrics.views if v.passed is False]


def test_min_rho_minus_one_is_no_gate_however_verify_recorded_it(tmp_path):
    """-1 passes every rho, so it gates nothing: passed None, as the report says "no gate"."""
    views = {"a": {"rho": 0.9, "psnr": 20.0}, "b": {"rho": -0.2, "psnr": 3.0}}
    for passed in (True, None):  # as verify wrote it before, and now
        gate = {"min_rho": -1, "passed": passed, "failing": [], "unchecked": []}
        got = VerifyMetrics.read(write_metrics(tmp_path, views, gate))
        assert got is not None and got.min_rho == -1.0
        assert got.passed is None and [v.passed for v in got.views] == [None, None]
    gate = {"min_rho": -0.99, "passed": True, "failing": [], "unchecked": []}
    got = VerifyMetrics.read(write_metrics(tmp_path, views, gate))
    assert got is not None and got.passed is True and [v.passed for v in got.views] == [True] * 2


@pytest.mark.parametrize(
    ("gate", "key", "shown"),
    [
        ({"min_rho": 0.5, "failing": 5}, "gate.failing", "5"),
        ({"min_rho": 0.5, "unchecked": [[1]]}, "gate.unchecked", "[[1]]"),
        ({"min_rho": 0.5, "failing": ["a", 2]}, "gate.failing", "['a', 2]"),
        ({"min_rho": 0.5, "failing": "a"}, "gate.failing", "'a'"),
        (7, "gate", "7"),
    ],
)
def test_a_damaged_gate_is_a_one_line_error_naming_file_and_key(tmp_path, gate, key, shown):
    from scratchfab.errors import ConfigError

    file = tmp_path / "metrics.json"
    file.write_text(json.dumps({"views": {"a": {"rho": 0.9}}, "gate": gate}))
    with pytest.raises(ConfigError) as info:
        VerifyMetrics.read(file)
    said = str(info.value)
    assert said.startswith(f"{file}: {key}: expected ") and said.endswith(f"got {shown}")
    assert "\n" not in said


def test_a_run_at_min_rho_minus_one_gives_no_verdict(run, tmp_path):
    """The pipeline's "-1 never stops": verify records no pass, and the result says none."""
    loose, copy = _job_copy_at_min_rho(run, tmp_path, "-1.0")
    result = run_pipeline(load_pipeline(loose), copy, until="verify")
    assert result.ran == ["verify"]
    recorded = json.loads(JobLayout(copy).verify_metrics.read_text())["gate"]
    assert recorded["min_rho"] == -1 and recorded["passed"] is None
    assert result.verify is not None and result.verify.min_rho == -1.0
    assert result.verify.passed is None
    assert [v.passed for v in result.verify.views] == [None] * len(result.verify.views)
    assert all(v.rho is not None for v in result.verify.views)
