from __future__ import annotations

import base64
import hashlib
import html
import json
import os
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from conftest import CHROMIUM, check_report_in_chromium, pasted_words
from PIL import Image

from scratchfab.pipeline.manifest import Manifest, fingerprint
from scratchfab.pipeline.report import write_report


def _png(path: Path, seed: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(0, 255, (16, 16), dtype=np.uint8)).save(path)


# The fabricated design: views in the order right, left (not alphabetical), each placed
# by azimuth, elevation (degrees) and distance (mm) from the board's centre.
PLACES = {"right": (30.0, 10.0, 420.0), "left": (-15.0, -5.0, 600.0)}
LIGHT = (0.0, 25.0, 500.0)


def _cartesian(azimuth: float, elevation: float, distance: float) -> list[float]:
    """A point seen at these angles: a rotation of (0, 0, distance) about x, then about y."""
    el, az = np.radians(elevation), np.radians(azimuth)
    about_x = np.array([[1, 0, 0], [0, np.cos(el), np.sin(el)], [0, -np.sin(el), np.cos(el)]])
    about_y = np.array([[np.cos(az), 0, np.sin(az)], [0, 1, 0], [-np.sin(az), 0, np.cos(az)]])
    return list(about_y @ about_x @ np.array([0.0, 0.0, distance]))


def _vec(v: list[float]) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def fake_job(root: Path, rho: tuple[float, float] = (0.91234, 0.8765)) -> Path:
    """A job folder as the stages leave it, every file fabricated (no stage runs)."""
    job = root / "job"
    for i, name in enumerate(("left", "right")):
        _png(job / "design" / "targets" / f"{name}.png", i)
        _png(job / "optimize" / "renders" / f"{name}.png", 10 + i)
        _png(job / "verify" / f"{name}.png", 20 + i)
    frames = [Image.fromarray(np.full((8, 8), v, np.uint8)) for v in (0, 128, 255)]
    frames[0].save(job / "verify" / "sweep.gif", save_all=True, append_images=frames[1:])
    metrics = {
        "names": ["left", "right"],
        "views": {
            "left": {
                "rho": rho[0],
                "psnr": 21.5,
                "rel_l2": 0.0123,
                "spp": 64,
                "seconds": 2.0,
                "crosstalk": {"right": 0.0456},
            },
            "right": {
                "rho": rho[1],
                "psnr": 19.25,
                "rel_l2": 0.0099,
                "spp": 64,
                "seconds": 2.1,
                "crosstalk": {"left": -0.0123},
            },
        },
    }
    (job / "verify" / "metrics.json").write_text(json.dumps(metrics))
    views = "".join(
        f'[[views]]\nname = "{name}"\nposition_mm = {_vec(_cartesian(*place))}\n'
        "look_at_mm = [0.0, 0.0, 0.0]\n"
        for name, place in PLACES.items()
    )
    (job / "design" / "design.toml").write_text(
        f"[board]\nwidth_mm = 60.0\n\n[light]\nposition_mm = {_vec(_cartesian(*LIGHT))}\n\n" + views
    )
    feasibility = {"views": {}, "pairs": [], "errors": [], "warnings": []}
    (job / "design" / "feasibility.json").write_text(json.dumps(feasibility))
    stats = {
        "input_count": 2000,
        "outside_count": 0,
        "clipped_count": 0,
        "short_count": 0,
        "merged_count": 0,
        "count": 2000,
        "cut_length_mm": 15220.8,
        "travel_length_mm": 1217.5,
        "travel_input_order_mm": 41815.7,
        "estimated_time_s": 5009.1,
    }
    (job / "toolpath").mkdir()
    (job / "toolpath" / "toolpath.json").write_text(json.dumps({"statistics": stats}))
    (job / "export").mkdir()
    (job / "export" / "board.gcode").write_text(GCODE)
    (job / "export" / "board.svg").write_text("<svg xmlns='http://www.w3.org/2000/svg'/>")
    (job / "optimize" / "scratches.csv").write_text("x0,y0,x1,y1\n")
    (job / "optimize" / "log.csv").write_text(
        "iteration,loss,seconds,psnr_left,rho_left,x_left_right,psnr_right,rho_right,x_right_left\n"
        "119,0.0313,0.4,20.61,0.9123,0.0211,26.88,0.8801,0.0190\n"
    )
    return job


GCODE = "G21\nG90\nG0 Z5\nG0 X1 Y1\nG1 Z-0.1 F200\nG1 X5 Y5 F600\nG0 Z5\nM2\n"


def _journal(
    job: Path, acked: int, finished: bool, gcode: bytes | None = None, port: str | None = None
) -> int:
    """Journal a stream of the job's G-code (or of ``gcode``); returns its line count.

    ``port``: recorded in the start event as the sender does (None: an older journal).
    """
    body = gcode if gcode is not None else (job / "export" / "board.gcode").read_bytes()
    lines = [n for n, ln in enumerate(body.decode().splitlines(), 1) if ln.strip()]
    events: list[dict[str, object]] = [
        {
            "ev": "start",
            "file": "job/export/board.gcode",
            "sha256": hashlib.sha256(body).hexdigest(),
            "blocks": len(lines),
            "resume": False,
            "resume_from": None,
            "protocol": "counting",
            "preamble": [],
            "planner": 15,
            "time": "2026-01-01T00:00:00",
        }
    ]
    if port is not None:
        events[0]["port"] = port
    events += [{"ev": "ack", "i": i, "line": n} for i, n in enumerate(lines[:acked])]
    if finished:
        events.append({"ev": "end", "complete": True, "time": "2026-01-01T00:01:00"})
    (job / "stream").mkdir(exist_ok=True)
    (job / "stream" / "journal.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    return len(lines)


def _verdict(page: str) -> tuple[str, str, list[tuple[str, str]]]:
    """The verdict box: its state, its headline and its (status, text) lines."""
    box = re.search(
        r"<div class='verdict [^']*' data-verdict='([^']+)'><h2>(.*?)</h2>(.*?)</div>", page
    )
    assert box, page[:2000]
    lines = re.findall(r"<li data-check='(\w+)'>(.*?)</li>", box.group(3))
    return box.group(1), html.unescape(box.group(2)), [(s, _text(t)) for s, t in lines]


def _text(fragment: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", fragment))


def test_report_is_self_contained_and_shows_metrics(tmp_path):
    job = fake_job(tmp_path)
    page = write_report(job).read_text()
    # No external resources: every src is a data URI (2 views x 3 pictures + the sweep).
    srcs = re.findall(r'src="([^"]*)"', page)
    assert len(srcs) == 7 and all(s.startswith("data:image/") for s in srcs)
    values = dict(re.findall(r'data-metric="([^"]+)" data-value="([^"]+)"', page))
    assert float(values["left.rho"]) == 0.91234
    assert float(values["left.crosstalk.right"]) == 0.0456
    assert float(values["right.crosstalk.left"]) == -0.0123
    # Moving the folder keeps every picture: nothing refers to where it was.
    assert str(job.resolve()) not in page and "images decoded" not in page
    assert str(tmp_path) not in page


def test_verdict_ready_lists_every_check_with_the_configured_min_rho(tmp_path):
    job = fake_job(tmp_path)
    # 0.8: the weaker view (0.877) lies nearer the best (0.912) than the gate, no warning
    page = write_report(job, min_rho=0.8).read_text()
    verdict, head, lines = _verdict(page)
    assert verdict == "ready" and head == "Ready to cut"
    texts = " | ".join(t for _, t in lines)
    metrics = json.loads((job / "verify" / "metrics.json").read_text())["views"]
    for name in PLACES:
        assert f"{name} looks like its target: rho_kk {metrics[name]['rho']:.3f} ≥ 0.8" in texts
    assert "feasibility" in texts and "crosstalk: at most 0.046" in texts
    assert "all 2000 scratches inside it" in texts
    stats = json.loads((job / "toolpath" / "toolpath.json").read_text())["statistics"]
    hours, minutes = divmod(round(stats["estimated_time_s"] / 60), 60)
    assert f"estimated cutting time: {hours} h {minutes} min" in texts
    # Every status has a word and a symbol besides its colour.
    statuses = {s for s, _ in lines}
    assert statuses <= {"ok", "info"}
    for status, text in lines:
        assert text.startswith({"ok": "✔ ok", "info": "ℹ info"}[status])
    # Crosstalk has no configured threshold: informative, never coloured as good or bad.
    cross = re.findall(r'<td([^>]*)data-metric="\w+\.crosstalk\.\w+"', page)
    assert cross and all("class" not in attrs for attrs in cross)


def test_verdict_not_ready_when_a_view_falls_below_min_rho(tmp_path):
    job = fake_job(tmp_path, rho=(0.91234, 0.75))
    page = write_report(job, min_rho=0.8).read_text()
    verdict, head, lines = _verdict(page)
    assert verdict == "not-ready" and head.startswith("Not ready: ")
    assert "right rho 0.750 below 0.8" in head and "left" not in head
    assert (
        "fail",
        "✘ no right looks like its target: rho_kk 0.750 < 0.8 ([verify] min_rho; 1 = perfect)",
    ) in lines
    # The table marks the low view in words too, against the configured threshold.
    right = re.search(r'data-metric="right.rho"[^>]*>([^<]*)<span class=\'(\w+)\'>([^<]*)<', page)
    left = re.search(r'data-metric="left.rho"[^>]*>([^<]*)<span class=\'(\w+)\'>([^<]*)<', page)
    assert right and right.group(2, 3) == ("bad", "✘ low")
    assert left and left.group(2, 3) == ("ok", "✔ ok")
    assert "<span data-stat='min_rho'>0.8</span>" in page
    # The next steps fix the view; they do not send anyone to the machine.
    steps = re.search(r"<ol data-next='([\w-]+)'>(.*?)</ol>", page)
    assert steps and steps.group(1) == "fix" and "run optimize longer" in steps.group(2)
    assert "--check" not in steps.group(2)
    # A lower configured min_rho passes the same view; without one, verify's gate decides.
    assert _verdict(write_report(job, min_rho=0.7).read_text())[0] == "ready"
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    metrics["gate"] = {"min_rho": 0.76}
    (job / "verify" / "metrics.json").write_text(json.dumps(metrics))
    assert _verdict(write_report(job).read_text())[1] == "Not ready: right rho 0.750 below 0.76"


def test_a_rho_just_below_min_rho_never_reads_as_reaching_it(tmp_path):
    """Rounded, 0.7996 read '0.800 below 0.8'; rounded down as verify's gate says it."""
    job = fake_job(tmp_path, rho=(0.91234, 0.7996))
    verdict, head, lines = _verdict(write_report(job, min_rho=0.8).read_text())
    assert verdict == "not-ready" and "right rho 0.799 below 0.8" in head
    assert any(
        text.startswith("✘ no right looks like its target: rho_kk 0.799 < 0.8") for _, text in lines
    )
    _, _, lines = _verdict(write_report(job, min_rho=0.79955).read_text())
    assert any("rho_kk 0.79960 ≥ 0.79955" in text for _, text in lines)


def test_min_rho_minus_one_marks_no_view_as_passing(tmp_path):
    """-1 turns the gate off: a view that shows nothing gets no tick, only its figure."""
    job = fake_job(tmp_path, rho=(0.91234, -0.072))
    _, _, lines = _verdict(write_report(job, min_rho=-1.0).read_text())
    right = [(status, text) for status, text in lines if "right looks like" in text]
    assert right == [
        (
            "info",
            "ℹ info right looks like its target: rho_kk -0.072 (1 = perfect; min_rho -1: no gate)",
        )
    ]


def test_an_ungated_rho_is_rounded_down_as_verify_shows_it(tmp_path):
    """With the gate off (or none set) the report's rho still reads as verify's line reads
    it (rounded down: 0.7996 is 0.799 there), not rounded to 0.800."""
    job = fake_job(tmp_path, rho=(0.91234, 0.7996))
    for min_rho, why in ((-1.0, "min_rho -1: no gate"), (None, "no min_rho set")):
        _, _, lines = _verdict(write_report(job, min_rho=min_rho).read_text())
        right = [text for _, text in lines if "right looks like" in text]
        assert right == [f"ℹ info right looks like its target: rho_kk 0.799 (1 = perfect; {why})"]


def _steps(page: str) -> list[str]:
    """The numbered next steps, as text."""
    steps = re.search(r"<ol data-next='[\w-]+'>(.*?)</ol>", page)
    assert steps, page[:2000]
    return [_text(s) for s in re.findall(r"<li>(.*?)</li>", steps.group(1))]


def test_a_view_short_where_the_bare_board_glints_is_told_the_glint_not_more_steps(tmp_path):
    """Where design found the bare board glinting into a failing view, more iterations or
    scratches cannot help (the glint outshines the image): the verdict names the glint and
    the next step says to move the camera or the light. A failing view without glint keeps
    the usual advice."""
    job = fake_job(tmp_path, rho=(-0.06, 0.5))
    path = job / "design" / "feasibility.json"
    feasibility = json.loads(path.read_text())
    share = 0.035699
    feasibility["views"] = {
        "left": {"glint_fraction": share, "reachable_fraction": 0.91},
        "right": {"glint_fraction": 0.0, "reachable_fraction": 1.0},
    }
    path.write_text(json.dumps(feasibility))
    page = write_report(job, min_rho=0.8).read_text()
    _, head, lines = _verdict(page)
    said = (
        f"; the bare board glints into left (design warned; on {100 * share:.1f}% of the "
        "board): no scratch shows the image there and the glint outshines the rest, so "
        "optimizing longer does not help: move the camera or the light as design's warning "
        "says"
    )
    assert "left rho -0.060 below 0.8 (the bare board outshines its grooves)" in head
    assert "right rho 0.500 below 0.8;" in head + ";" and head.count("outshines") == 1
    left = [t for _, t in lines if "left looks like" in t]
    assert left == [
        f"✘ no left looks like its target: rho_kk -0.060 < 0.8 ([verify] min_rho; "
        f"1 = perfect){said}"
    ]
    steps = _steps(page)
    glint = [s for s in steps if s.startswith("The bare board outshines")]
    assert len(glint) == 1 and "does not help" in glint[0]
    assert sum("run optimize longer" in s for s in steps) == 1  # right's, once
    # Only the glinting view failing: no step sends anyone to optimize longer.
    job2 = fake_job(tmp_path / "two", rho=(-0.06, 0.9))
    (job2 / "design" / "feasibility.json").write_text(json.dumps(feasibility))
    steps = _steps(write_report(job2, min_rho=0.8).read_text())
    assert not any("run optimize longer" in s for s in steps)
    assert any(s.startswith("The bare board outshines") for s in steps)


def test_a_view_short_where_design_warned_of_the_glints_shoulder_is_told_the_count(tmp_path):
    """A maker's case: a speck of glint (0.1 %) beside a warned shoulder (17 %): the
    verdict names the shoulder, its share and design's count, not the glint's 'move the
    camera or the light'; a view whose shoulder is under the warn share and whose glint is
    not a speck keeps the glint's words; a glint at the warn share is named beside the
    shoulder."""
    from scratchfab.design.feasibility import SHOULDER_WARN_FRACTION

    job = fake_job(tmp_path, rho=(0.257, 0.3))
    path = job / "design" / "feasibility.json"
    feasibility = json.loads(path.read_text())
    below = SHOULDER_WARN_FRACTION / 2
    feasibility.update(shoulder_count=14233, groove_coverage=0.0412)
    feasibility["views"] = {
        "left": {"glint_fraction": 0.001, "shoulder_fraction": 0.17},
        "right": {"glint_fraction": 0.001, "shoulder_fraction": below},
    }
    path.write_text(json.dumps(feasibility))
    _, head, lines = _verdict(write_report(job, min_rho=0.8).read_text())
    left = next(t for _, t in lines if "left looks like" in t)
    assert (
        "; past the glint the bare board still outshines the sparse grooves at groove "
        "coverage 0.04 (the glint's shoulder; design warned): left on 17.0% of the board; "
        "optimizing longer does not help, more scratches do: [scratch] count = 14233 "
        "or more" in left
    )
    assert "glints into" not in left
    right = next(t for _, t in lines if "right looks like" in t)
    assert "the bare board glints into right (design warned; on 0.1% of the board)" in right
    assert "shoulder" not in right
    # A glint at the warn share matters beside a shoulder: both are named.
    feasibility["views"]["left"]["glint_fraction"] = SHOULDER_WARN_FRACTION
    feasibility["shoulder_count"] = None
    path.write_text(json.dumps(feasibility))
    _, _, lines = _verdict(write_report(job, min_rho=0.8).read_text())
    left = next(t for _, t in lines if "left looks like" in t)
    assert "no scratch count clears it: move the cameras or the light" in left
    assert f"glints into left (design warned; on {100 * SHOULDER_WARN_FRACTION:.1f}%" in left


def test_optimization_section_says_which_views_glint_was_left_out(tmp_path):
    """summary.json's glint_left_out (optimize left the glint out of its image error) is
    said in the Optimization section, views in the design's order, with the share of the
    board; a summary without it (or with none left out) says nothing of glint."""
    job = fake_job(tmp_path)
    summary = {"iterations": 60, "stopped": "done", "elapsed_s": 3.0, "scratches": 2000}
    path = job / "optimize" / "summary.json"
    path.write_text(json.dumps(summary))
    assert "data-glint-left-out" not in write_report(job).read_text()
    path.write_text(json.dumps({**summary, "glint_left_out": {}}))
    assert "data-glint-left-out" not in write_report(job).read_text()
    left_out = {"left": 0.0123, "right": 0.25}
    path.write_text(json.dumps({**summary, "glint_left_out": left_out}))
    page = write_report(job).read_text()
    found = re.search(r"<p data-glint-left-out='(\d+)'>(.*?)</p>", page)
    assert found and found.group(1) == str(len(left_out))
    text = _text(found.group(2))
    listed = ", ".join(f"{n} ({100 * left_out[n]:.1f}% of the board)" for n in PLACES)
    assert text.startswith(f"The bare board glints into views {listed}: ")
    assert "left those pixels out of its image error" in text and "verify's count" in text
    path.write_text(json.dumps({**summary, "glint_left_out": {"left": 0.5}}))
    found = re.search(r"<p data-glint-left-out='1'>(.*?)</p>", write_report(job).read_text())
    assert found and _text(found.group(1)).startswith("The bare board glints into view left (50.0%")


def test_difference_map_caption_says_the_outline_where_verify_found_glint(tmp_path):
    """verify outlines the glint on a view's map (metrics.json's glint_share > 0): that
    view's caption says what the outline means; the other view's and a map without glint
    (or from before glint_share) do not."""
    job = fake_job(tmp_path)
    for name in PLACES:
        _png(job / "verify" / "diff" / f"{name}.png", 30)
    path = job / "verify" / "metrics.json"
    metrics = json.loads(path.read_text())
    outline = "a purple outline marks where the bare board glints"

    def captions() -> dict[str, str]:
        page = write_report(job).read_text()
        found = re.findall(
            r'<img alt="(\w+) difference map".*?<figcaption>(.*?)</figcaption>', page
        )
        return {name: _text(text) for name, text in found}

    assert not any(outline in c for c in captions().values())  # an older metrics.json
    metrics["views"]["left"]["glint_share"] = 0.036
    metrics["views"]["right"]["glint_share"] = 0.0
    path.write_text(json.dumps(metrics))
    said = captions()
    assert set(said) == set(PLACES)
    assert outline in said["left"] and "the rest reads darker" in said["left"]
    assert outline not in said["right"]


def test_verdict_not_ready_on_feasibility_errors_envelope_and_missing_stages(tmp_path):
    job = fake_job(tmp_path)
    feasibility = json.loads((job / "design" / "feasibility.json").read_text())
    feasibility["errors"] = ["views 'left' and 'right' are indistinguishable"]
    feasibility["warnings"] = ["view 'left' is steep"]
    (job / "design" / "feasibility.json").write_text(json.dumps(feasibility))
    data = json.loads((job / "toolpath" / "toolpath.json").read_text())
    data["statistics"].update(outside_count=3, clipped_count=2)
    (job / "toolpath" / "toolpath.json").write_text(json.dumps(data))
    (job / "export" / "board.gcode").unlink()
    _, head, lines = _verdict(write_report(job).read_text())
    assert head == (
        "Not ready: feasibility error; 5 of 2000 scratches left out or clipped; no G-code yet"
    )
    assert ("fail", "✘ no feasibility: views 'left' and 'right' are indistinguishable") in lines
    assert ("warn", "⚠ check feasibility: view 'left' is steep") in lines
    assert any(s == "fail" and "3 of 2000 scratches lie outside" in t for s, t in lines)


def test_stream_wording_follows_the_pipeline_port_and_the_journal(tmp_path):
    job = fake_job(tmp_path)

    def report(port: str | None) -> tuple[str, str, str]:
        page = write_report(job, port=port).read_text()
        steps = re.search(r"<ol data-next='([\w-]+)'>(.*?)</ol>", page)
        stream = re.search(r"<h2>Stream</h2>(.*?)</body>", page)
        assert steps and stream
        return steps.group(1), _text(steps.group(2)), _text(stream.group(1))

    kind, steps, stream = report("grblsim://?time_scale=0")
    assert (kind, stream) == ("not-streamed", "not streamed.")
    assert "--check" in steps
    lines = _journal(job, acked=len(GCODE.splitlines()), finished=True)
    kind, steps, stream = report("grblsim://?time_scale=0.001")
    assert kind == "emulator"
    assert "Streamed to the built-in GRBL emulator: nothing was cut." in stream
    assert f"{lines} of {lines} G-code lines acknowledged by the emulator" in stream
    assert "nothing was cut yet" in steps and "--check" in steps
    assert "streamed to the built-in GRBL emulator (to the end): nothing was cut" in (
        " ".join(t for _, t in _verdict(write_report(job, port="grblsim://").read_text())[2])
    )
    kind, steps, stream = report("/dev/ttyUSB0")
    assert kind == "cut" and "nothing was cut" not in stream + steps
    assert "Streamed to the machine on /dev/ttyUSB0" in stream and "finished" in stream
    assert "The board is cut" in steps and "--from stream" in steps
    _journal(job, acked=4, finished=False)
    kind, steps, stream = report("/dev/ttyUSB0")
    assert kind == "resume" and f"4 of {lines} G-code lines" in stream
    assert "unfinished (the next run resumes it)" in stream
    assert f"stopped after 4 of {lines} lines" in steps and "recut_unsure" in steps
    # A journal of another G-code says nothing about this one.
    _journal(job, acked=2, finished=True, gcode=b"G0 X9\n")
    kind, _, stream = report("/dev/ttyUSB0")
    assert kind == "not-streamed" and "earlier G-code" in stream


def test_the_port_the_journal_names_beats_the_pipelines(tmp_path):
    """Streamed by hand to the emulator, then the pipeline named a real port: not cut."""
    job = fake_job(tmp_path)
    _journal(job, acked=3, finished=True, port="grblsim://?time_scale=0.01")
    page = write_report(job, port="/dev/ttyUSB0").read_text()
    assert "data-stream='emulator'" in page and "nothing was cut" in page
    _journal(job, acked=3, finished=True, port="/dev/ttyACM0")
    page = write_report(job, port=None).read_text()
    assert "Streamed to the machine on <code>/dev/ttyACM0</code>" in page


def test_stand_here_sentence_from_the_design_positions(tmp_path):
    job = fake_job(tmp_path)
    page = write_report(job).read_text()
    section = re.search(r"<h2>Where to stand</h2>(.*?)<h2>", page)
    assert section
    items = re.findall(r"<li data-stand='(\w+)'[^>]*>(.*?)</li>", section.group(1))
    assert [name for name, _ in items] == list(PLACES)  # the design's order
    for name, text in items:
        azimuth, elevation, distance = PLACES[name]
        side = "left" if azimuth < 0 else "right"
        updown = "above" if elevation > 0 else "below"
        assert _text(text) == (
            f"{name}: stand {abs(azimuth):.0f}° to the {side} of the board’s front, "
            f"{abs(elevation):.0f}° {updown} its centre, {distance / 10:.0f} cm away; "
            f"light straight in front of the board, {LIGHT[1]:.0f}° above its centre, "
            f"{LIGHT[2] / 10:.0f} cm away."
        )


def test_a_view_with_its_own_light_is_told_that_light(tmp_path):
    job = fake_job(tmp_path)
    design = job / "design" / "design.toml"
    name = next(iter(PLACES))
    own = (35.0, 10.0, 800.0)  # azimuth, elevation, distance
    design.write_text(
        design.read_text().replace(
            f'name = "{name}"\n',
            f'name = "{name}"\nlight_position_mm = {_vec(_cartesian(*own))}\n',
        )
    )
    page = write_report(job).read_text()
    stands = dict(re.findall(r"<li data-stand='(\w+)'[^>]*>(.*?)</li>", page))
    assert "light 35° to the right of the board, 10° above its centre, 80 cm away" in _text(
        stands[name]
    )
    other = next(n for n in PLACES if n != name)
    assert f"light straight in front of the board, {LIGHT[1]:.0f}° above" in _text(stands[other])


def test_a_view_straight_in_front_says_so_once(tmp_path):
    job = fake_job(tmp_path)
    design = job / "design" / "design.toml"
    ahead = (0.3, 4.0, 450.0)  # azimuth rounds to 0°
    name, place = next(iter(PLACES.items()))
    design.write_text(
        design.read_text().replace(_vec(_cartesian(*place)), _vec(_cartesian(*ahead)))
    )
    stands = dict(
        re.findall(r"<li data-stand='(\w+)'[^>]*>(.*?)</li>", write_report(job).read_text())
    )
    assert _text(stands[name]).startswith(
        f"{name}: stand straight in front of the board, 4° above its centre, 45 cm away; "
    )


def test_views_follow_the_design_order_everywhere(tmp_path):
    job = fake_job(tmp_path)
    page = write_report(job).read_text()
    order = list(PLACES)  # right, left: metrics.json and the folders list left first
    headings = re.findall(r"<h3>view (\w+)</h3>", page)
    assert headings == order
    rows = re.findall(r'data-metric="(\w+)\.rho"', page)
    assert rows == order
    checks = re.findall(r"(\w+) looks like its target: rho_kk", page)
    assert checks == order


def test_plain_labels_links_and_captions(tmp_path):
    job = fake_job(tmp_path)
    page = write_report(job, pipeline_file=tmp_path / "board.toml").read_text()
    stats = json.loads((job / "toolpath" / "toolpath.json").read_text())["statistics"]
    table = dict(
        re.findall(r"<td data-stat='toolpath\.(\w+)' data-value='[^']*'>([^<]*)</td>", page)
    )
    assert table["cut_length_mm"] == f"{stats['cut_length_mm'] / 1000:.2f} m"
    assert table["travel_length_mm"] == f"{stats['travel_length_mm'] / 1000:.2f} m"
    assert table["estimated_time_s"] == "1 h 23 min"  # 5009 s
    rel = re.search(r'data-metric="left.rel_l2" data-value="([^"]+)">([^<]*)<', page)
    assert rel and rel.group(2) == f"{100 * float(rel.group(1)):.2f} %"
    # No raw keys of log.csv or toolpath.json as labels.
    for raw in ("rho_left", "x_left_right", "psnr_right", "cut_length_mm", "rel. L2 vs"):
        assert f">{raw}<" not in page
    # Relative links to the files a maker takes away; each points at an existing file.
    links = re.findall(r"<a href='([^']+)'>", page)
    for wanted in (
        "export/board.gcode",
        "export/board.svg",
        "optimize/scratches.csv",
        "verify/metrics.json",
    ):
        assert wanted in links
    assert all((job / link).is_file() for link in links)
    assert "export/board.dxf" not in page  # not exported
    # Commands work from the job folder.
    assert "scratchfab run ../board.toml --out ." in page
    assert "scratchfab stream export/board.gcode --port PORT --check" in page
    # One caption per figure.
    assert page.count("<figure") == page.count("<figcaption>")
    assert page.count("<img") == len(re.findall(r"<figure[^>]*><img", page))


def test_walk_past_and_sun_and_sky_headings(tmp_path):
    job = fake_job(tmp_path)
    page = write_report(job).read_text()
    assert "Beyond the design light" not in page and "Under sun and sky" not in page
    walk = re.search(r"<h2>Walking past the board</h2>(.*?)<h2>", page)
    gif = base64.b64encode((job / "verify" / "sweep.gif").read_bytes()).decode()
    assert walk and f"data:image/gif;base64,{gif}" in walk.group(1)
    for i, name in enumerate(PLACES):
        _png(job / "verify" / "sky" / f"{name}.png", 40 + i)
    page = write_report(job).read_text()
    sky = re.search(r"<h2>Under sun and sky</h2>(.*?)<h2>", page)
    assert sky
    shown = re.findall(
        r'alt="(\w+) under sun and sky" src="data:image/png;base64,([^"]+)"', sky.group(1)
    )
    assert [name for name, _ in shown] == list(PLACES)
    for name, data in shown:
        assert base64.b64decode(data) == (job / "verify" / "sky" / f"{name}.png").read_bytes()


def test_walk_past_caption_names_its_ends_as_the_stand_list_does(tmp_path):
    job = fake_job(tmp_path)
    metrics_file = job / "verify" / "metrics.json"
    metrics = json.loads(metrics_file.read_text())
    ends = [(-40.0, 5.0, 500.0), (0.2, 5.0, 500.0)]  # azimuths -40° and (rounded) 0°
    metrics["sweep"] = {"cameras": [{"position_mm": _cartesian(*end)} for end in ends]}
    metrics_file.write_text(json.dumps(metrics))
    page = write_report(job).read_text()
    walk = re.search(r"<h2>Walking past the board</h2>(.*?)<h2>", page)
    assert walk
    assert "from 40° to the left to straight in front of the board's front" in _text(walk.group(1))
    stands = dict(re.findall(r"<li data-stand='(\w+)'[^>]*>(.*?)</li>", page))
    assert "stand 15° to the left of the board’s front" in _text(stands["left"])


@pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (.ci/run installs it)"
)
def test_report_images_decode_in_headless_chromium(tmp_path):
    job = fake_job(tmp_path)
    shown = check_report_in_chromium(write_report(job), tmp_path / "profile")
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    for view, entry in metrics["views"].items():
        assert float(shown[f"{view}.rho"]) == pytest.approx(entry["rho"], abs=5e-4)
        assert float(shown[f"{view}.psnr"]) == pytest.approx(entry["psnr"], abs=5e-3)


def test_manifest_detects_changes_not_touches(tmp_path):
    src = tmp_path / "cat.png"
    _png(src, 1)
    made = tmp_path / "job" / "design" / "scratches.csv"
    made.parent.mkdir(parents=True)
    made.write_text("x0,y0,x1,y1\n")
    manifest = Manifest.load(tmp_path / "job")
    inputs = fingerprint([made], {"target:cat": src}, {"seed": 1})
    assert not manifest.is_current("design", inputs)
    manifest.record("design", inputs, ["design/scratches.csv"], 0.1)
    again = Manifest.load(tmp_path / "job")
    assert again.is_current("design", fingerprint([made], {"target:cat": src}, {"seed": 1}))
    assert not again.is_current("design", fingerprint([made], {"target:cat": src}, {"seed": 2}))
    made.write_text("x0,y0,x1,y1\n0,0,1,1\n")
    assert not again.is_current("design", fingerprint([made], {"target:cat": src}, {"seed": 1}))
    made.write_text("x0,y0,x1,y1\n")
    import os

    st = src.stat()
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # touched, same bytes
    assert again.is_current("design", fingerprint([made], {"target:cat": src}, {"seed": 1}))
    _png(src, 2)  # other bytes
    assert not again.is_current("design", fingerprint([made], {"target:cat": src}, {"seed": 1}))


def test_verdict_names_a_failed_stage_from_the_manifest(tmp_path):
    job = fake_job(tmp_path)
    reason = "view right looks like its target only to rho 0.700, below min_rho 0.8"
    stages = {
        "design": {"status": "done"},
        "verify": {"status": "failed", "reason": reason},
        "stream": {"status": "interrupted", "reason": "stopped"},
    }
    (job / "manifest.json").write_text(json.dumps({"stages": stages}))
    _, head, lines = _verdict(write_report(job).read_text())
    # the stream's state is its own line
    assert head == "Not ready: stage verify failed; the stream was interrupted"
    assert any(s == "fail" and reason in t for s, t in lines)


@pytest.mark.parametrize(
    ("status", "words"),
    [("failed", "failed"), ("interrupted", "was interrupted"), ("running", "did not finish")],
)
def test_a_stage_that_did_not_finish_reads_as_the_answer_to_a_claim(tmp_path, status, words):
    """Under "✘ no" the line states what should hold, as every other line does.

    "✘ no stage verify failed" read as "no stage failed"; a stage a kill left "running"
    was reported as running after the run had ended.
    """
    job = fake_job(tmp_path)
    stages = {"design": {"status": "done"}, "toolpath": {"status": status}}
    (job / "manifest.json").write_text(json.dumps({"stages": stages}))
    _, head, lines = _verdict(write_report(job).read_text())
    assert head == f"Not ready: stage toolpath {words}"
    assert (
        "fail",
        f"✘ no every stage finished: stage toolpath {words} "
        "(files after it may be from an earlier run)",
    ) in lines


def test_views_line_before_verify_names_its_subject(tmp_path):
    job = fake_job(tmp_path)
    (job / "verify" / "metrics.json").unlink()
    _, _, lines = _verdict(write_report(job).read_text())
    assert ("fail", "✘ no the views look like their targets: verify has not run") in lines


def test_rerun_command_names_the_pipeline_even_across_windows_drives(tmp_path, monkeypatch):
    job = fake_job(tmp_path)
    pipeline = tmp_path / "board.toml"
    page = write_report(job, pipeline_file=pipeline).read_text()
    assert "scratchfab run ../board.toml --out ." in page

    def other_drive(path, start):
        raise ValueError("path is on mount 'C:', start on mount 'D:'")

    monkeypatch.setattr("scratchfab.pipeline.report.os.path.relpath", other_drive)
    page = write_report(job, pipeline_file=pipeline).read_text()
    assert f"scratchfab run {pipeline.resolve()} --out ." in page


@pytest.mark.skipif(os.name == "nt", reason="the POSIX shell's quoting")
def test_commands_paste_back_as_the_same_arguments(tmp_path):
    job = fake_job(tmp_path)
    folder = tmp_path / "p dir $(touch PWNED)'q"
    folder.mkdir()
    pipeline = folder / 'a "b" `touch PWNED2`.toml'
    page = write_report(job, pipeline_file=pipeline).read_text()
    commands = [
        html.unescape(c)
        for c in re.findall(r"<code>([^<]*)</code>", page)
        if c.startswith("scratchfab run")
    ]
    assert commands
    for command in commands:
        words = shlex.split(command)  # an independent reader of the quoting
        assert words[:2] == ["scratchfab", "run"] and words[3:5] == ["--out", "."]
        assert words[5:] in ([], ["--from", "stream"])
        assert (job / words[2]).resolve() == pipeline.resolve()
        assert pasted_words(command, job) == words  # and the shell agrees
    assert not list(tmp_path.rglob("PWNED*"))  # nothing ran


def _windows_argv(line: str) -> list[str]:
    """``line`` split as the Microsoft C runtime splits a command line (its documented rules).

    Whitespace separates arguments outside double quotes; 2n backslashes before a quote
    give n and the quote toggles quoting, 2n+1 give n and a literal quote; other
    backslashes are literal.
    """
    args: list[str] = []
    word: list[str] = []
    quoted = started = False
    i = 0
    while i < len(line):
        c = line[i]
        if c == "\\":
            n = len(line[i:]) - len(line[i:].lstrip("\\"))
            i += n
            if line[i : i + 1] == '"':
                word += "\\" * (n // 2)
                if n % 2:
                    word.append('"')
                    i += 1
            else:
                word += "\\" * n
            started = True
            continue
        if c == '"':
            quoted, started = not quoted, True
        elif c in " \t" and not quoted:
            if started:
                args.append("".join(word))
            word, started = [], False
        else:
            word.append(c)
            started = True
        i += 1
    if started:
        args.append("".join(word))
    return args


def test_commands_for_windows_split_back_into_the_same_arguments(monkeypatch):
    from scratchfab.console import command_line

    args = [
        "scratchfab",
        "run",
        r"C:\p dir $(touch PWNED)'q\a \"b\" c\\",
        "",
        'say "hi"',
        "tab\there",
        "--out",
        ".",
    ]
    with monkeypatch.context() as patch:
        patch.setattr(os, "name", "nt")
        line = command_line(args)
    assert _windows_argv(line) == args
    posix = command_line(args)
    assert shlex.split(posix) == args  # and here, the POSIX form
    assert _windows_argv(posix) != args  # which Windows would read otherwise


def test_log_keeps_a_perfect_psnr_and_an_undefined_rho_apart(tmp_path: Path) -> None:
    """A black target's view: PSNR is +inf (no error at exposure 0), rho undefined (NaN).

    log.csv wrote both as "nan"; read back by a second reader (csv + float) they must stay
    what they were, and the report's last-iteration table must show them differently.
    """
    import csv
    import math

    from scratchfab.optimize.stage import _write_log, log_columns
    from scratchfab.pipeline.report import _last_iteration

    names = ["a", "b"]
    columns = log_columns(names)
    row = [3.0, 0.25, 1.5, math.inf, math.nan, 0.125, 21.5, 0.75, math.nan]
    assert len(row) == len(columns)
    path = tmp_path / "log.csv"
    _write_log(path, columns, [row])
    with path.open(encoding="utf-8") as handle:
        back = list(csv.DictReader(handle))[-1]
    for key, value in zip(columns[1:], row[1:], strict=True):
        got = float(back[key])
        assert got == value or (math.isnan(got) and math.isnan(value)), key
    table = _last_iteration(back, names)
    cells = re.findall(r"<th scope='row'>(\w)</th>(.*?)</tr>", table)
    assert cells[0] == ("a", "<td>–</td><td>∞</td><td>0.125</td>")
    assert cells[1] == ("b", "<td>0.750</td><td>21.50</td><td>–</td>")
