"""`optimize`'s per-view lines name the crosstalk they show, and say once what it means."""

from __future__ import annotations

import json
import re

from conftest import cli_said, write_pipeline

from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline


def test_crosstalk_is_named_from_which_view_and_explained_once(tmp_path, capsys):
    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    run_pipeline(load_pipeline(path), job, until="design")
    code, said = cli_said(["optimize", str(job), "--iterations", "3"], capsys)
    assert code == 0, said
    views = json.loads((job / "optimize" / "summary.json").read_text())["quality"]["views"]
    assert set(views) == {"disc", "bar"}
    for k, v in views.items():
        ((j, x),) = v["crosstalk"].items()
        (line,) = [s for s in said.splitlines() if s.startswith(f"{k}: PSNR ")]
        assert f", crosstalk from {j} {x:.3f}" in line, line
    assert not re.search(r"\bx_\w+,", said), said  # no bare symbol x_k,j
    meaning = [s for s in said.splitlines() if s.startswith("crosstalk from ")]
    assert len(meaning) == 1, said
    assert "beyond what the two pictures share" in meaning[0]
    assert "0 = none, 1 = fully" in meaning[0]
