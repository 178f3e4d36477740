"""`run` into a folder the single commands made: it says once why every stage runs."""

from __future__ import annotations

from conftest import write_pipeline

from scratchfab.cli import main
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline

NO_RECORD = "no record of earlier runs in"


def test_a_folder_made_by_the_single_commands_is_said_to_have_no_record(tmp_path):
    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    assert main(["design", str(path), "--out", str(job)]) in (0, None)
    assert (job / "design" / "design.toml").is_file() and not (job / "manifest.json").exists()
    said: list[str] = []
    result = run_pipeline(load_pipeline(path), job, until="design", say=said.append)
    assert result.ran == ["design"]
    notes = [line for line in said if NO_RECORD in line]
    assert len(notes) == 1, said
    assert str(job) in notes[0] and "every stage" in notes[0]
    assert said.index(notes[0]) < said.index("[design] running")
    # Now the run keeps its record: the next run skips design and says nothing of it.
    again: list[str] = []
    assert run_pipeline(load_pipeline(path), job, until="design", say=again.append).skipped == [
        "design"
    ]
    assert not [line for line in again if NO_RECORD in line], again


def test_a_new_folder_or_a_forced_run_says_nothing_of_records(tmp_path):
    path = write_pipeline(tmp_path)
    said: list[str] = []
    run_pipeline(load_pipeline(path), tmp_path / "new", until="design", say=said.append)
    assert not [line for line in said if NO_RECORD in line], said
    job = tmp_path / "made"
    assert main(["design", str(path), "--out", str(job)]) in (0, None)
    forced: list[str] = []
    run_pipeline(load_pipeline(path), job, until="design", force=True, say=forced.append)
    assert not [line for line in forced if NO_RECORD in line], forced
