from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
from collections import Counter
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import CHROMIUM, check_report_in_chromium, write_pipeline

from scratchfab.cli import main
from scratchfab.errors import ScratchfabError
from scratchfab.pipeline.config import STAGES, load_pipeline
from scratchfab.pipeline.manifest import Manifest
from scratchfab.pipeline.runner import run_pipeline


@pytest.fixture(scope="module")
def toml_reads():
    """File name -> how often the run of ``finished_job`` read it as TOML."""
    return Counter()


@pytest.fixture(scope="module")
def said():
    """The lines the run of ``finished_job`` said."""
    return []


@pytest.fixture(scope="module")
def finished_job(tmp_path_factory, toml_reads, said):
    import scratchfab.model.schema as schema

    folder = tmp_path_factory.mktemp("pipe")
    path = write_pipeline(folder)
    job = folder / "job"
    real = schema.read_input

    def spy(file, *args, **kwargs):
        toml_reads[Path(file).name] += 1
        return real(file, *args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(schema, "read_input", spy)  # every TOML file is read by load_toml
        result = run_pipeline(load_pipeline(path), job, say=said.append)
    return path, job, result


@contextlib.contextmanager
def _edited(path: Path, old: str, new: str) -> Iterator[None]:
    """The shared pipeline file with ``old`` replaced by ``new`` for a while, then restored."""
    text = path.read_text()
    path.write_text(text.replace(old, new))
    try:
        yield
    finally:
        path.write_text(text)


def test_run_produces_every_stage_output(finished_job):
    _, job, result = finished_job
    assert result.ran == ["design", "optimize", "verify", "toolpath", "export", "stream"]
    for rel in (
        "design/design.toml",
        "optimize/scratches.csv",
        "verify/metrics.json",
        "toolpath/toolpath.json",
        "export/board.gcode",
        "export/board.svg",
        "stream/journal.jsonl",
        "report.html",
        "manifest.json",
    ):
        assert (job / rel).is_file(), rel
    # Every G-code line that carries a command was acknowledged exactly once, in order
    # (comment-only and blank lines are not sent).
    code_lines = [
        n
        for n, ln in enumerate((job / "export" / "board.gcode").read_text().splitlines(), 1)
        if re.sub(r"\(.*?\)|;.*", "", ln).strip()
    ]
    journal = [json.loads(ln) for ln in (job / "stream" / "journal.jsonl").read_text().splitlines()]
    acked = [e["line"] for e in journal if e["ev"] == "ack"]
    assert acked == code_lines
    assert journal[-1]["ev"] == "end"
    report = (job / "report.html").read_text()
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    for name, view in metrics["views"].items():
        assert f'data-metric="{name}.rho" data-value="{view["rho"]}"' in report


def test_one_run_reads_the_pipeline_file_and_the_profile_once(finished_job, toml_reads):
    _, _, result = finished_job
    assert len(result.ran) == len(STAGES)  # each stage ran, toolpath and stream included
    assert toml_reads["tiny.toml"] == 1
    assert toml_reads["grbl-3018-diamond.toml"] == 1


def test_optimize_progress_is_indented_under_its_stage(finished_job, said):
    first = said.index("[optimize] running")
    last = next(i for i, line in enumerate(said) if line.startswith("[optimize] done"))
    lines = said[first + 1 : last]
    assert lines[0] == "  compiling kernels..." and "  writing outputs..." in lines
    assert re.fullmatch(r"  \[#{30}\] 4/4 loss \d\.\d{5}  elapsed \S+  eta 00:00", lines[-2])


def test_every_stages_lines_are_indented_under_it(finished_job, said):
    """What a stage says sits under its ``[stage] running``, as optimize's progress does."""
    stage = None
    seen = set()
    for line in said:
        if match := re.fullmatch(r"\[(\w+)\] running", line):
            stage = match.group(1)
        elif line.startswith(f"[{stage}] done"):
            stage = None
        elif stage is not None:
            assert line.startswith("  "), (stage, line)
            seen.add(stage)
    assert seen == set(STAGES)  # each stage said something (design's header included)


@pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (.ci/run installs it)"
)
def test_report_of_a_real_run_loads_in_chromium(finished_job, tmp_path):
    _, job, _ = finished_job
    shown = check_report_in_chromium(job / "report.html", tmp_path / "profile")
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    for name, view in metrics["views"].items():
        assert float(shown[f"{name}.rho"]) == pytest.approx(view["rho"], abs=5e-4)
        for other, x in view["crosstalk"].items():
            assert float(shown[f"{name}.crosstalk.{other}"]) == pytest.approx(x, abs=5e-4)


def test_rerun_skips_everything_then_a_changed_target_reruns_downstream(finished_job):
    from PIL import Image

    path, job, _ = finished_job
    again = run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert again.ran == [] and again.skipped == list(STAGES)  # no timing: skipped stages
    gcode = (job / "export" / "board.gcode").read_bytes()
    journal = (job / "stream" / "journal.jsonl").read_bytes()
    bar = path.parent / "bar.png"
    st = bar.stat()
    os.utime(bar, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # a copy's new time: no change
    touched = run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert touched.ran == [] and touched.skipped == list(STAGES)
    before = bar.read_bytes()
    with Image.open(bar) as image:  # other bytes (a text chunk), the same picture
        from PIL.PngImagePlugin import PngInfo

        info = PngInfo()
        info.add_text("Comment", "saved again")
        image.save(bar, pnginfo=info)
    assert bar.read_bytes() != before
    said = []
    changed = run_pipeline(load_pipeline(path), job, say=said.append)  # up to date after it
    assert changed.ran == ["design", "optimize", "verify", "toolpath", "export"]
    # The same board again, byte for byte, streamed to the end before: not cut twice.
    assert (job / "export" / "board.gcode").read_bytes() == gcode
    assert changed.skipped == ["stream"]
    assert (job / "stream" / "journal.jsonl").read_bytes() == journal
    (line,) = [s for s in said if s.startswith("[stream]")]
    assert str(job / "export" / "board.gcode") in line and "--from stream" in line


def test_moved_job_is_still_up_to_date(finished_job, tmp_path, monkeypatch):
    path, job, _ = finished_job
    moved = tmp_path / "elsewhere"
    shutil.copytree(job, moved)
    monkeypatch.chdir(tmp_path)  # named by a relative path from another folder
    result = run_pipeline(load_pipeline(path), Path("elsewhere"), say=lambda s: None)
    assert result.ran == []


def test_moved_job_reads_its_own_board_pictures(finished_job, tmp_path):
    import numpy as np

    from scratchfab.design.targets import cross_targets, job_cross_targets
    from scratchfab.model.design import load_design
    from scratchfab.optimize.stage import load_job_inputs
    from scratchfab.verify.verify import load_job_targets

    _, job, _ = finished_job
    moved = tmp_path / "moved"
    shutil.copytree(job, moved)
    toml = moved / "design" / "design.toml"
    # as if the job had been moved: the recorded absolute paths lead nowhere
    toml.write_text(toml.read_text().replace(str(job.resolve()), str(tmp_path / "gone")))
    stale = load_design(toml)
    assert not any(stale.target_path(v).exists() for v in stale.views)
    expected = cross_targets(load_design(job / "design" / "design.toml"))
    assert len(expected) == 4  # two views: every pair

    design, _, _ = load_job_inputs(moved)
    assert all(
        Path(v.target).parent == (moved / "design" / "board").resolve() for v in design.views
    )
    for cross in (job_cross_targets(design), load_job_targets(moved, design)[1]):
        assert cross is not None and set(cross) == set(expected)
        for key, image in expected.items():
            assert np.array_equal(cross[key], image, equal_nan=True)


def test_job_without_board_pictures_falls_back_to_its_view_targets(finished_job, tmp_path):
    import numpy as np

    from scratchfab.design.targets import job_cross_targets
    from scratchfab.optimize.stage import load_job_inputs
    from scratchfab.verify.verify import load_job_targets

    _, job, _ = finished_job
    moved = tmp_path / "no-pictures"
    shutil.copytree(job, moved)
    pictures = sorted((moved / "design" / "board").glob("*.png"))
    assert pictures
    pictures[0].write_bytes(b"not a picture")  # broken
    for picture in pictures[1:]:
        picture.unlink()  # gone

    design, targets, _ = load_job_inputs(moved)
    assert job_cross_targets(design) is None
    view_targets, cross = load_job_targets(moved, design)
    assert cross is None and set(view_targets) == set(targets) == {v.name for v in design.views}
    for name, image in targets.items():
        assert np.array_equal(view_targets[name], image, equal_nan=True)


def test_changed_option_reruns_only_downstream(finished_job):
    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)  # up to date after other tests
    journal = (job / "stream" / "journal.jsonl").read_bytes()
    with _edited(path, 'formats = ["gcode", "svg"]', 'formats = ["gcode", "svg", "dxf"]'):
        result = run_pipeline(load_pipeline(path), job, say=lambda s: None)
        assert result.ran == ["export"] and result.skipped[-1] == "stream"
        assert (job / "export" / "board.dxf").is_file()
        assert (job / "stream" / "journal.jsonl").read_bytes() == journal
    # The format left out again: its file goes, from the folder, the manifest and the report.
    result = run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert result.ran == ["export"]
    assert sorted(p.name for p in (job / "export").iterdir()) == ["board.gcode", "board.svg"]
    outputs = Manifest.load(job).stages["export"]["outputs"]
    assert outputs == ["export/board.gcode", "export/board.svg"]
    report = (job / "report.html").read_text()
    assert "board.svg" in report and "board.dxf" not in report


def test_upstream_option_change_does_not_stream_the_same_gcode_again(finished_job):
    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)
    gcode = (job / "export" / "board.gcode").read_bytes()
    journal = (job / "stream" / "journal.jsonl").read_bytes()
    with _edited(path, "[verify]\n", "[verify]\nseed = 3\n"):
        result = run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert result.ran == ["verify", "toolpath", "export"] and result.skipped[-1] == "stream"
    assert (job / "export" / "board.gcode").read_bytes() == gcode
    assert (job / "stream" / "journal.jsonl").read_bytes() == journal


def _fresh_starts(job):
    events = [json.loads(ln) for ln in (job / "stream" / "journal.jsonl").read_text().splitlines()]
    return [e for e in events if e["ev"] == "start" and not e["resume"]]


def _code_lines(gcode: Path) -> int:
    return sum(1 for ln in gcode.read_text().splitlines() if re.sub(r"\(.*?\)|;.*", "", ln).strip())


@pytest.mark.parametrize("how", ["force", "from"])
def test_force_or_from_stream_cuts_the_same_board_again(finished_job, monkeypatch, capsys, how):
    import io

    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)
    before = len(_fresh_starts(job))
    monkeypatch.setattr("sys.stdin", io.StringIO(""))  # the emulator never asks
    flags = ["--force"] if how == "force" else ["--from", "stream"]
    main(["run", str(path), "--out", str(job), *flags])
    out = capsys.readouterr().out
    assert "[stream] running" in out and "[stream] done" in out
    assert len(_fresh_starts(job)) == before + 1
    # The report counts the last fresh stream only, not every run in the journal.
    report = (job / "report.html").read_text()
    lines = _code_lines(job / "export" / "board.gcode")
    assert f"<span data-stat='stream.acknowledged'>{lines}</span> of " in report
    assert f"<span data-stat='stream.lines'>{lines}</span>" in report
    acks = (job / "stream" / "journal.jsonl").read_text().count('"ev":"ack"')
    assert acks >= 2 * lines and f">{acks}<" not in report


def test_changed_gcode_is_streamed_again(finished_job):
    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)
    gcode = (job / "export" / "board.gcode").read_bytes()
    before = len(_fresh_starts(job))
    with _edited(path, "[toolpath]\n", "[toolpath]\nseed = 11\npasses = 0\n"):
        result = run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert (job / "export" / "board.gcode").read_bytes() != gcode
    assert result.ran == ["toolpath", "export", "stream"]
    assert len(_fresh_starts(job)) == before + 1


def test_interrupted_stream_of_the_same_gcode_is_resumed(finished_job):
    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)
    journal = job / "stream" / "journal.jsonl"
    events = [json.loads(ln) for ln in journal.read_text().splitlines()]
    last = max(k for k, e in enumerate(events) if e["ev"] == "start")
    acks = [e for e in events[last:] if e["ev"] == "ack" and "i" in e][:40]
    # As if the host died mid-stream after a forced run: the manifest still says done.
    with journal.open("a") as handle:
        for event in [events[last], *acks]:
            handle.write(json.dumps(event) + "\n")
    result = run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert result.ran == ["stream"]
    after = [json.loads(ln) for ln in journal.read_text().splitlines()]
    resumed = max(k for k, e in enumerate(after) if e["ev"] == "start")
    assert after[resumed]["resume"] is True and after[-1]["ev"] == "end"
    first_i = next(e["i"] for e in after[resumed:] if e["ev"] == "ack" and "i" in e)
    assert 0 < first_i <= acks[-1]["i"] + 1


def test_report_counts_the_acknowledgements_of_a_killed_stream(finished_job, tmp_path):
    """A session with no closing event: every ack counts as acknowledged in the report."""
    from scratchfab.pipeline.report import write_report

    path, job, _ = finished_job
    copy = tmp_path / "job"
    shutil.copytree(job, copy)
    journal = copy / "stream" / "journal.jsonl"
    events = [json.loads(ln) for ln in journal.read_text().splitlines()]
    fresh = max(k for k, e in enumerate(events) if e["ev"] == "start" and not e["resume"])
    acks = [e for e in events[fresh:] if e["ev"] == "ack" and "i" in e][:40]
    with journal.open("a") as handle:  # the sender was killed after 40 acknowledgements
        for event in [events[fresh], *acks]:
            handle.write(json.dumps(event) + "\n")
    report = write_report(copy, "tiny").read_text()
    assert f"<span data-stat='stream.acknowledged'>{len(acks)}</span> of " in report
    assert "unfinished (the next run resumes it)" in report


def test_unfinished_stream_of_another_file_does_not_restream_the_board(finished_job):
    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)
    journal = job / "stream" / "journal.jsonl"
    events = [json.loads(ln) for ln in journal.read_text().splitlines()]
    start = dict(events[max(k for k, e in enumerate(events) if e["ev"] == "start")])
    # `scratchfab stream JOB/export/edited.gcode` journals here too, and was stopped.
    start.update(file=str(job / "export" / "edited.gcode"), sha256="0" * 64)
    with journal.open("a") as handle:
        handle.write(json.dumps(start) + "\n" + json.dumps({"ev": "ack", "i": 0, "line": 1}) + "\n")
    text = journal.read_bytes()
    result = run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert result.ran == [] and journal.read_bytes() == text


def test_report_setup_step_follows_the_readme_not_a_generic_zeroing(finished_job):
    from scratchfab.machine.profile import load_profile

    _, job, _ = finished_job
    report = (job / "report.html").read_text()
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    assert "5. **Cut.**" in readme and "do not zero the" in readme
    assert "zero the tool on its surface" not in report
    assert "README step 5" in report
    profile = load_profile("grbl-3018-diamond")
    x, y = profile.board.offset_mm
    assert f"<span data-stat='setup.x'>{x:g}</span>" in report
    assert f"<span data-stat='setup.y'>{y:g}</span>" in report
    assert f"<span data-stat='setup.z'>{profile.z.engrave_mm:g}</span>" in report


def _real_port_pipeline(path: Path, record: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The pipeline with a port of its own: the emulator, recording what it receives.

    A pipeline may not name a record file (it would overwrite it on every run), so the
    port the stream stage opens gets ``record=`` here, as ``stream --port`` would give it.
    """
    import scratchfab.machine.stream_job as stream_job

    real = path.with_name("real-port.toml")
    text = path.read_text()
    start = text.index('port = "grblsim')
    end = text.index('"', start + len('port = "'))
    real.write_text(text[:end] + "&latency=0" + text[end:])
    stream = stream_job.run_stream_job

    def recording(job: Path, port: str, **kwargs: object) -> object:
        return stream(job, port=f"{port}&record={record}", **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(stream_job, "run_stream_job", recording)
    return real


@pytest.mark.parametrize(
    ("flags", "answer", "refusal"),
    [
        ([], "", "no answer came to the question (stdin closed): answer y, or pass --yes"),
        ([], "n\n", "not confirmed; nothing was sent"),
        ([], "y\n", None),  # a terminal's answer, or a pipe's (echo y | scratchfab run)
        (["--yes"], "", None),
    ],
)
def test_real_port_asks_before_streaming(
    finished_job, tmp_path, monkeypatch, capsys, flags, answer, refusal
):
    import io
    import json

    import scratchfab.pipeline.runner as runner
    from scratchfab.machine.sender_program import load_program

    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)
    copy = tmp_path / "job"
    shutil.copytree(job, copy)
    journal = (copy / "stream" / "journal.jsonl").read_bytes()
    record = tmp_path / "received.jsonl"
    real = _real_port_pipeline(path, record, monkeypatch)
    monkeypatch.setattr(runner, "is_emulator", lambda port: False)  # as a real machine
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    monkeypatch.setattr("sys.stdin", io.StringIO(answer))
    code = 0
    try:
        main(["run", str(real), "--out", str(copy), *flags])
    except SystemExit as exc:
        code = exc.code
    finally:
        real.unlink()
    got = capsys.readouterr()
    assert code == (0 if refusal is None else 2)
    assert "Traceback" not in got.err
    # Every other stage was up to date; the stream stage connected and checked first.
    assert got.out.count("up to date, skipped") == len(STAGES) - 1
    assert "[stream] running" in got.out and "connected: Grbl" in got.out
    asked = "The machine moves: board clamped and set up as README step 5 says" in got.err
    assert asked == ("--yes" not in flags)
    events = [json.loads(line) for line in record.read_text().splitlines()]
    received = [e["text"] for e in events if e["ev"] == "rx" and e["g"]]
    after = (copy / "stream" / "journal.jsonl").read_bytes()
    if refusal is not None:
        assert refusal in got.err
        assert received == [] and after == journal  # nothing was sent
    else:
        program = load_program(copy / "export" / "board.gcode")
        blocks = [b.text.replace(" ", "") for b in program.blocks]
        # whole, in order; then the sender's G4P0, whose ok waits for the motion to end
        assert received == [*blocks, "G4P0"]
        assert after.startswith(journal) and len(after) > len(journal)


@pytest.mark.parametrize(
    ("flags", "answers", "refusal"),
    [
        (["--yes"], "", "refusing to cut a partial board with --yes: "),
        ([], "n\n", "not confirmed; nothing was sent"),
        ([], "y\ny\n", None),  # the partial board, then the usual question
    ],
)
def test_real_port_cuts_a_board_the_envelope_cuts_short_only_when_asked(
    tmp_path, monkeypatch, capsys, flags, answers, refusal
):
    """A board overhanging the envelope: --yes refuses it, a person is asked about it."""
    import io
    import json

    import scratchfab.pipeline.runner as runner
    from scratchfab.bundled import bundled_dir

    profile = (bundled_dir("machine_profiles") / "grbl-3018-diamond.toml").read_text()
    old = "offset_mm = [-220.0, -150.0]"
    assert old in profile
    (tmp_path / "overhang.toml").write_text(profile.replace(old, "offset_mm = [-15.0, -150.0]"))
    path = write_pipeline(
        tmp_path,
        edits={
            # plans the part it reaches
            'machine = "grbl-3018-diamond"': 'machine = "overhang.toml"\nforce = true',
        },
    )
    job = tmp_path / "job"
    main(["run", str(path), "--out", str(job), "--until", "export"])
    stats = json.loads((job / "toolpath" / "toolpath.json").read_text())["statistics"]
    assert stats["outside_count"] > 0 and stats["clipped_count"] > 0  # the x <= 0 half
    record = tmp_path / "received.jsonl"
    real = _real_port_pipeline(path, record, monkeypatch)
    monkeypatch.setattr(runner, "is_emulator", lambda port: False)  # as a real machine
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    monkeypatch.setattr("sys.stdin", io.StringIO(answers))
    capsys.readouterr()
    code = 0
    try:
        main(["run", str(real), "--out", str(job), *flags])
    except SystemExit as exc:
        code = exc.code
    got = capsys.readouterr()
    assert "Traceback" not in got.err
    received = record.read_text() if record.is_file() else ""
    if refusal is not None:
        assert code == 2 and refusal in got.err
        assert f"{stats['outside_count']} of {stats['input_count']} scratches" in got.err
        assert '"rx"' not in received and not (job / "stream" / "journal.jsonl").exists()
    else:
        assert code == 0 and "Cut a partial board?" in got.err
        assert '"rx"' in received and (job / "stream" / "journal.jsonl").is_file()


def test_pipeline_out_is_relative_to_the_pipeline_file(tmp_path, monkeypatch):
    folder = tmp_path / "boards"
    path = write_pipeline(folder)
    path.write_text(path.read_text().replace("[pipeline]\n", '[pipeline]\nout = "jobs/tiny"\n'))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    main(["run", str(path), "--until", "design"])
    assert (folder / "jobs" / "tiny" / "design" / "design.toml").is_file()
    assert list(elsewhere.iterdir()) == []
    main(["run", str(path), "--until", "design", "--out", "cli-job"])
    assert (elsewhere / "cli-job" / "design" / "design.toml").is_file()
    # The same rule for library callers: load_pipeline + Pipeline.job_dir.
    pipe = load_pipeline(Path("..") / "boards" / path.name)
    assert pipe.job_dir().resolve() == (folder / "jobs" / "tiny").resolve()
    assert pipe.job_dir(Path("cli-job")) == Path("cli-job")
    path.write_text(path.read_text().replace('out = "jobs/tiny"\n', ""))
    assert load_pipeline(path).job_dir() == Path(f"job-{path.stem}")  # in the current folder


def test_bundled_demo_runs_by_name_into_the_current_folder(tmp_path, monkeypatch, capsys):
    """`scratchfab run demo` finds the pipeline inside the package, as an installed one would."""
    from scratchfab.bundled import bundled_dir

    monkeypatch.chdir(tmp_path)
    pipe = load_pipeline("demo")
    assert pipe.path == (bundled_dir("pipelines") / "demo.toml").resolve()
    job = tmp_path / pipe.job_dir()
    assert pipe.job_dir() == Path(f"job-{pipe.path.stem}")  # here, not in the package
    main(["run", "demo", "--until", "design"])
    assert (job / "design" / "design.toml").is_file()
    assert {p.stem for p in (job / "design" / "targets").glob("*.npy")} == {
        "sun",
        "house",
    }
    # A wrong name lists the bundled ones, without a traceback.
    with pytest.raises(SystemExit) as exit_info:
        main(["run", "dmeo"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "pipeline 'dmeo': not a bundled pipeline (bundled: demo) nor a file" in err
    assert "Traceback" not in err


def test_recut_unsure_does_not_stream_a_finished_board_again(finished_job):
    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)  # up to date after other tests
    with _edited(path, "[stream]\n", "[stream]\nrecut_unsure = true\n"):
        pipe = load_pipeline(path)
        assert pipe.stream.recut_unsure
        assert run_pipeline(pipe, job, say=lambda s: None).ran == []


def test_naming_the_profiles_own_baud_does_not_stream_a_finished_board_again(finished_job):
    """The stream's fingerprint holds the baud used, whether [stream] or the profile gave it."""
    path, job, _ = finished_job
    run_pipeline(load_pipeline(path), job, say=lambda s: None)  # up to date after other tests
    baud = load_pipeline(path).profile.serial.baud
    with _edited(path, "[stream]\n", f"[stream]\nbaud = {baud}\n"):
        pipe = load_pipeline(path)
        assert pipe.stream.baud == baud
        assert run_pipeline(pipe, job, say=lambda s: None).ran == []


def test_toolpath_table_reaches_the_ordering_and_reruns_from_toolpath(finished_job, monkeypatch):
    import scratchfab.toolpath.stage as stage
    from scratchfab.toolpath import OrderOptions

    path, job, _ = finished_job
    seen = []
    real = stage.run_toolpath_job

    def spy(*args, **kwargs):
        seen.append(args[2])  # the OrderOptions
        return real(*args, **kwargs)

    monkeypatch.setattr(stage, "run_toolpath_job", spy)
    with _edited(path, "[toolpath]\n", "[toolpath]\nkicks = 30\nseed = 5\npasses = 4\n"):
        result = run_pipeline(load_pipeline(path), job, say=lambda s: None)
        assert result.ran[:2] == ["toolpath", "export"]
        assert seen == [OrderOptions(passes=4, kicks=30, seed=5)]


def test_failed_stage_keeps_earlier_outputs_and_next_run_resumes_there(tmp_path):
    path = write_pipeline(tmp_path, min_rho=0.9999)
    job = tmp_path / "job"
    with pytest.raises(ScratchfabError) as info:
        run_pipeline(load_pipeline(path), job, say=lambda s: None)
    # Named as the pipeline file names it, not as verify-render's --min-rho option.
    assert "--min-rho" not in str(info.value)
    shown = re.search(
        r"view (\w+) looks like its target only to rho (-?\d\.\d+), below \[verify\] "
        r"min_rho = 0.9999",
        str(info.value),
    )
    assert shown
    # as many decimals as min_rho has, rounded down (verify's gate rule)
    rho = json.loads((job / "verify" / "metrics.json").read_text())["views"][shown[1]]["rho"]
    assert shown[2] == f"{math.floor(rho * 10**4) / 10**4:.4f}"
    assert str(path) in str(info.value)
    manifest = Manifest.load(job)
    assert manifest.stages["optimize"]["status"] == "done"
    assert manifest.stages["verify"]["status"] == "failed"
    assert manifest.stages["verify"]["reason"] == str(info.value)  # its words, no class name
    assert not (job / "toolpath").exists()  # the gate stopped the pipeline before toolpath
    assert (job / "report.html").is_file()
    before = (job / "optimize" / "scratches.csv").read_bytes()
    path.write_text(path.read_text().replace("min_rho = 0.9999", "min_rho = -1.0"))
    result = run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert result.skipped == ["design", "optimize"]
    assert result.ran[0] == "verify"
    assert (job / "optimize" / "scratches.csv").read_bytes() == before


def test_stage_killed_midway_runs_again(finished_job, tmp_path, monkeypatch):
    """A stage that never got to say it failed (kill -9) is not left marked done."""
    from scratchfab.pipeline import runner

    path, job, _ = finished_job
    copy = tmp_path / "job"
    shutil.copytree(job, copy)

    def killed(self):
        raise SystemExit("killed")

    with monkeypatch.context() as mp:
        mp.setattr(Manifest, "invalidate", lambda *a: None)  # a kill runs no except clause
        mp.setattr(runner._Stages, "_run_toolpath", killed)
        with pytest.raises(SystemExit):
            run_pipeline(load_pipeline(path), copy, start="toolpath", until="export")
    assert Manifest.load(copy).stages["toolpath"]["status"] == "running"
    result = run_pipeline(load_pipeline(path), copy, until="export")
    assert result.skipped == ["design", "optimize", "verify"]
    assert result.ran == ["toolpath", "export"]


def test_ctrl_c_in_optimize_stops_the_run_and_the_next_run_continues_it(
    tmp_path, monkeypatch, capsys
):
    import contextlib

    from scratchfab.optimize import stage as optimize_stage

    text = write_pipeline(tmp_path).read_text().replace("iterations = 4", "iterations = 12")
    path = tmp_path / "tiny.toml"
    path.write_text(text)
    reference = tmp_path / "reference"
    run_pipeline(load_pipeline(path), reference, until="optimize")

    @contextlib.contextmanager
    def ctrl_c_after_five_steps():
        polls = iter(range(10**6))
        yield lambda: next(polls) >= 4

    job = tmp_path / "job"
    with monkeypatch.context() as mp:
        mp.setattr(optimize_stage, "interrupt_flag", ctrl_c_after_five_steps)
        with pytest.raises(SystemExit) as exc:
            main(["run", str(path), "--out", str(job)])
    assert exc.value.code == 130
    err = capsys.readouterr().err
    assert "[optimize] interrupted after 5 of 12 iterations; the pipeline stops here" in err
    assert "error" not in err and "Traceback" not in err
    assert Manifest.load(job).stages["optimize"]["status"] == "interrupted"
    assert not (job / "verify").exists() and not (job / "export").exists()

    said: list[str] = []
    result = run_pipeline(load_pipeline(path), job, until="optimize", say=said.append)
    assert result.ran == ["optimize"]
    assert any("continuing the run from" in line for line in said)
    scratches = "optimize/scratches.csv"
    assert (job / scratches).read_bytes() == (reference / scratches).read_bytes()
    assert Manifest.load(job).stages["optimize"]["status"] == "done"


def test_a_second_run_on_a_busy_job_is_refused(tmp_path):
    import fcntl

    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    job.mkdir()
    with open(job / ".run.lock", "a") as held:  # as a run in another process holds it
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(ScratchfabError, match="another `scratchfab run` is working on"):
            run_pipeline(load_pipeline(path), job)
    assert sorted(p.name for p in job.iterdir()) == [".run.lock"]  # nothing run
    result = run_pipeline(load_pipeline(path), job, until="design")  # free again
    assert result.ran == ["design"]


def test_until_and_from(tmp_path):
    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    with pytest.raises(ScratchfabError, match="comes after"):
        run_pipeline(load_pipeline(path), job, start="export", until="design", say=print)
    first = run_pipeline(load_pipeline(path), job, until="design", say=lambda s: None)
    assert first.ran == ["design"] and not (job / "optimize").exists()
    again = run_pipeline(
        load_pipeline(path), job, start="design", until="design", say=lambda s: None
    )
    assert again.ran == ["design"]


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            ("[optimize]\n", "[optimize]\niteratons = 3\n"),
            "optimize: unknown key 'iteratons' (did you mean 'iterations'?)",
        ),
        (
            ("[optimize]\n", "[optimise]\n"),
            "unknown key 'optimise' (did you mean 'optimize'?); valid keys: board, light, "
            "scratch, views, pipeline, optimize, verify, toolpath, export, stream",
        ),
        (("spp = 256", "spp = 0"), "verify.spp: expected a value at least 2, got 0"),
        (("spp = 256", "spp = 1"), "verify.spp: expected a value at least 2, got 1"),
        (
            ("[verify]\n", "[verify]\nsweep = 1\n"),
            "verify.sweep: expected 0 (no sweep) or at least 2 frames, got 1",
        ),
        (("[verify]\n", "[verify]\nseed = -1\n"), "verify.seed: expected a value at least 0"),
        (("[pipeline]\n", "[pipeline]\nseed = -1\n"), "pipeline.seed: expected a value at least 0"),
        (
            ('formats = ["gcode", "svg"]', "formats = []"),
            'stream.port: streaming needs "gcode" in export.formats, got export.formats = []',
        ),
        (
            ('formats = ["gcode", "svg"]', 'formats = ["svg", "dxf"]'),
            'stream.port: streaming needs "gcode" in export.formats, '
            "got export.formats = ['svg', 'dxf']",
        ),
        (('port = "grblsim', 'port = ""  # "grblsim'), "stream.port: expected a serial device"),
        (('port = "grblsim', 'port = " "  # "grblsim'), "stream.port: expected a serial device"),
        (
            ('machine = "grbl-3018-diamond"', 'machine = "nope"'),
            "toolpath.machine: machine 'nope': not a bundled profile",
        ),
        (
            ("[toolpath]\n", "[toolpath]\nkicks = -3\n"),
            "toolpath.kicks: expected a value at least 0",
        ),
        (
            ("[toolpath]\n", "[toolpath]\nseed = 4294967296\n"),
            "toolpath.seed: expected a value in [0, 4294967296), got 4294967296",
        ),
        (
            ("[toolpath]\n", '[toolpath]\nforce = "yes"\n'),
            "toolpath.force: expected true or false, got 'yes'",
        ),
        (
            ("[toolpath]\n", "[toolpath]\nforced = true\n"),
            "toolpath: unknown key 'forced' (did you mean 'force'?)",
        ),
    ],
)
def test_pipeline_errors_are_one_line(tmp_path, capsys, edit, message):
    path = write_pipeline(tmp_path)
    path.write_text(path.read_text().replace(*edit, 1))
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--out", str(tmp_path / "job"), "--until", "toolpath"])
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert message in err and str(path) in err and "Traceback" not in err
    assert not (tmp_path / "job").exists()  # refused on loading, before any stage ran


@pytest.mark.parametrize(
    ("edit", "check"),
    [
        (("[verify]\n", "[verify]\nsweep = 0\n"), lambda p: p.verify.sweep == 0),
        (("[verify]\n", "[verify]\nsweep = 2\n"), lambda p: p.verify.sweep == 2),
        (("spp = 256", "spp = 2"), lambda p: p.verify.spp == 2),
        (("[pipeline]\n", "[pipeline]\nseed = 7\n"), lambda p: p.pipeline.seed == 7),
        # unset: the machine profile's baud, as `stream` takes it
        (("[pipeline]\n", "[pipeline]\n"), lambda p: p.stream.baud is None),
        (("[stream]\n", "[stream]\nbaud = 57600\n"), lambda p: p.stream.baud == 57600),
        (('formats = ["gcode", "svg"]', 'formats = ["gcode"]'), lambda p: p.stream.port),
        # Without a port nothing is streamed, so export may leave out G-code (or write nothing).
        (("[stream]\nport", "[stream]\n# port"), lambda p: p.stream.port is None),
        (
            (
                'formats = ["gcode", "svg"]\n\n[stream]\nport',
                'formats = ["svg"]\n\n[stream]\n# port',
            ),
            lambda p: p.export.formats == ("svg",),
        ),
        (
            ('formats = ["gcode", "svg"]\n\n[stream]\nport', "formats = []\n\n[stream]\n# port"),
            lambda p: p.export.formats == (),
        ),
    ],
)
def test_stage_table_bounds_accept_the_valid_forms(tmp_path, edit, check):
    path = write_pipeline(tmp_path)
    text = path.read_text()
    assert edit[0] in text
    path.write_text(text.replace(*edit, 1))
    assert check(load_pipeline(path))


def testresolve_machine_ref_is_the_bundled_name_or_the_resolved_path(tmp_path):
    from scratchfab.bundled import bundled_dir
    from scratchfab.machine.profile import load_profile

    path = write_pipeline(tmp_path / "p")
    assert load_pipeline(path).machine_ref() == "grbl-3018-diamond"
    machines = tmp_path / "machines"
    machines.mkdir()
    (machines / "mine.toml").write_text(
        (bundled_dir("machine_profiles") / "grbl-3018-diamond.toml").read_text()
    )
    text = path.read_text().replace('"grbl-3018-diamond"', '"../machines/mine.toml"')
    path.write_text(text)
    pipe = load_pipeline(path)
    assert Path(pipe.machine_ref()).resolve() == (machines / "mine.toml").resolve()
    assert Path(pipe.profile.source).resolve() == (machines / "mine.toml").resolve()
    assert pipe.profile.tool == load_profile("grbl-3018-diamond").tool


@pytest.mark.parametrize(
    ("ref", "is_file"),
    [
        ("grbl-3018-diamond", False),
        ("my-engraver.toml", True),
        ("profiles/my3018", True),
        ("profiles\\my3018", True),  # a Windows path, as profile loading reads it
    ],
)
def test_toolpath_machine_is_a_name_or_a_file_beside_the_pipeline(tmp_path, ref, is_file):
    from scratchfab.pipeline.config import resolve_machine_ref

    pipeline = tmp_path / "p.toml"
    assert resolve_machine_ref(ref, pipeline) == (str(tmp_path / ref) if is_file else ref)


def _killed_optimize(finished_job, tmp_path, monkeypatch) -> tuple[Path, Path, Path]:
    """A copy of the finished job whose optimize was killed midway (the manifest says
    "running"): the pipeline, the copy and its checkpoint."""
    from scratchfab.pipeline import runner

    path, job, _ = finished_job
    copy = tmp_path / "job"
    shutil.copytree(job, copy)

    def killed(self):
        raise SystemExit("killed")

    with monkeypatch.context() as mp:
        mp.setattr(Manifest, "invalidate", lambda *a: None)
        mp.setattr(runner._Stages, "_run_optimize", killed)
        with pytest.raises(SystemExit):
            run_pipeline(load_pipeline(path), copy, start="optimize", until="optimize")
    return path, copy, copy / "optimize" / "checkpoint.npz"


def test_a_checkpoint_made_otherwise_is_started_afresh_without_optimize_s_advice(
    finished_job, tmp_path, monkeypatch
):
    """A checkpoint of other settings (here `scratchfab optimize` with another seed): the
    pipeline says why it starts over, not the command's "give that to resume it" advice,
    which editing the pipeline's [optimize] table could not follow."""
    from scratchfab.optimize.stage import run_optimize

    path, copy, ckpt = _killed_optimize(finished_job, tmp_path, monkeypatch)
    options = load_pipeline(path).optimize
    run_optimize(copy, replace(options, seed=options.seed + 1, iterations=2))
    said: list[str] = []
    result = run_pipeline(load_pipeline(path), copy, until="optimize", say=said.append)
    assert result.ran == ["optimize"]
    assert (
        f"  cannot continue it ({ckpt}: made with different settings (seed)); "
        "optimizing from the start"
    ) in said
    assert not any("--resume" in line or "give that" in line for line in said)
    scratches = "optimize/scratches.csv"
    assert (copy / scratches).read_bytes() == (finished_job[1] / scratches).read_bytes()


def test_damaged_checkpoint_of_an_interrupted_optimize_starts_it_afresh(
    finished_job, tmp_path, monkeypatch
):
    path, copy, ckpt = _killed_optimize(finished_job, tmp_path, monkeypatch)
    job = finished_job[1]
    ckpt.write_bytes(b"garbage")
    said: list[str] = []
    result = run_pipeline(load_pipeline(path), copy, until="optimize", say=said.append)
    assert result.ran == ["optimize"]
    assert f"  continuing the run from {ckpt}" in said
    assert (
        f"  cannot continue it ({ckpt}: not a NumPy .npz file (it begins with b'garbage')); "
        "optimizing from the start"
    ) in said
    # The fresh run is the finished job's run again, and leaves a readable checkpoint.
    scratches = "optimize/scratches.csv"
    assert (copy / scratches).read_bytes() == (job / scratches).read_bytes()
    assert Manifest.load(copy).stages["optimize"]["status"] == "done"
    assert ckpt.read_bytes()[:2] == b"PK"


def test_pipeline_without_a_stream_port_runs_to_the_end_and_says_not_streamed(tmp_path):
    from conftest import PIPELINE

    port = next(line for line in PIPELINE.splitlines() if line.startswith("port ="))
    path = write_pipeline(tmp_path, edits={f"[stream]\n{port}\n": ""})
    assert "[stream]" not in path.read_text()
    job = tmp_path / "job"
    said: list[str] = []
    result = run_pipeline(load_pipeline(path), job, say=said.append)
    assert result.ran == [s for s in STAGES if s != "stream"]
    assert (job / "export" / "board.gcode").is_file()
    assert not (job / "stream").exists() and "stream" not in Manifest.load(job).stages
    assert not any(line.startswith("[stream]") for line in said)
    report = (job / "report.html").read_text()
    assert "<span class='muted'>ℹ info</span> not streamed</li>" in report
    assert "<p class='muted'>not streamed.</p>" in report
    assert "Or set [stream] <code>port</code> in the pipeline file" in report


def test_report_after_design_failed_says_design_failed_and_the_rest_has_not_run(tmp_path):
    path = write_pipeline(tmp_path)
    (tmp_path / "disc.png").write_bytes(b"not a png")
    job = tmp_path / "job"
    with pytest.raises(ScratchfabError, match=r"disc\.png: not an image file"):
        run_pipeline(load_pipeline(path), job, say=lambda s: None)
    assert Manifest.load(job).stages["design"]["status"] == "failed"
    assert not (job / "design").exists()
    report = (job / "report.html").read_text()
    assert "data-verdict='not-ready'" in report
    assert "stage design failed" in report and "disc.png: not an image file" in report
    assert "design has not run</li>" not in report  # its failure is its line
    assert "design has not run" not in report  # it ran, and failed
    failed = "<p class='muted'>design failed (see the verdict above).</p>"
    assert report.count(failed) == 2  # where to stand, the views
    for later in ("optimize", "toolpath", "export"):
        assert f"<p class='muted'>{later} has not run.</p>" in report


@pytest.mark.parametrize(
    "port",
    [
        "grblsim://?time_scale=0&record={victim}",
        "GrblSim://?record={victim}&time_scale=0",
        "grblsim://?time_scale=0&recor%64={victim}",  # the handler percent-decodes keys
        "grblsim://?record",
    ],
)
def test_a_pipelines_emulator_port_may_not_record(tmp_path, capsys, port):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    port = port.format(victim=victim)
    path = write_pipeline(tmp_path, edits={'port = "grblsim://?time_scale=0&': f'port = "{port}&'})
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--out", str(tmp_path / "job")])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "Traceback" not in err
    (line,) = err.splitlines()
    assert line.startswith(f"error: {path}: stream.port: ") and "[stream] port" in line
    assert "scratchfab grbl-sim --record" in line and "stream --port" in line
    assert victim.read_text() == "precious\n"
    assert not (tmp_path / "job").exists()  # refused on loading, before any stage ran


@pytest.mark.parametrize(
    "port",
    [
        "grblsim://?time_scale=0&$130=300&$131=180&$132=45",  # the emulator, no record
        "grblsim://?time_scale=0&recorder=1",  # not the key (the emulator names it)
        "socket://localhost:7000?record=1",  # another handler's URL is its own business
    ],
)
def test_other_ports_load(tmp_path, port):
    path = write_pipeline(
        tmp_path, edits={"grblsim://?time_scale=0&$130=300&$131=180&$132=45": port}
    )
    assert load_pipeline(path).stream.port == port


@pytest.mark.parametrize(("width", "warned"), [(30.0, False), (400.0, True)])
def test_a_board_the_machine_cannot_reach_whole_is_said_before_design(tmp_path, width, warned):
    """The 3018's envelope is 300 x 180 mm: a 400 mm board is said at the start, and the
    toolpath stage (under ``[toolpath] force``) then finds scratches outside it, as the warning said."""
    path = write_pipeline(
        tmp_path,
        edits={
            "width_mm = 30.0": f"width_mm = {width}",
            'machine = "grbl-3018-diamond"': 'machine = "grbl-3018-diamond"\nforce = true',
        },
    )
    said: list[str] = []
    result = run_pipeline(load_pipeline(path), tmp_path / "job", until="toolpath", say=said.append)
    first = said[0].startswith(f"warning: the {width:g} x 30 mm board (corners ")
    assert first is warned
    envelope = (
        "the envelope of machine 'GRBL 3018 engraver, diamond drag bit' (X -300 to 0, Y -180 to 0)"
    )
    assert any(f"reaches beyond {envelope}" in line for line in said) is warned
    if warned:
        # Prose, not Python: the corners as points from offset_mm (-220, -150) and the size;
        # no moving helps a board wider than the travel.
        assert "(corners (-220, -150), (180, -150), (180, -120), (-220, -120))" in said[0]
        assert (
            "400 mm in X (the design's [board] width_mm) but the machine's X travel is 300 mm"
            in said[0]
        )
        assert "no offset_mm in the profile's [board] can fit it" in said[0]
        assert "''" not in said[0] and "[[" not in said[0]
    stats = json.loads((tmp_path / "job" / "toolpath" / "toolpath.json").read_text())["statistics"]
    assert (stats["outside_count"] + stats["clipped_count"] > 0) is warned
    assert result.ran[-1] == "toolpath"
    # Said once: not again by a run with nothing to do, nor by one that starts at toolpath
    # (which says what it left out itself).
    for start in (None, "toolpath"):
        said.clear()
        run_pipeline(
            load_pipeline(path), tmp_path / "job", start=start, until="toolpath", say=said.append
        )
        assert not any("board (corners" in line for line in said), said
        assert any("outside the machine's envelope" in line for line in said) is (
            warned and start == "toolpath"
        )


def test_a_board_wholly_off_the_machine_is_said_with_advice_that_works(tmp_path):
    """Before design: the toolpath stage will refuse it (not "leave out or clip"), and what
    to set; the toolpath stage then refuses it with the same advice."""
    from scratchfab.bundled import bundled_dir

    profile = (bundled_dir("machine_profiles") / "grbl-3018-diamond.toml").read_text()
    old = "offset_mm = [-220.0, -150.0]"
    (tmp_path / "off.toml").write_text(profile.replace(old, "offset_mm = [50.0, -150.0]"))
    path = write_pipeline(tmp_path, edits={'machine = "grbl-3018-diamond"': 'machine = "off.toml"'})
    said: list[str] = []
    with pytest.raises(ScratchfabError) as info:
        run_pipeline(load_pipeline(path), tmp_path / "job", until="toolpath", say=said.append)
    warning = said[0]
    assert warning.startswith(
        "warning: the 30 x 30 mm board (corners (50, -150), (80, -150), (80, -120), (50, -120))"
    )
    assert "can fit it" not in warning  # 30 mm fits the travel: moving it is the fix
    assert "lies wholly outside" in warning and "the toolpath stage will refuse it" in warning
    assert "leave out" not in warning and "clip" not in warning
    # The same offset in both, one that fits: the 30 mm board's far corner inside X <= 0.
    (offset,) = re.findall(r"set the profile's \[board\] offset_mm = \[([-0-9.]+), ", warning)
    assert f"offset_mm = [{offset}, " in str(info.value)
    assert -300 <= float(offset) <= -30
    assert "wholly outside the envelope" in str(info.value)
    assert sum("board (corners" in line for line in said) == 1


def test_a_stopped_stream_s_advice_says_how_a_pipeline_resumes(tmp_path):
    """The sender's advice names `stream --resume`; in a pipeline, running it again is how
    the stream resumes, and the message says so."""
    from conftest import PIPELINE

    port = next(line for line in PIPELINE.splitlines() if line.startswith("port ="))
    path = write_pipeline(tmp_path, edits={port: port[:-1] + '&reset_after=30"'})
    with pytest.raises(ScratchfabError) as info:
        run_pipeline(load_pipeline(path), tmp_path / "job", say=lambda s: None)
    text = str(info.value)
    assert "the controller reset itself" in text and "--resume" in text
    assert text.endswith("(here `scratchfab run` has no --resume: run it again and it resumes)")


@pytest.mark.parametrize(
    ("sender", "in_run"),
    [
        (
            "stopped by Ctrl-C after line 12; machine held, then soft-reset (spindle off); "
            "continue later with --resume",
            "stopped by Ctrl-C after line 12; machine held, then soft-reset (spindle off); "
            "run the same command again later: it resumes",
        ),
        (
            "connection lost: reconnect, re-home, then --resume",
            "connection lost: reconnect, re-home, then --resume (here `scratchfab run` has no "
            "--resume: run it again and it resumes)",
        ),
        ("error:20 at line 3", "error:20 at line 3"),
    ],
)
def test_the_senders_resume_advice_reads_as_run_resumes(sender, in_run):
    from scratchfab.pipeline.runner import as_run_advice

    assert as_run_advice(sender) == in_run


def test_an_interrupted_optimize_whose_design_changed_says_why_it_starts_over(
    finished_job, tmp_path, monkeypatch
):
    """The pipeline file's roughness edited after an interrupted optimize: the run says
    what changed since the checkpoint, rather than starting over without a word."""
    path, copy, ckpt = _killed_optimize(finished_job, tmp_path, monkeypatch)
    said: list[str] = []
    with _edited(path, "[board]\n", "[board]\nroughness = 0.06\n"):
        result = run_pipeline(load_pipeline(path), copy, until="optimize", say=said.append)
    assert result.ran == ["design", "optimize"]
    (line,) = [s for s in said if "cannot continue it" in s]
    assert f"{ckpt}: " in line and "[board] roughness 0.05 -> 0.06" in line
    assert line.endswith("optimizing from the start")


def test_a_design_toml_the_design_stage_wrote_since_optimize_is_not_taken_for_a_hand_edit(
    finished_job, tmp_path
):
    """The pipeline file changed and a run went only as far as design (``--until design``):
    design.toml differs from what optimize read, but nobody edited it by hand."""
    path, job, _ = finished_job
    copy = tmp_path / "job"
    shutil.copytree(job, copy)
    said: list[str] = []
    with _edited(path, "[board]\n", "[board]\nroughness = 0.06\n"):
        result = run_pipeline(load_pipeline(path), copy, until="design", say=said.append)
        assert result.ran == ["design"]
        said.clear()
        run_pipeline(load_pipeline(path), copy, until="design", say=said.append)
    assert said == ["[design] up to date, skipped"]


def test_a_hand_edited_design_toml_in_a_pipeline_job_is_named_with_where_to_edit(
    finished_job, tmp_path
):
    """The design stage is up to date (the pipeline file did not change), yet the job's
    design.toml was edited: the run says the edit holds only until design runs again."""
    path, job, _ = finished_job
    copy = tmp_path / "job"
    shutil.copytree(job, copy)
    toml = copy / "design" / "design.toml"
    said: list[str] = []
    run_pipeline(load_pipeline(path), copy, until="design", say=said.append)
    assert said == ["[design] up to date, skipped"]  # untouched: nothing more
    toml.write_text(toml.read_text().replace("roughness = 0.05", "roughness = 0.06"))
    said.clear()
    run_pipeline(load_pipeline(path), copy, until="design", say=said.append)
    assert said[0] == "[design] up to date, skipped"
    assert said[1] == (
        f"  {toml} was edited since the design stage wrote it: the stages after design use "
        f"it as it is now, but this job's design comes from {path}, and the design stage "
        "writes it over whenever that file changes: make the edit there"
    )


def test_a_board_the_envelope_cuts_short_stops_the_run_at_toolpath_with_the_offset_that_fits(
    tmp_path,
):
    """Without ``[toolpath] force`` a partial board is refused at toolpath, as the CLI's
    ``toolpath`` refuses it without ``--force``: the start's warning says so, the refusal
    names the offset_mm that fits, nothing is planned, and that offset cuts every scratch."""
    from scratchfab.bundled import bundled_dir

    profile = (bundled_dir("machine_profiles") / "grbl-3018-diamond.toml").read_text()
    old = "offset_mm = [-220.0, -150.0]"
    (tmp_path / "overhang.toml").write_text(profile.replace(old, "offset_mm = [-15.0, -150.0]"))
    path = write_pipeline(
        tmp_path, edits={'machine = "grbl-3018-diamond"': 'machine = "overhang.toml"'}
    )
    job = tmp_path / "job"
    said: list[str] = []
    with pytest.raises(ScratchfabError) as info:
        run_pipeline(load_pipeline(path), job, until="toolpath", say=said.append)
    assert "will stop there if a scratch lies beyond it, unless [toolpath] force = true" in said[0]
    refusal = str(info.value)
    assert "or give [toolpath] force = true to plan only the part it reaches" in refusal
    assert not (job / "toolpath" / "toolpath.json").exists()
    assert (job / "optimize" / "scratches.csv").is_file()  # the work before it is kept
    (offset,) = re.findall(r"offset_mm = (\[[-0-9.]+, [-0-9.]+\])", refusal)
    (tmp_path / "overhang.toml").write_text(profile.replace(old, f"offset_mm = {offset}"))
    said.clear()
    run_pipeline(load_pipeline(path), job, until="toolpath", say=said.append)
    stats = json.loads((job / "toolpath" / "toolpath.json").read_text())["statistics"]
    assert stats["outside_count"] == 0 and stats["clipped_count"] == 0
    assert not any("board (corners" in line for line in said)


@pytest.mark.parametrize("force", [False, True])
def test_a_refused_design_names_the_pipeline_key_that_overrides_it(tmp_path, force):
    """Under ``run``, ``--force`` reruns every stage: a design refusal (here a black target)
    names ``[pipeline] force = true`` in the file instead, and that key does design it."""
    from PIL import Image

    edits = {'target = "bar.png"': 'target = "black.png"'}
    if force:
        edits['name = "tiny"'] = 'name = "tiny"\nforce = true'
    path = write_pipeline(tmp_path, edits=edits)
    Image.new("L", (24, 24), 0).save(tmp_path / "black.png")
    job = tmp_path / "job"
    if force:
        run_pipeline(load_pipeline(path), job, until="design", say=lambda _: None)
        assert (job / "design" / "design.toml").is_file()
        return
    with pytest.raises(ScratchfabError) as info:
        run_pipeline(load_pipeline(path), job, until="design", say=lambda _: None)
    said = str(info.value)
    assert "the picture is black on the board" in said
    assert f"(set [pipeline] force = true in {path} to design anyway)" in said
    assert "--force" not in said


@pytest.mark.parametrize(("x", "warned"), [(-29.0, False), (-28.0, True)])
def test_a_board_overhanging_by_less_than_its_margin_is_not_warned_of(tmp_path, x, warned):
    """The tiny board is 30 mm wide with a 1.5 mm margin: its scratches end 1.5 mm inside
    its edge, so an overhang of 1 mm past X 0 leaves every scratch reachable (the toolpath
    stage plans it whole) and the start says nothing; 2 mm is said."""
    from scratchfab.bundled import bundled_dir

    profile = (bundled_dir("machine_profiles") / "grbl-3018-diamond.toml").read_text()
    old = "offset_mm = [-220.0, -150.0]"
    (tmp_path / "edge.toml").write_text(profile.replace(old, f"offset_mm = [{x}, -150.0]"))
    path = write_pipeline(
        tmp_path, edits={'machine = "grbl-3018-diamond"': 'machine = "edge.toml"'}
    )
    said: list[str] = []
    # warned: the toolpath stage may then refuse, if a scratch lies beyond X 0
    with contextlib.suppress(ScratchfabError) if warned else contextlib.nullcontext():
        run_pipeline(load_pipeline(path), tmp_path / "job", until="toolpath", say=said.append)
    assert any("board (corners" in line for line in said) is warned
    if not warned:
        stats = json.loads((tmp_path / "job" / "toolpath" / "toolpath.json").read_text())
        assert stats["statistics"]["outside_count"] == 0
        assert stats["statistics"]["clipped_count"] == 0


def test_the_design_stage_of_a_run_says_where_to_stand(tmp_path):
    """As ``design`` ends: where each view stands and where the light goes."""
    from scratchfab.design.stand import stand_lines
    from scratchfab.model.design import load_design

    path = write_pipeline(tmp_path)
    said: list[str] = []
    run_pipeline(load_pipeline(path), tmp_path / "job", until="design", say=said.append)
    design = load_design(tmp_path / "job" / "design" / "design.toml")
    lines = stand_lines(design)
    assert len(lines) == 4 and lines[1].startswith("  disc: stand 22° to the left")
    shown = [line.strip() for line in said]
    assert all(line.strip() in shown for line in lines), said
