"""The report as a maker reads it on a first evening: the bundled demo's next steps, the
feasibility map's key at a readable size, and the walk-past section before verify ran."""

from __future__ import annotations

import html
import re
import shlex

import numpy as np
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
