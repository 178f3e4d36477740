"""report.html names the weakest view where every view passes, and how to raise it.

An artist's board: one view at Mitsuba rho 0.80, the other 0.99, [verify] min_rho 0.8.
verify passed, and the report said "Ready to cut" with no word on the weak view. It
still says "Ready to cut" (verify's gate decides), with a warning that names the view,
its figure against the best view's and the gate, and what raises it.
"""

from __future__ import annotations

import json
import re

import pytest

from scratchfab.pipeline.report import write_report
from tests.test_report import _steps, _verdict, fake_job

# fake_job's views: left, right (the design's order: right, left)


@pytest.mark.parametrize(
    ("left", "right", "min_rho", "status"),
    [
        (0.99, 0.80, 0.8, "warn"),  # the artist's board: at the gate, far below the other
        (0.91234, 0.8765, 0.85, "warn"),  # 0.027 above the gate, 0.036 below the best
        (0.91234, 0.8765, 0.8, "info"),  # 0.077 above the gate: nearer the best
        (0.996, 0.998, 0.8, "info"),  # the demo's board
        (0.95, 0.6, None, "info"),  # no gate: named, not judged
        (0.95, 0.6, -1.0, "info"),  # the gate off
        (0.95, 0.7, 0.8, None),  # a view fails: its own line says so
    ],
)
def test_the_weakest_view_is_named_and_warned_of_only_when_far_behind(
    tmp_path, left, right, min_rho, status
):
    job = fake_job(tmp_path, rho=(left, right))
    page = write_report(job, min_rho=min_rho).read_text()
    verdict, head, lines = _verdict(page)
    weakest = [(s, t) for s, t in lines if "weakest view" in t]
    if status is None:
        assert verdict == "not-ready" and weakest == []
        return
    weak, best = ("left", "right") if left < right else ("right", "left")
    rho = {"left": left, "right": right}
    assert verdict == "ready"
    assert head == (
        "Ready to cut (read the 1 warning below)" if status == "warn" else "Ready to cut"
    )
    assert len(weakest) == 1 and weakest[0][0] == status
    text = weakest[0][1]
    said = f"weakest view: {weak}, rho_kk {rho[weak]:.3f} (the best, {best}, {rho[best]:.3f}"
    assert said in text, text
    gated = min_rho is not None and min_rho > -1
    if gated:
        assert f"; {rho[weak] - min_rho:.3f} above [verify] min_rho {min_rho:g})" in text
    else:
        assert "min_rho" not in text
    found = re.search(r"<span data-stat='weakest.rho'>([^<]+)</span>", page)
    assert found and float(found.group(1)) == pytest.approx(rho[weak], abs=1e-3)
    steps = _steps(page)
    passes = [s for s in steps if s.startswith("The board passes as it is.")]
    if status == "warn":
        assert "to raise it, run optimize longer ([optimize] iterations)" in text
        # the step comes before the machine's: the choice is made before cutting
        assert len(passes) == 1 and f"If view {weak} should look as clear as {best}" in passes[0]
        assert steps.index(passes[0]) < next(i for i, s in enumerate(steps) if "--check" in s)
    else:
        assert passes == [] and "to raise it" not in text


def test_a_weak_view_the_bare_board_outshines_is_told_what_design_warned(tmp_path):
    """Optimizing longer cannot raise a view where the glint outshines its grooves: the
    warning gives verify's glint advice instead, as a failing view's line does."""
    job = fake_job(tmp_path, rho=(0.99, 0.81))
    path = job / "design" / "feasibility.json"
    feasibility = json.loads(path.read_text())
    feasibility["views"] = {"right": {"glint_fraction": 0.05}, "left": {"glint_fraction": 0.0}}
    path.write_text(json.dumps(feasibility))
    page = write_report(job, min_rho=0.8).read_text()
    _, _, lines = _verdict(page)
    (text,) = [t for s, t in lines if s == "warn" and "weakest view: right" in t]
    assert "the bare board glints into right (design warned; on 5.0% of the board)" in text
    assert "move the camera or the light" in text and "run optimize longer" not in text
    steps = " ".join(_steps(page))
    assert "run optimize longer" not in steps and "move the camera or the light" in steps
