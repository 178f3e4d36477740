"""The glint advice's distance factors, checked by rerunning the check as design runs it.

The maker's case (the demo on a 200 x 200 mm board): standing camera and light as far as
the glint's factor says ends the glint, but the band past it where the bare board still
outshines the sparse layout's grooves stays; the advice names the factor that ends that
too, and the shoulder warning the one for every view at once.
"""

from __future__ import annotations

import re
from dataclasses import replace

import pytest
from test_design_glint import GLINT_WORDS, _maker_design
from test_design_glint_shoulder import SHOULDER_WORDS, _checked

from scratchfab.design.feasibility import SHOULDER_WARN_FRACTION, FeasibilityReport
from scratchfab.model.design import Design

GLINT_FACTOR = r"stand both at least (\d+\.\d) times as far from the board's centre"
SHOULDER_FACTOR = r"at least (\d+\.\d) times also ends the glint's shoulder"
JOINT_FACTOR = r"standing the cameras and the light at least (\d+\.\d) times as far"


def scaled(design: Design, f: float) -> Design:
    """Cameras and light ``f`` times as far from the board's centre."""
    light = tuple(f * c for c in design.light.position_mm)
    views = [replace(v, position_mm=tuple(f * c for c in v.camera_position)) for v in design.views]
    return replace(design, light=replace(design.light, position_mm=light), views=views)


def said(report: FeasibilityReport, words: str, name: str | None = None) -> list[str]:
    return [w for w in report.warnings if words in w and (name is None or f"view '{name}'" in w)]


@pytest.fixture(scope="module")
def maker():
    design = _maker_design()
    return design, _checked(design)


def test_the_glint_advice_names_the_factor_that_ends_the_shoulder_too(maker):
    design, report = maker
    for name in ("sun", "house"):
        (text,) = said(report, GLINT_WORDS, name)
        glint_k = float(re.search(GLINT_FACTOR, text).group(1))
        both_k = float(re.search(SHOULDER_FACTOR, text).group(1))
        assert both_k > glint_k
        assert f"tilted up to {report.shoulder_deg:.1f} deg" in text
        # The glint's factor ends the glint, yet design still warns of the band past it.
        at_glint = _checked(scaled(design, glint_k))
        assert at_glint.views[name].glint_fraction == 0.0
        assert at_glint.views[name].shoulder_fraction >= SHOULDER_WARN_FRACTION
        assert said(at_glint, SHOULDER_WORDS)
        # The second factor ends both: design, rerun, warns of neither; a tenth less still
        # warns of the band.
        at_both = _checked(scaled(design, both_k))
        assert at_both.views[name].glint_fraction == 0.0
        assert at_both.views[name].shoulder_fraction < SHOULDER_WARN_FRACTION
        assert not said(at_both, GLINT_WORDS, name)
        less = _checked(scaled(design, round(both_k - 0.1, 1)))
        assert less.views[name].shoulder_fraction >= SHOULDER_WARN_FRACTION


def test_the_shoulder_warning_names_one_factor_for_every_view(maker):
    design, report = maker
    (text,) = said(report, SHOULDER_WORDS)
    k = float(re.search(JOINT_FACTOR, text).group(1))
    rerun = _checked(scaled(design, k))
    assert not said(rerun, SHOULDER_WORDS) and not said(rerun, GLINT_WORDS)
    assert all(v.shoulder_fraction < SHOULDER_WARN_FRACTION for v in rerun.views.values())
    assert said(_checked(scaled(design, round(k - 0.1, 1))), SHOULDER_WORDS)


def test_without_targets_the_glint_advice_names_only_the_glints_factor(maker):
    from scratchfab.design.feasibility import check_feasibility

    design, _ = maker
    report = check_feasibility(design)
    for name in ("sun", "house"):
        (text,) = said(report, GLINT_WORDS, name)
        assert re.search(GLINT_FACTOR, text) and not re.search(SHOULDER_FACTOR, text)
