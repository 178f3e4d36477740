"""Job folders and projects that move: copied, renamed, linked, to paths with spaces.

A maker designs and optimizes on a laptop, then copies the job (or the folder with the
pipeline file and its pictures) to the computer beside the engraver. Nothing finished may
run again because of where the files now lie, and nothing unsafe may pass because of it.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tomllib
from pathlib import Path

import pytest
from conftest import write_pipeline

from scratchfab.cli import main
from scratchfab.machine.sender_program import load_program
from scratchfab.pipeline.config import STAGES, load_pipeline
from scratchfab.pipeline.manifest import Manifest
from scratchfab.pipeline.runner import run_pipeline

MACHINE = "machines/my 3018.toml"  # a profile file of the project's own
COMPUTING = ["design", "optimize", "verify", "toolpath", "export"]


def _copy_as_cp_r(src: Path, dst: Path) -> None:
    """``cp -r``: the bytes, not the modification times (a USB stick, a fresh clone)."""
    shutil.copytree(src, dst, copy_function=shutil.copyfile, symlinks=True)


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """A finished project folder: pipeline, pictures, machine file and the job in ``jobs/``."""
    from scratchfab.bundled import find_bundled

    folder = tmp_path_factory.mktemp("laptop") / "project"
    path = write_pipeline(
        folder,
        edits={
            'machine = "grbl-3018-diamond"': f'machine = "{MACHINE}"',
            'name = "tiny"': 'name = "tiny"\nout = "jobs/board"',
        },
    )
    (folder / "machines").mkdir()
    shutil.copyfile(
        find_bundled("machine_profiles", "grbl-3018-diamond", "machine"), folder / MACHINE
    )
    result = run_pipeline(load_pipeline(path), load_pipeline(path).job_dir())
    assert result.ran == list(STAGES)
    return folder


def _run(folder: Path, said: list[str] | None = None, out: Path | None = None):
    pipe = load_pipeline(folder / "tiny.toml")
    return run_pipeline(pipe, pipe.job_dir(out), say=(said if said is not None else []).append)


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="utf-8")
    assert old in text, old
    path.write_text(text.replace(old, new), encoding="utf-8")


def test_copied_project_folder_keeps_every_stage(project, tmp_path):
    copy = tmp_path / "pi home" / "Zeichnungen für Ätzung"  # spaces, non-ASCII
    _copy_as_cp_r(project, copy)
    said: list[str] = []
    result = _run(copy, said)
    assert result.ran == [] and result.skipped == list(STAGES), said
    # The copy is its own job: a changed picture there still reruns from design.
    picture = copy / "disc.png"
    picture.write_bytes(picture.read_bytes() + b"\0")  # other bytes after IEND
    assert _run(copy).ran == COMPUTING


def test_renaming_the_job_or_the_report_title_keeps_every_stage(project, tmp_path):
    copy = tmp_path / "project"
    shutil.copytree(project, copy, symlinks=True)
    (copy / "jobs" / "board").rename(copy / "jobs" / "board, second try")
    _edit(copy / "tiny.toml", 'out = "jobs/board"', 'out = "jobs/board, second try"')
    _edit(copy / "tiny.toml", 'name = "tiny"', 'name = "the second try"')
    result = _run(copy)
    assert result.ran == [] and result.job == copy / "jobs" / "board, second try"
    assert "the second try" in (result.job / "report.html").read_text(encoding="utf-8")


def test_pictures_and_profile_moved_inside_the_project_keep_every_stage(project, tmp_path):
    copy = tmp_path / "project"
    shutil.copytree(project, copy, symlinks=True)
    (copy / "pictures").mkdir()
    for name in ("disc.png", "bar.png"):
        (copy / name).rename(copy / "pictures" / name)
        _edit(copy / "tiny.toml", f'target = "{name}"', f'target = "pictures/{name}"')
    (copy / MACHINE).rename(copy / "my 3018.toml")
    _edit(copy / "tiny.toml", MACHINE, "my 3018.toml")
    assert _run(copy).ran == []
    # The bundled profile it was copied from is the same machine, byte for byte.
    _edit(copy / "tiny.toml", 'machine = "my 3018.toml"', 'machine = "grbl-3018-diamond"')
    assert _run(copy).ran == []
    # Swapping the two views' pictures is a change, though the same files are named.
    text = (copy / "tiny.toml").read_text(encoding="utf-8")
    swapped = text.replace("pictures/disc.png", "@").replace(
        "pictures/bar.png", "pictures/disc.png"
    )
    (copy / "tiny.toml").write_text(swapped.replace("@", "pictures/bar.png"), encoding="utf-8")
    assert _run(copy).ran == [*COMPUTING, "stream"]  # another board: cut


def test_job_named_through_a_symlink_or_its_real_path_is_one_job(project, tmp_path):
    copy = tmp_path / "project"
    shutil.copytree(project, copy, symlinks=True)
    link = tmp_path / "the board"
    link.symlink_to(copy / "jobs" / "board", target_is_directory=True)
    assert _run(copy, out=link).ran == []
    assert _run(copy, out=copy / "jobs" / "board").ran == []


# -- manifests written before fingerprint format 2 --------------------------------------


def _stamped(path: Path) -> str:
    return hashlib.sha256(path.read_bytes() + str(path.stat().st_mtime_ns).encode()).hexdigest()


def _as_format_1(folder: Path) -> None:
    """Rewrite the job's manifest as scratchfab wrote it before fingerprint format 2.

    From a real one (``scratchfab run demo``): the user's files under their absolute
    paths, each digest the SHA-256 of the bytes followed by the decimal st_mtime_ns;
    ``design`` took the pipeline's tables whole (less the later stages'), ``toolpath``
    ``[toolpath] machine`` as named; no ``format`` key. The job's own files as now.
    """
    pipeline = folder / "tiny.toml"
    data = tomllib.loads(pipeline.read_text(encoding="utf-8"))
    job = folder / data["pipeline"]["out"]
    manifest = json.loads((job / "manifest.json").read_text(encoding="utf-8"))
    for stage, entry in manifest["stages"].items():
        inputs = entry["inputs"]
        del inputs["format"]
        files = {k: v for k, v in inputs["files"].items() if ":" not in k and k != "machine"}
        if stage == "design":
            for view in data["views"]:
                target = (folder / view["target"]).resolve()
                files[str(target)] = _stamped(target)
            inputs["options"] = {"tables": {k: v for k, v in data.items() if k not in STAGES[1:]}}
        if stage == "toolpath":
            profile = (folder / data["toolpath"]["machine"]).resolve()
            files[str(profile)] = _stamped(profile)
            inputs["options"]["machine"] = data["toolpath"]["machine"]
        inputs["files"] = files
    (job / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")


def test_format_1_manifest_of_an_unchanged_job_is_taken_and_rewritten(project, tmp_path):
    copy = tmp_path / "project"
    shutil.copytree(project, copy, symlinks=True)  # times kept, as an upgrade finds them
    _as_format_1(copy)
    job = copy / "jobs" / "board"
    journal = (job / "stream" / "journal.jsonl").read_bytes()
    said: list[str] = []
    result = _run(copy, said)
    assert result.ran == [] and result.skipped == list(STAGES), said
    assert (job / "stream" / "journal.jsonl").read_bytes() == journal  # not cut again
    stages = json.loads((job / "manifest.json").read_text(encoding="utf-8"))["stages"]
    assert {entry["inputs"].get("format") for entry in stages.values()} == {2}
    # moved now (new times, new paths): format 2 keeps it
    moved = tmp_path / "moved"
    _copy_as_cp_r(copy, moved)
    assert _run(moved).ran == []


def test_format_1_manifest_of_a_moved_project_reruns_with_a_message(project, tmp_path):
    original = tmp_path / "project"
    shutil.copytree(project, original, symlinks=True)
    _as_format_1(original)
    moved = tmp_path / "copied"
    _copy_as_cp_r(original, moved)  # the recorded paths and times no longer hold
    said: list[str] = []
    result = _run(moved, said)
    assert result.ran == COMPUTING and result.skipped == ["stream"]
    (note,) = [line for line in said if "earlier scratchfab" in line]
    assert note.startswith("[design] ") and "running it again" in note
    assert _run(moved).ran == []


@pytest.mark.parametrize("inputs", [5, [], {"files": 3}, {"files": {"/x": 1}, "options": []}])
def test_damaged_format_1_entries_rerun_their_stage(project, tmp_path, inputs):
    copy = tmp_path / "project"
    shutil.copytree(project, copy, symlinks=True)
    job = copy / "jobs" / "board"
    manifest = json.loads((job / "manifest.json").read_text(encoding="utf-8"))
    manifest["stages"]["export"]["inputs"] = inputs
    (job / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    result = _run(copy)
    assert result.ran == ["export"] and result.skipped[-1] == "stream"
    assert Manifest.load(job).stages["export"]["inputs"]["format"] == 2


# -- streaming a job that moved --------------------------------------------------------


def test_stream_resumes_in_a_job_moved_after_a_dropped_cable(project, tmp_path, capsys):
    laptop = tmp_path / "laptop"
    shutil.copytree(project / "jobs" / "board", laptop, symlinks=True)
    (laptop / "stream" / "journal.jsonl").unlink()
    port = "grblsim://?time_scale=0&$130=300&$131=180&$132=45"
    gcode = laptop / "export" / "board.gcode"
    with pytest.raises(SystemExit) as stopped:
        main(["stream", str(gcode), "--port", f"{port}&disconnect_after=120", "--yes"])
    assert stopped.value.code != 0 and "connection lost" in capsys.readouterr().err
    pi = tmp_path / "pi" / "Gravur für Oma"
    pi.parent.mkdir()
    laptop.rename(pi)
    moved = pi / "export" / "board.gcode"
    main(["stream", str(moved), "--port", port, "--yes", "--resume"])
    events = [json.loads(line) for line in (pi / "stream" / "journal.jsonl").open()]
    starts = [e for e in events if e["ev"] == "start"]
    assert [s["resume"] for s in starts] == [False, True]
    assert [s["file"] for s in starts] == ["export/board.gcode"] * 2  # where it lay, and lies
    second = events.index(starts[1])
    before = {e["i"] for e in events[:second] if e["ev"] == "ack" and "i" in e}
    after = {e["i"] for e in events[second:] if e["ev"] == "ack" and "i" in e}
    assert before and after and min(after) > 0 and events[-1]["ev"] == "end"
    # every cut of the board acknowledged in one session or the other: nothing skipped
    cuts = {i for i, b in enumerate(load_program(moved).blocks) if b.text.startswith("G1")}
    assert cuts <= before | after


def test_a_copied_job_records_its_own_files(project, tmp_path, monkeypatch):
    """The verify metrics' comparison and the stream journal's file are named relative to
    the job folder, so a copy's records name the copy's own files (a file outside a job:
    absolute, not relative to whatever folder the stream ran in)."""
    copy = tmp_path / "copy"
    _copy_as_cp_r(project / "jobs" / "board", copy)
    metrics = json.loads((copy / "verify" / "metrics.json").read_text(encoding="utf-8"))
    assert metrics["comparison"] == "optimize/renders"
    assert (copy / metrics["comparison"]).is_dir()
    (start, *_) = [json.loads(line) for line in (copy / "stream" / "journal.jsonl").open()]
    assert start["ev"] == "start" and start["file"] == "export/board.gcode"
    gcode = (copy / start["file"]).read_bytes()
    assert hashlib.sha256(gcode).hexdigest() == start["sha256"]
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "board.gcode").write_bytes(gcode)
    monkeypatch.chdir(alone)
    main(["stream", "board.gcode", "--port", "grblsim://?time_scale=0&$130=300&$131=180", "--yes"])
    (start, *_) = [json.loads(line) for line in (alone / "board.gcode.journal.jsonl").open()]
    assert start["file"] == str(alone / "board.gcode")


def test_a_file_browser_looking_at_the_job_reruns_nothing(project, tmp_path):
    copy = tmp_path / "usb stick"
    shutil.copytree(project, copy, symlinks=True)
    board = copy / "jobs" / "board"
    for folder in (board / "design" / "board", board / "design" / "targets"):
        (folder / "Thumbs.db").write_bytes(b"\xd0\xcf\x11\xe0")  # Windows Explorer
        (folder / "desktop.ini").write_text("[.ShellClassInfo]\n")
        (folder / "._sun.png").write_bytes(b"\0\5\26\7")  # macOS on a FAT stick
        (folder / ".Trashes").mkdir()
        (folder / ".Trashes" / "501").write_bytes(b"x")
    assert _run(copy).ran == []
    # a file of the job's own under a new name still counts
    targets = board / "design" / "targets"
    shutil.copyfile(targets / "disc.npy", targets / "x.npy")
    assert _run(copy).ran == COMPUTING[1:]


def test_verify_with_jitter_reruns_when_the_machines_tolerance_changes(tmp_path):
    from scratchfab.bundled import find_bundled

    path = write_pipeline(
        tmp_path,
        edits={
            'machine = "grbl-3018-diamond"': 'machine = "3018.toml"',
            "[verify]\n": "[verify]\njitter = true\n",
        },
    )
    profile = tmp_path / "3018.toml"
    shutil.copyfile(find_bundled("machine_profiles", "grbl-3018-diamond", "machine"), profile)
    job = tmp_path / "job"
    first = run_pipeline(load_pipeline(path), job, until="toolpath")
    assert first.ran == COMPUTING[:4]
    _edit(profile, "tolerance_mm = 0.01", "tolerance_mm = 0.2")
    again = run_pipeline(load_pipeline(path), job, until="toolpath")
    assert again.ran == ["verify", "toolpath"]
    metrics = json.loads((job / "verify" / "metrics.json").read_text(encoding="utf-8"))
    assert "0.2" in json.dumps(metrics["jitter"])


def test_a_stage_folder_linked_elsewhere_is_keyed_inside_the_job(project, tmp_path):
    copy = tmp_path / "project"
    shutil.copytree(project, copy, symlinks=True)
    board = copy / "jobs" / "board"
    big = tmp_path / "big disk" / "optimize"
    big.parent.mkdir()
    shutil.move(board / "optimize", big)
    (board / "optimize").symlink_to(big, target_is_directory=True)
    assert _run(copy).ran == []
    verify = Manifest.load(board).stages["verify"]["inputs"]["files"]
    assert "optimize/scratches.csv" in verify and not any(k.startswith("/") for k in verify)
    moved = tmp_path / "other disk"
    big.parent.rename(moved)  # the disk mounted elsewhere; the link follows
    (board / "optimize").unlink()
    (board / "optimize").symlink_to(moved / "optimize", target_is_directory=True)
    assert _run(copy).ran == []
