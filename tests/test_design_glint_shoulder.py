"""The glint's shoulder: past the glint, where the bare board still outshines sparse grooves.

The references are renders by the project's renderer (SPEC section 4) on a 170 mm strip
whose half-vector tilts from 0 to about 12.5 deg: the bare board, and the strip tiled
edge to edge with grooves turned toward the half-vector (what grooves return per groove
area). A pixel a share c of which grooves cover returns c times the latter plus (1 - c)
times the former; random grooves at that coverage check that too.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace

import numpy as np
import pytest
from test_design_glint import (
    DEMO,
    DEMO_TOML,
    GLINT_WORDS,
    ROOT,
    _maker_design,
    _render,
    _strip_design,
    _tiling,
)

from scratchfab.design.feasibility import (
    SHOULDER_WARN_FRACTION,
    FeasibilityReport,
    check_feasibility,
    outshine_limit_deg,
    tilt_deg,
)
from scratchfab.design.quick import quick_design
from scratchfab.design.targets import board_image
from scratchfab.model.design import MAX_SCRATCHES, Design, design_from_mapping, load_design
from scratchfab.model.scratches import ScratchSet

SHOULDER_WORDS = "outshines the scratches"
STRIP_MM = 170


def _checked(design: Design) -> FeasibilityReport:
    """The check with the design's own targets as board images, as ``design`` runs it."""
    boards = {v.name: board_image(design.target_path(v), design.board) for v in design.views}
    return check_feasibility(design, boards=boards)


def _said(report: FeasibilityReport) -> list[str]:
    return [w for w in report.warnings if SHOULDER_WORDS in w]


@pytest.fixture(scope="module")
def strip():
    """The strip's bare render, its edge-to-edge grooved render, the pixels inside and their tilt."""
    design = _strip_design(0.05, STRIP_MM)
    tool = design.scratch
    vr, bare = _render(design, "top", None)
    covered = np.zeros_like(bare)
    half = STRIP_MM / 2
    for phase in (0.0, 0.25, 0.5, 0.75):
        tiles = _tiling((-half, -2.0, half, 2.0), 0.0, tool.width_mm, tool.depth_mm, phase)
        covered += _render(design, "top", tiles)[1] / 4
    inside = vr.valid & (np.abs(vr.area_on_board - vr.area) < 1e-9 * vr.area)
    return design, bare, covered, inside, tilt_deg(vr.half_vector)


@pytest.fixture(scope="module")
def maker():
    """The maker's case (the demo on a 200 x 200 mm board, 2000 scratches) and its check."""
    design = _maker_design()
    return design, _checked(design)


def test_the_shoulder_is_where_the_bare_render_outshines_grooves_at_the_layouts_coverage(
    strip, maker
):
    """At the maker's coverage (0.05) the bare strip renders brighter than the grooves return
    below the shoulder limit (about 10 deg), darker above it; at the advised count's
    coverage nowhere past its own, narrower band."""
    _, bare, covered, inside, tilt = strip
    design, report = maker
    c, limit, glint = report.groove_coverage, report.shoulder_deg, report.glint_deg
    assert c is not None and limit is not None
    assert 0.04 < c < 0.07 and limit > glint + 5.0
    assert tilt[inside].max() > limit + 1.0
    outshone = bare > c * covered
    past = inside & (tilt > glint + 0.3)
    sure = past & (np.abs(tilt - limit) > 0.3)
    assert outshone[sure].sum() > 50 and (~outshone[sure]).sum() > 50
    np.testing.assert_array_equal(outshone[sure], tilt[sure] < limit)

    assert report.shoulder_count is not None
    advised = _checked(
        replace(design, scratch=replace(design.scratch, count=report.shoulder_count))
    )
    assert advised.groove_coverage is not None and advised.groove_coverage <= 1.0
    assert advised.shoulder_deg is not None and advised.shoulder_deg < limit - 3.0
    # past its (narrower) band, under the warning's share of each view, nothing is outshone
    beyond = past & (tilt > advised.shoulder_deg + 0.3)
    assert beyond.sum() > 50
    assert not np.any((bare > advised.groove_coverage * covered)[beyond])


@pytest.mark.parametrize("coverage", [0.05, 0.3])
def test_random_grooves_add_their_coverage_times_what_edge_to_edge_grooves_return(strip, coverage):
    """The check's premise: a pixel returns c S + (1 - c) D for grooves covering a share c.
    Random grooves (uniform across the strip, eight layouts) against the tiled and bare
    renders, averaged over 2-degree bands of tilt."""
    design, bare, covered, inside, tilt = strip
    tool = design.scratch
    rng = np.random.default_rng(7)
    n = round(coverage * STRIP_MM / tool.width_mm)
    mean = np.zeros_like(bare)
    for _ in range(8):
        x = rng.uniform(-STRIP_MM / 2, STRIP_MM / 2, n)
        grooves = ScratchSet.from_arrays(
            np.stack([x, np.full(n, -2.0)], axis=1),
            np.stack([x, np.full(n, 2.0)], axis=1),
            tool.width_mm,
            tool.depth_mm,
        )
        mean += _render(design, "top", grooves)[1] / 8
    expected = coverage * covered + (1.0 - coverage) * bare
    for lo in np.arange(0.0, 12.0, 2.0):
        band = inside & (tilt >= lo) & (tilt < lo + 2.0)
        assert band.sum() > 40
        assert mean[band].mean() == pytest.approx(expected[band].mean(), rel=0.12)


def test_the_maker_warns_with_the_share_and_a_count_that_clears_it(maker):
    design, report = maker
    said = _said(report)
    assert len(said) == 1, report.warnings
    for name in ("sun", "house"):
        share = report.views[name].shoulder_fraction
        assert share is not None and 0.08 < share < 0.25
        assert f"'{name}' on {100 * share:.1f}% of the board, around its glint" in said[0]
        assert report.to_json()["views"][name]["shoulder_fraction"] == pytest.approx(
            share, abs=1e-6
        )
    count = report.shoulder_count
    assert count is not None and count > design.scratch.count
    assert f"set [scratch] count to at least {count} (groove coverage " in said[0]
    assert f"tilts at least {report.shoulder_deg:.1f} deg" in said[0]
    data = report.to_json()
    assert data["shoulder_limit_deg"] == pytest.approx(report.shoulder_deg, abs=1e-4)
    assert data["shoulder_count"] == count
    assert report.ok

    advised = _checked(replace(design, scratch=replace(design.scratch, count=count)))
    assert not _said(advised)
    assert advised.shoulder_count is None
    assert all(v.shoulder_fraction < SHOULDER_WARN_FRACTION for v in advised.views.values())
    assert [w for w in advised.warnings if GLINT_WORDS in w]  # the glint itself stays
    assert not [w for w in advised.warnings if "will overlap" in w]
    fewer = _checked(replace(design, scratch=replace(design.scratch, count=count - 40)))
    assert _said(fewer)  # the least count, up to the search's step


def test_the_quick_form_says_which_count_to_give():
    """Sparse grooves on a glint-free quick design: its half-vectors tilt 6.6 deg and more,
    inside the shoulder of a 0.05 coverage."""
    design = quick_design([DEMO / "sun.png", DEMO / "house.png"], (200.0, 200.0), count=2000)
    report = _checked(design)
    assert all(v.glint_fraction == 0 for v in report.views.values())
    said = _said(report)
    assert len(said) == 1
    assert f"give --count {report.shoulder_count} or more" in said[0]
    assert "[scratch]" not in said[0] and "worst around (" in said[0]
    again = _checked(
        quick_design(
            [DEMO / "sun.png", DEMO / "house.png"], (200.0, 200.0), count=report.shoulder_count
        )
    )
    assert not _said(again)


def test_where_no_count_up_to_the_maximum_clears_it_the_warning_says_so():
    """A 1 m board of 100 scratches 0.1 mm long and 0.02 mm wide: the count the shoulder
    needs (about 13 million) is above what a design takes. The check warns without a
    count instead of failing on it (a ValueError from the count's bound)."""
    data = tomllib.loads(DEMO_TOML.read_text())
    data["board"]["width_mm"] = data["board"]["height_mm"] = 1000.0
    data["scratch"].update(
        width_mm=0.02, depth_mm=0.002, min_length_mm=0.1, max_length_mm=0.2, count=100
    )
    design = design_from_mapping(data, "big.toml", DEMO_TOML.parent)
    report = _checked(design)
    said = _said(report)
    assert len(said) == 1 and report.shoulder_count is None
    assert f"no scratch count up to {MAX_SCRATCHES:,} makes the grooves outshine it" in said[0]
    assert "set [scratch] count" not in said[0]
    assert f"tilts at least {report.shoulder_deg:.1f} deg" in said[0]
    assert report.to_json()["shoulder_count"] is None
    # the reference: the coverage grows with the count (the lengths do not depend on it),
    # and at the maximum the grooves still leave more than the share outshone past the glint
    assert report.groove_coverage is not None
    most = report.groove_coverage * MAX_SCRATCHES / design.scratch.count
    tool = design.scratch
    limit = outshine_limit_deg(tool.width_mm, tool.depth_mm, design.board.roughness, most)
    shares = [
        np.mean((v.tilt_map >= report.glint_deg) & (v.tilt_map < limit))
        for v in report.views.values()
    ]
    assert max(shares) >= SHOULDER_WARN_FRACTION, shares


def test_no_target_images_no_shoulder():
    report = check_feasibility(_maker_design())
    assert report.shoulder_deg is None and report.shoulder_count is None
    assert report.to_json()["views"]["sun"]["shoulder_fraction"] is None
    assert not _said(report)


@pytest.mark.parametrize(
    "make",
    [
        lambda: load_design(DEMO_TOML),
        lambda: load_design(ROOT / "pipelines" / "full-size.toml"),
        lambda: quick_design([DEMO / "sun.png"], (40.0, 40.0)),
        lambda: quick_design([DEMO / "sun.png", DEMO / "house.png"], (100.0, 60.0)),
        lambda: quick_design(
            [DEMO / "sun.png", DEMO / "moon.png", DEMO / "house.png"], (300.0, 200.0)
        ),
        lambda: quick_design([DEMO / "moon.png"] * 6, (500.0, 500.0)),
    ],
    ids=["demo", "full-size", "quick-1-small", "quick-2", "quick-3-large", "quick-6-500"],
)
def test_bundled_designs_and_the_quick_form_have_no_shoulder(make):
    report = _checked(make())
    assert all(v.shoulder_fraction == 0 for v in report.views.values())
    assert not _said(report) and report.shoulder_count is None
