"""The report as a maker reads it on a first evening: the bundled demo's next steps, the
feasibility map's key at a readable size, and the walk-past section before verify ran."""

from __future__ import annotations

import html
import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from conftest import CHROMIUM, chromium_dom
from PIL import Image
from test_report import fake_job

from scratchfab.bundled import bundled_dir, find_bundled
from scratchfab.model.job import JobLayout
from scratchfab.pipeline.report import write_report


def _commands(page: str) -> list[list[str]]:
    """Every ``scratchfab run`` command the page shows, split as a shell splits it."""
    return [
        shlex.split(html.unescape(c))
        for c in re.findall(r"<code>([^<]*)</code>", page)
        if c.startswith("scratchfab run")
    ]


def test_bundled_pipeline_is_named_and_copied_not_edited_in_the_package(tmp_path):
    job = fake_job(tmp_path)
    demo = bundled_dir("pipelines") / "demo.toml"
    page = write_report(job, pipeline_file=demo).read_text()
    steps = re.search(r"<ol data-next='[\w-]+'>(.*?)</ol>", page)
    assert steps
    assert _commands(steps.group(1)) == [["scratchfab", "run", "my.toml", "--out", "."]]
    text = html.unescape(re.sub(r"<[^>]+>", "", steps.group(1)))
    assert "set [stream] port in the pipeline file" not in text  # not the package's own file
    assert f"copy the bundled pipeline {demo.resolve()} to a file of your own" in text
    # a job to fix and run again: the bundled pipeline by the name `run` finds it by
    low = fake_job(tmp_path / "low", rho=(0.5, 0.9))
    page = write_report(low, pipeline_file=demo, min_rho=0.8)
    commands = _commands(page.read_text())
    assert commands == [["scratchfab", "run", "demo", "--out", "."]]
    assert find_bundled("pipelines", commands[0][2], "pipeline").resolve() == demo.resolve()


def test_a_pipeline_of_ones_own_keeps_its_path_and_the_edit_advice(tmp_path):
    job = fake_job(tmp_path)
    page = write_report(job, pipeline_file=tmp_path / "board.toml").read_text()
    assert ["scratchfab", "run", "../board.toml", "--out", "."] in _commands(page)
    assert "set [stream] <code>port</code> in the pipeline file" in page
    assert "copy the bundled pipeline" not in page


def test_feasibility_map_is_shown_at_its_own_width_for_its_key(tmp_path):
    job = fake_job(tmp_path)
    width = 439  # the design stage's map: picture, colour bar and key
    for name in ("left", "right"):
        path = JobLayout(job).design.feasibility_png(name)
        Image.fromarray(np.full((686, width, 3), 200, np.uint8)).save(path)
    page = write_report(job).read_text()
    boxes = re.findall(r"<figure([^>]*)><img alt=\"(\w+) (feasibility|target)\"", page)
    assert sorted((v, kind) for _, v, kind in boxes) == [
        ("left", "feasibility"),
        ("left", "target"),
        ("right", "feasibility"),
        ("right", "target"),
    ]
    for attrs, _, kind in boxes:
        assert f"style='width:{width}px'" in attrs  # every box of a view as wide as the map
        assert ("class='wide'" in attrs) == (kind == "feasibility")  # the map unshrunk


def test_walk_past_section_says_verify_has_not_run_before_it_ran(tmp_path):
    job = fake_job(tmp_path)
    verify = JobLayout(job).verify_dir
    (verify / "sweep.gif").unlink()
    page = write_report(job).read_text()  # verify ran, without a sweep
    walk = re.search(r"<h2>Walking past the board</h2>(.*?)<h2>", page)
    assert walk and "[verify] sweep = 0" in walk.group(1)
    (verify / "metrics.json").unlink()  # verify has not run (a design that failed, say)
    page = write_report(job).read_text()
    walk = re.search(r"<h2>Walking past the board</h2>(.*?)<h2>", page)
    assert walk and "verify has not run" in walk.group(1) and "sweep = 0" not in walk.group(1)


def _toolpath_preview(job: Path) -> int:
    """A toolpath preview as the toolpath stage draws one: 1500 px wide; its width."""
    path = JobLayout(job).toolpath_preview
    Image.fromarray(np.full((1270, 1500, 3), 255, np.uint8)).save(path)
    return 1500


def test_toolpath_preview_spans_the_page_smoothly_scaled(tmp_path):
    job = fake_job(tmp_path)
    _toolpath_preview(job)
    page = write_report(job).read_text()
    shown = re.search(r"<figure([^>]*)><img alt=\"toolpath preview\"", page)
    assert shown and "class='full'" in shown.group(1)
    style = re.search(r"<style>(.*?)</style>", page, re.S)
    assert style
    rules = {k.strip(): v for k, v in re.findall(r"([^{}]+)\{([^}]*)\}", style.group(1))}
    full = rules["figure.full img"]
    assert "width:100%" in full and "image-rendering:auto" in full  # not pixelated when shrunk
    assert "image-rendering:auto" in rules["figure.wide img"]  # the loss plot's text too


@pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (.ci/run installs it)"
)
def test_toolpath_preview_measured_in_chromium_is_wider_than_the_other_pictures(tmp_path):
    """In a 1200 px window the preview fills the page's width (body at most 1200 px, 2em
    margins), far past the 640 px of the other wide pictures, its legend readable."""
    job = fake_job(tmp_path)
    natural = _toolpath_preview(job)
    report = write_report(job)
    measure = """<script>
window.addEventListener('load', function () {
  var img = document.querySelector('img[alt="toolpath preview"]');
  var r = img.getBoundingClientRect();
  document.body.setAttribute('data-preview', JSON.stringify([r.width, img.naturalWidth,
    document.body.getBoundingClientRect().width]));
});
</script></body>"""
    report.write_text(report.read_text().replace("</body>", measure))
    dom = chromium_dom(report, tmp_path / "profile", window="1200,900")
    found = re.search(r'data-preview="([^"]*)"', dom)
    assert found, dom[:2000]
    width, seen_natural, body = json.loads(html.unescape(found.group(1)))
    assert seen_natural == natural
    assert 1000 < width <= body  # the body's width less the box's padding and border
    assert body - width == pytest.approx(2 * 8 + 2, abs=1.0)


def test_a_view_below_min_rho_says_how_to_cut_the_board_anyway(tmp_path):
    """The gate's fix names the key that lets a maker cut a board below the threshold,
    with the value docs/files.md gives for never stopping."""
    job = fake_job(tmp_path, rho=(0.5, 0.9))
    page = write_report(job, min_rho=0.8).read_text()
    steps = re.search(r"<ol data-next='fix'>(.*?)</ol>", page)
    assert steps
    text = html.unescape(re.sub(r"<[^>]+>", "", steps.group(1)))
    assert "lower [verify] min_rho (-1 never stops the run)" in text
    files_md = Path(__file__).parents[1] / "docs" / "files.md"
    row = next(ln for ln in files_md.read_text().splitlines() if ln.startswith("| `min_rho`"))
    assert "`-1` never stops" in row  # the documented value the advice repeats
