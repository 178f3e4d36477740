"""The report reads verify's gate as the run's result does (``gate_applies``).

-1 passes every rho, so it gates nothing: no view is marked as reaching it, in the
verdict, the metrics table or ``RunResult.verify``. The gate verify recorded is read by
the result's reader, so a damaged one leaves the page unjudged rather than unwritten.
"""

from __future__ import annotations

import json
import re

import pytest
from test_report import _verdict, fake_job

from scratchfab.pipeline.report import write_report
from scratchfab.pipeline.runner import VerifyMetrics

MARK = re.compile(r'data-metric="(\w+)\.rho"[^>]*>[^<]*(?:<span class=\'(\w+)\'>)?')


def _marks(page: str) -> dict[str, str | None]:
    """Each view's rho cell's mark in the metrics table ('ok', 'bad'; None unmarked)."""
    return {view: mark or None for view, mark in MARK.findall(page)}


def _record(job, gate) -> None:
    path = job / "verify" / "metrics.json"
    metrics = json.loads(path.read_text())
    metrics["gate"] = gate
    path.write_text(json.dumps(metrics))


def test_the_table_marks_rho_only_under_a_gate(tmp_path):
    job = fake_job(tmp_path, rho=(0.91234, -0.072))
    assert _marks(write_report(job, min_rho=0.5).read_text()) == {"left": "ok", "right": "bad"}
    page = write_report(job, min_rho=-1.0).read_text()
    assert _marks(page) == {"left": None, "right": None}
    assert "min_rho is <span data-stat='min_rho'>-1</span>, no gate" in page
    assert _marks(write_report(job).read_text()) == {"left": None, "right": None}


@pytest.mark.parametrize("passed", [True, None])
def test_a_recorded_minus_one_reads_as_no_gate_in_page_and_result(tmp_path, passed):
    job = fake_job(tmp_path, rho=(0.91234, -0.072))
    _record(job, {"min_rho": -1, "passed": passed, "failing": [], "unchecked": []})
    page = write_report(job).read_text()
    lines = [text for _, text in _verdict(page)[2] if "looks like its target" in text]
    assert all(text.endswith("(1 = perfect; min_rho -1: no gate)") for text in lines), lines
    assert len(lines) == 2
    result = VerifyMetrics.read(job / "verify" / "metrics.json")
    assert result is not None and result.passed is None
    assert [v.passed for v in result.views] == [None, None]


@pytest.mark.parametrize(
    "gate",
    [{"min_rho": "0.8"}, {"min_rho": 0.8, "failing": 5}, {"min_rho": True}, [0.8]],
)
def test_a_damaged_recorded_gate_leaves_the_views_unjudged(tmp_path, gate):
    job = fake_job(tmp_path, rho=(0.91234, 0.5))
    _record(job, gate)
    lines = [text for _, text in _verdict(write_report(job).read_text())[2]]
    said = [text for text in lines if "looks like its target" in text]
    assert len(said) == 2 and all(t.endswith("(1 = perfect; no min_rho set)") for t in said)
    _record(job, {"min_rho": 0.8})  # the same figures under a sound gate: judged
    assert _verdict(write_report(job).read_text())[0] == "not-ready"
