"""`scratchfab run` and `scratchfab stream` read the answer to their question alike.

An artist pipes the answer (``echo y | scratchfab run ...``) as ``stream`` takes it; both
refuse, naming how to answer, where stdin closes before any answer came.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import write_pipeline

from scratchfab.cli import main

QUESTION = "The machine moves: board clamped and set up as README step 5 says"


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> tuple[Path, Path]:
    """A tiny pipeline run up to export: (pipeline file, job folder)."""
    folder = tmp_path_factory.mktemp("confirm")
    path = write_pipeline(folder)
    job = folder / "job"
    with CliRunner().isolation() as _, pytest.raises(SystemExit) as exc:
        main(["run", str(path), "--out", str(job), "--until", "export"])
        raise SystemExit(0)
    assert exc.value.code == 0
    return path, job


def _port(pipeline: Path) -> str:
    """The pipeline's [stream] port (the emulator)."""
    text = pipeline.read_text()
    start = text.index('port = "') + len('port = "')
    return text[start : text.index('"', start)]


def _acks(job: Path) -> int:
    journal = job / "stream" / "journal.jsonl"
    if not journal.is_file():
        return 0
    return sum(json.loads(line).get("ev") == "ack" for line in journal.read_text().splitlines())


@pytest.mark.parametrize("command", ["run", "stream"])
@pytest.mark.parametrize(
    ("stdin", "refusal"),
    [
        ("y\n", None),
        ("n\n", "error: not confirmed; nothing was sent"),
        ("", "error: no answer came to the question (stdin closed): answer y, or pass --yes"),
    ],
)
def test_a_piped_answer_is_read_by_run_as_by_stream(
    exported, tmp_path, monkeypatch, command, stdin, refusal
):
    path, finished = exported
    job = tmp_path / "job"
    shutil.copytree(finished, job)
    # as a real machine, which run asks about only there (stream asks the emulator too)
    monkeypatch.setattr("scratchfab.pipeline.runner.is_emulator", lambda port: False)
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    args = {
        "run": ["run", str(path), "--out", str(job), "--from", "stream"],
        "stream": ["stream", str(job), "--port", _port(path)],
    }[command]
    with CliRunner().isolation(input=stdin) as (_, stderr, _), pytest.raises(SystemExit) as exc:
        main(args)
        raise SystemExit(0)
    err = stderr.getvalue().decode()
    assert QUESTION in err  # asked, whatever stdin is
    assert "Traceback" not in err and "not a terminal" not in err
    if refusal is None:
        assert exc.value.code == 0, err
        assert _acks(job) > 0
    else:
        assert exc.value.code == 2
        lines = err.rstrip().splitlines()
        if command == "run":  # the error, then where the report is
            assert lines.pop().startswith("report: ")
        assert lines[-1].startswith(refusal)
        assert _acks(job) == 0  # nothing was sent
