"""The report on a noisy verify render, on a failed run's next steps, and on its title."""

from __future__ import annotations

import html
import json
import re

from test_report import _png, _text, _verdict, fake_job

from scratchfab.bundled import bundled_dir
from scratchfab.model.job import JobLayout
from scratchfab.pipeline.report import write_report
from scratchfab.verify.noise import diff_noise_advice, noise_advice

NOISY = {  # a render at 512 spp whose noise costs rho 0.06
    "rho": 0.808,
    "rho_noise_free": 0.868,
    "noise_to_signal": 0.154,
    "noise": 0.14,
    "spp": 512,
    "seconds": 12.0,
    "diff_noise_share": 0.8,
}


def _noisy_job(tmp_path, **left):
    job = fake_job(tmp_path)
    path = JobLayout(job).verify_metrics
    metrics = json.loads(path.read_text())
    metrics["views"]["left"] |= NOISY | left
    metrics["views"]["right"] |= {"diff_noise_share": 0.1}
    path.write_text(json.dumps(metrics))
    for name in ("left", "right"):
        _png(JobLayout(job).verify_diff_png(name), 30)
    return job


def _steps(page: str) -> str:
    steps = re.search(r"<ol data-next='[\w-]+'>(.*?)</ol><p class='muted'>(.*?)</p>", page)
    assert steps
    return _text(steps.group(1)) + "\n" + _text(steps.group(2))


def test_a_gate_failed_for_noise_says_so_and_names_the_spp(tmp_path):
    job = _noisy_job(tmp_path)
    page = write_report(job, min_rho=0.85, pipeline_file=tmp_path / "board.toml").read_text()
    _, head, lines = _verdict(page)
    assert head == "Not ready: left rho 0.808 below 0.85 in a noisy render"
    said = noise_advice(NOISY, 0.85, "[verify] spp =")
    assert "explains it" in said
    line = next(t for s, t in lines if s == "fail" and t.startswith("✘ no left looks like"))
    assert line.endswith(f"; {said}")
    spp = int(re.search(r"\[verify\] spp = (\d+)", line).group(1))
    assert spp > 512
    steps = _steps(page)
    assert "too noisy to judge a view: raise [verify] spp" in steps
    assert "run optimize longer" not in steps


def test_noise_that_does_not_explain_the_shortfall_keeps_the_optimize_advice(tmp_path):
    job = _noisy_job(tmp_path)
    page = write_report(job, min_rho=0.87, pipeline_file=tmp_path / "board.toml").read_text()
    _, head, lines = _verdict(page)
    assert head == "Not ready: left rho 0.808 below 0.87"  # noise-free 0.868: still below
    line = next(t for s, t in lines if t.startswith("✘ no left looks like"))
    assert "costs rho about 0.060 (noise-free about 0.868)" in line
    assert "run optimize longer" in _steps(page)


def test_a_difference_map_mostly_noise_says_so_under_it(tmp_path):
    job = _noisy_job(tmp_path)
    page = write_report(job, min_rho=0.5).read_text()
    captions = dict(
        re.findall(r'<img alt="(\w+) difference map".*?<figcaption>(.*?)</figcaption>', page)
    )
    left = _text(captions["left"])
    assert left.endswith(diff_noise_advice(NOISY, "[verify] spp ="))
    assert "mostly sampling noise: about 80 % of these differences" in left
    assert "noise" not in _text(captions["right"])  # 10 %: the board's own differences


def test_a_failed_design_reads_once_and_runs_again_once(tmp_path):
    """A design that failed is not also 'not run'; the fix and 'run again' are said once;
    no PORT footnote where no command names PORT."""
    job = fake_job(tmp_path)
    JobLayout(job).design.feasibility_json.unlink()
    stages = {"design": {"status": "failed", "reason": "disc.png: not an image file"}}
    (job / "manifest.json").write_text(json.dumps({"stages": stages}))
    page = write_report(job, pipeline_file=tmp_path / "my.toml").read_text()
    _, head, lines = _verdict(page)
    assert head.startswith("Not ready: stage design failed")
    assert "design has not run" not in head
    assert not any("design has not run" in t for _, t in lines)
    steps = _steps(page)
    assert len(re.findall(r"(?i)run again", steps)) == 1, steps
    assert "Fix what stage design reports above." in steps
    assert "scratchfab run ../my.toml --out ." in steps
    assert "PORT" not in steps and "serial port" not in steps
    # Where a command names PORT, the footnote says what it is.
    ready = html.unescape(write_report(fake_job(tmp_path / "ready")).read_text())
    assert "--port PORT" in ready and "PORT is your machine's serial port" in ready


def test_every_fix_leaves_run_again_to_the_last_step(tmp_path):
    job = fake_job(tmp_path, rho=(0.5, 0.6))
    feasibility = {"views": {}, "pairs": [], "errors": ["the tool cannot reach view left"]}
    feasibility["warnings"] = []
    JobLayout(job).design.feasibility_json.write_text(json.dumps(feasibility))
    steps = _steps(write_report(job, min_rho=0.8).read_text())
    assert len(re.findall(r"(?i)run again", steps)) == 1, steps


def test_a_copied_demo_title_says_where_it_comes_from(tmp_path):
    demo = bundled_dir("pipelines") / "demo.toml"
    name = "scratchfab demo: sun and house"
    assert f'name = "{name}"' in demo.read_text()
    job = fake_job(tmp_path)
    mine = tmp_path / "my.toml"
    mine.write_text(demo.read_text())
    page = write_report(job, name, pipeline_file=mine).read_text()
    note = re.search(r"<p class='muted' data-title-note>(.*?)</p>", page)
    assert note and "[pipeline] name" in html.unescape(note.group(1))
    assert "my.toml" in note.group(1)
    # The demo itself, or a name of one's own: no note.
    assert "data-title-note" not in write_report(job, name, pipeline_file=demo).read_text()
    assert "data-title-note" not in write_report(job, "my board", pipeline_file=mine).read_text()
