"""verify's gate names what design's check found where the bare board outshines the grooves.

A sparse layout on a glinting test board: design's check (``feasibility.json``, as the
design stage writes it) warns of the glint's shoulder and names the count that clears it;
the glint itself covers about 1 % of the board. The gate's refusal names the shoulder,
its shares and that count, not the glint's "move the camera or the light".
"""

from __future__ import annotations

import dataclasses
import json

import pytest
from test_optimize_glint import glint_design
from test_optimize_helpers import make_job

from scratchfab.design.feasibility import SHOULDER_WARN_FRACTION, check_feasibility
from scratchfab.design.targets import board_image
from scratchfab.model.design import load_design
from scratchfab.verify.verify import VerifyGateError, VerifySettings, run_verify_job


def test_the_gate_names_the_shoulder_and_designs_count_not_a_speck_of_glint(tmp_path):
    base = glint_design(resolution=16, count=300)
    # The light a little higher than glint_design's: its glint shrinks to about 1 %.
    light = dataclasses.replace(base.light, position_mm=(0.0, 70.0, 300.0))
    job = make_job(tmp_path / "job", dataclasses.replace(base, light=light), count=300)
    design = load_design(job / "design" / "design.toml")
    boards = {v.name: board_image(design.target_path(v), design.board) for v in design.views}
    report = check_feasibility(design, boards=boards)
    (job / "design" / "feasibility.json").write_text(json.dumps(report.to_json()))
    shoulders = {n: v.shoulder_fraction or 0.0 for n, v in report.views.items()}
    assert all(s >= SHOULDER_WARN_FRACTION for s in shoulders.values()), shoulders
    assert report.shoulder_count is not None and report.groove_coverage is not None
    assert 0 < report.views["left"].glint_fraction < SHOULDER_WARN_FRACTION
    with pytest.raises(VerifyGateError) as caught:
        run_verify_job(job, VerifySettings(spp=16, min_rho=0.99))
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    assert 0 < metrics["views"]["left"]["glint_share"] < SHOULDER_WARN_FRACTION
    views = ", ".join(f"{n} on {100 * s:.1f}% of the board" for n, s in shoulders.items())
    said = str(caught.value)
    assert (
        "past the glint the bare board still outshines the sparse grooves at groove coverage "
        f"{report.groove_coverage:.2f} (the glint's shoulder; design warned): {views}; "
        "optimizing longer does not help, more scratches do: design --count "
        f"{report.shoulder_count} or more" in said
    )
    assert "glints into" not in said and "optimize longer" not in said
    named = str(caught.value.named("[verify] min_rho =", "p.toml"))
    assert f"[scratch] count = {report.shoulder_count} or more" in named
    assert caught.value.glinting == ("left",)  # the glint is there, only not named
