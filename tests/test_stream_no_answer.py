"""A question that gets no answer (stdin closed) names how that question is answered.

"answer y, or pass --yes" holds only for the ordinary "Stream ...?" question: --yes
refuses the lost-position, partial-board and stale-plan questions, so their message
names their own way (--homed; an answer on a terminal or through a pipe). After --check
the controller got every line in check mode, which moves nothing: "nothing was cut".
"""

from __future__ import annotations

import shutil

import pytest
from stream_helpers import alarmed_job, hard_limit_run
from test_stream import SIM, read_record, write_job
from test_stream_cli_input import _gcode_received, _stream
from test_stream_restart import _partial_job

from scratchfab.cli import main


@pytest.fixture
def real_port(monkeypatch):
    """The emulator taken for a machine: it is asked what a machine is asked."""
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)


def _last(err: str) -> str:
    return err.rstrip().splitlines()[-1]


@pytest.mark.parametrize(("terminal", "answers"), [(True, ""), (False, "y\ny\n")])
def test_no_answer_to_the_homed_question_names_homed(
    tmp_path, monkeypatch, real_port, terminal, answers
):
    """On a terminal closed before the answer, or from a pipe (`yes |` would answer a
    question only a person can: was the machine homed?), the resume is refused before
    connecting, naming --homed; a pipe still answers the other questions."""
    monkeypatch.setattr("scratchfab.cli.options.stdin_is_a_terminal", lambda: terminal)
    job = tmp_path / "job.gcode"
    alarmed_job(job, True, 1)
    rec = tmp_path / "rec.jsonl"
    code, _, err = _stream([str(job), "--port", f"{SIM}&record={rec}", "--resume"], answers)
    last = _last(err)
    why = "stdin closed" if terminal else "stdin is not a terminal"
    assert code == 2 and last.startswith(f"error: no answer came to the question ({why}"), err
    assert "Was the machine homed ($H)" in err  # the question, said
    assert "then run the same command with --homed" in last and "nothing was sent" in last
    assert "pass --yes" not in last and "Traceback" not in err
    assert not rec.exists()  # refused before connecting


def test_no_answer_to_the_partial_board_question_does_not_name_yes_as_the_way(tmp_path, real_port):
    layout, _ = _partial_job(tmp_path / "made", outside=3, clipped=1)
    copy = tmp_path / "board-copy.gcode"
    shutil.copy(layout.export_file("gcode"), copy)
    rec = tmp_path / "rec.jsonl"
    code, _, err = _stream([str(copy), "--port", f"{SIM}&record={rec}"], "")
    last = _last(err)
    assert code == 2 and "Cut a partial board?" in err
    assert last.startswith("error: no answer came to the question (stdin closed)")
    assert "answer y on a terminal or through a pipe (--yes refuses this question)" in last
    assert "pass --yes" not in last and "nothing was sent" in last
    assert not rec.exists() or not _gcode_received(read_record(rec))


@pytest.mark.parametrize("answer", ["n\n", ""])
def test_after_check_mode_a_refused_stream_says_nothing_was_cut(tmp_path, real_port, answer):
    job = tmp_path / "job.gcode"
    write_job(job, 3)
    rec = tmp_path / "rec.jsonl"
    code, _, err = _stream([str(job), "--port", f"{SIM}&record={rec}", "--check"], answer)
    last = _last(err)
    assert code == 2 and "nothing was cut (check mode moves nothing)" in last, err
    assert "nothing was sent" not in last
    # every line went to the controller, in check mode ($C), and nothing after it
    record = read_record(rec)
    assert any(e["ev"] == "rx" and e["text"] == "$C" for e in record)
    assert _gcode_received(record)


def test_run_without_an_answer_to_the_homed_question_names_homed(tmp_path, monkeypatch, capsys):
    """`run` asks through the same question: a closed stdin names --homed there too."""
    from click.testing import CliRunner

    path, job, journal = hard_limit_run(tmp_path)
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    monkeypatch.setattr("scratchfab.pipeline.runner.is_emulator", lambda port: False)
    text = journal.read_bytes()
    with CliRunner().isolation(input="y\ny\n") as (_, stderr, _):  # a pipe: not taken
        with pytest.raises(SystemExit) as exc:
            main(["run", str(path), "--out", str(job), "--from", "stream"])
        err = stderr.getvalue().decode()
    assert exc.value.code == 2, err
    error = next(line for line in err.splitlines() if line.startswith("error: "))
    assert error.startswith("error: no answer came to the question (stdin is not a terminal")
    assert "--homed" in error and "pass --yes" not in error
    assert journal.read_bytes() == text  # nothing was sent
