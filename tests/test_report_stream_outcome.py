"""report.html after a stream that failed or stopped: the manifest's word comes first.

A failed stream (the controller reset during check mode: no line of the file was sent)
left the journal of an earlier, finished session in place; the report read that one as
the run's own and said "Ready to cut" and "The board is cut".
"""

from __future__ import annotations

import json
import re

from scratchfab.pipeline.manifest import Manifest
from scratchfab.pipeline.report import write_report
from tests.test_report import _journal, _text, _verdict, fake_job

REASON = "the controller reset itself during check mode; nothing more was sent"


def _steps(page: str) -> tuple[str, str]:
    steps = re.search(r"<ol data-next='([\w-]+)'>(.*?)</ol>", page)
    assert steps
    return steps.group(1), _text(steps.group(2))


def _stream(page: str) -> str:
    found = re.search(r"<h2>Stream</h2>(.*?)</body>", page)
    assert found
    return _text(found.group(1))


def _failed_stream(job, started: str | None, status: str = "failed") -> None:
    entry: dict[str, str] = {"status": status, "reason": REASON}
    if started is not None:
        entry["started"] = started
    stages = {"export": {"status": "done"}, "stream": entry}
    (job / "manifest.json").write_text(json.dumps({"stages": stages}))


def test_a_failed_stream_after_an_earlier_finished_one_is_not_read_as_cut(tmp_path):
    job = fake_job(tmp_path)
    _journal(job, acked=6, finished=True, port="/dev/ttyUSB0")  # began 2026-01-01T00:00:00
    assert _steps(write_report(job).read_text())[0] == "cut"  # the journal alone: cut
    _failed_stream(job, started="2026-01-02T09:00:00")
    page = write_report(job, port="/dev/ttyUSB0").read_text()
    verdict, head, lines = _verdict(page)
    assert (verdict, head) == ("not-ready", "Not ready: the stream failed")
    assert ("fail", f"✘ no stream: the last one failed: {REASON}") in lines
    assert any(s == "info" and t.startswith("ℹ info an earlier run's session: ") for s, t in lines)
    kind, steps = _steps(page)
    assert kind == "fix" and "The board is cut" not in page
    assert "Deal with what stopped the stream" in steps and "run again" in steps
    stream = _stream(page)
    assert stream.startswith(f"The last stream failed: {REASON}.")
    assert "started 2026-01-01T00:00:00, is an earlier run's, not the one that failed" in stream


def test_a_stream_stopped_in_its_own_session_is_resumed_and_says_why(tmp_path):
    job = fake_job(tmp_path)
    lines = _journal(job, acked=3, finished=False, port="/dev/ttyUSB0")
    _failed_stream(job, started="2026-01-01T00:00:00")  # the same second: its own session
    page = write_report(job).read_text()
    _, head, checks = _verdict(page)
    assert head == "Not ready: the stream failed"
    assert any(
        t == f"ℹ info streamed to the machine on /dev/ttyUSB0 (3 of {lines} lines, unfinished)"
        for _, t in checks
    )
    kind, steps = _steps(page)
    assert kind == "resume" and f"stopped after 3 of {lines} lines" in steps
    assert "earlier run" not in _stream(page)


def test_a_manifest_without_the_start_time_says_the_session_may_be_earlier(tmp_path):
    job = fake_job(tmp_path)
    _journal(job, acked=6, finished=True, port="/dev/ttyUSB0")
    _failed_stream(job, started=None, status="interrupted")
    page = write_report(job).read_text()
    assert "The last stream was interrupted: " in _stream(page)
    assert "may be an earlier run's than the one that was interrupted" in _stream(page)
    assert _steps(page)[0] == "fix" and "The board is cut" not in page


def test_no_journal_after_a_failed_stream_says_none_was_recorded(tmp_path):
    job = fake_job(tmp_path)
    _failed_stream(job, started="2026-01-02T09:00:00")
    stream = _stream(write_report(job).read_text())
    assert stream == f"The last stream failed: {REASON}.the journal records no stream."


def test_the_manifest_keeps_when_a_failed_or_interrupted_stage_began(tmp_path):
    manifest = Manifest(tmp_path)
    manifest.start("stream", {"options": {}})
    began = manifest.stages["stream"]["started"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d", began)
    manifest.invalidate("stream", REASON)
    assert Manifest.load(tmp_path).stages["stream"] == {
        "status": "failed",
        "reason": REASON,
        "started": began,
    }
    manifest.start("optimize", {})
    manifest.interrupt("optimize", {}, "stopped")
    stopped = Manifest.load(tmp_path).stages["optimize"]
    assert stopped["status"] == "interrupted" and stopped["started"] >= began
    # a stage failing on changed inputs without having started keeps no time
    manifest.invalidate("design", "inputs changed")
    assert "started" not in Manifest.load(tmp_path).stages["design"]
