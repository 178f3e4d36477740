"""A Ctrl-C that reaches the runner from inside a stage is recorded in words, not as
``KeyboardInterrupt: `` (a reviewer: the report would print that as the reason)."""

from __future__ import annotations

import pytest
from conftest import write_pipeline

from scratchfab.pipeline import runner
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.manifest import Manifest
from scratchfab.pipeline.runner import run_pipeline


@pytest.mark.parametrize(
    ("raised", "reason"),
    [
        (KeyboardInterrupt(), "interrupted (Ctrl-C)"),
        (RuntimeError("disk on fire"), "RuntimeError: disk on fire"),  # any other: its kind
    ],
)
def test_a_stage_stopped_by_ctrl_c_is_recorded_as_interrupted(
    tmp_path, monkeypatch, raised, reason
):
    path = write_pipeline(tmp_path)
    job = tmp_path / "job"

    def stopped(self):
        raise raised

    monkeypatch.setattr(runner._Stages, "_run_design", stopped)
    with pytest.raises(type(raised)):
        run_pipeline(load_pipeline(path), job, say=lambda _: None)
    entry = Manifest.load(job).stages["design"]
    assert entry["status"] == "failed" and entry["reason"] == reason
