"""What `scratchfab stream` makes of its standard input and of the GCODE argument."""

from __future__ import annotations

import pytest
from click.testing import CliRunner
from test_stream import read_record, write_job

from scratchfab.cli import main


def _stream(args: list[str], stdin: str) -> tuple[int, str, str]:
    """Run ``scratchfab stream ARGS`` on the emulator with ``stdin``; (exit code, out, err)."""
    with CliRunner().isolation(input=stdin) as (stdout, stderr, _):
        with pytest.raises(SystemExit) as exc:
            main(["stream", *args, "--banner-timeout", "0.3"])
            raise SystemExit(0)
        return exc.value.code, stdout.getvalue().decode(), stderr.getvalue().decode()


def _gcode_received(record: list[dict]) -> bool:
    return any(e["ev"] == "rx" and e["text"].startswith(("G0", "G1")) for e in record)


def test_a_closed_stdin_at_the_question_says_no_answer_came(tmp_path):
    """EOF at "Stream ...?" is no answer, not a Ctrl-C: say so and how to answer, exit 2
    (a refusal, as answering n), not "aborted" with Ctrl-C's 130."""
    job = tmp_path / "job.gcode"
    write_job(job, 2)
    rec = tmp_path / "rec.jsonl"
    code, _, err = _stream([str(job), "--port", f"grblsim://?baud=0&record={rec}"], "")
    assert code == 2
    last = err.rstrip().splitlines()[-1]
    assert last.startswith("error: no answer came") and "stdin closed" in last
    assert "answer y, or pass --yes" in last and "nothing was sent" in last
    assert "aborted" not in err
    assert not _gcode_received(read_record(rec))


@pytest.mark.parametrize("given", ["job", "job/export"])
def test_a_job_folder_streams_its_exported_gcode_and_says_so(tmp_path, given):
    """`stream JOB` (or `stream JOB/export`) is `stream JOB/export/board.gcode`, its journal
    in JOB/stream/."""
    job = tmp_path / "job"
    (job / "export").mkdir(parents=True)
    write_job(job / "export" / "board.gcode", 2)
    rec = tmp_path / "rec.jsonl"
    port = f"grblsim://?baud=0&time_scale=0.001&record={rec}"
    code, out, err = _stream([str(tmp_path / given), "--port", port, "--yes"], "")
    assert code == 0, err
    what = "a job's export folder" if given.endswith("export") else "a job folder"
    assert f"{tmp_path / given} is {what}: streaming {job / 'export' / 'board.gcode'}" in err
    assert "done:" in out and (job / "stream" / "journal.jsonl").is_file()
    assert _gcode_received(read_record(rec))


def test_a_folder_without_gcode_says_where_it_would_be_and_to_export(tmp_path):
    job = tmp_path / "job"
    (job / "toolpath").mkdir(parents=True)
    rec = tmp_path / "rec.jsonl"
    code, _, err = _stream([str(job), "--port", f"grblsim://?baud=0&record={rec}"], "")
    assert code == 2
    last = err.rstrip().splitlines()[-1]
    assert last.startswith(f"error: {job} is a folder")
    assert f"{job / 'export' / 'board.gcode'}, which does not exist" in last
    assert f"scratchfab export {job} --format gcode" in last
    assert "is a directory" not in err and not rec.exists()
