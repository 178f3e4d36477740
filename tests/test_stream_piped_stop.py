"""Ctrl-C while stdin is a pipe: the resume-or-stop question is not read from it.

``yes | scratchfab stream JOB`` answers the "stream now?" question; a Ctrl-C later found
``y`` at the resume-or-stop question, which click refuses and asks again, for ever
(15,283 lines in 3 s while the machine was held). Off a terminal the answer is stop,
said once.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

from test_stream import _CLI, write_job

from scratchfab.cli.stream_cmd import ask_resume_or_stop


def test_ctrl_c_under_yes_stops_once(tmp_path):
    job = tmp_path / "job.gcode"
    write_job(job, 400)  # about 4 s at this time scale
    args = ["stream", str(job), "--port", "grblsim://?baud=0&time_scale=0.02"]
    answers = tmp_path / "yes.txt"
    answers.write_text("y\n" * 20000)  # what `yes |` gives, a file as stdin: no terminal
    with answers.open("rb") as stdin:
        proc = subprocess.Popen(
            [sys.executable, "-c", _CLI, *args, "--banner-timeout", "0.3"],
            stdin=stdin,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            start_new_session=True,
        )
    assert proc.stderr is not None and proc.stdout is not None
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(proc.stderr), daemon=True)
    reader.start()
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and not any(b" lines  elapsed " in line for line in err):
        time.sleep(0.05)  # the first progress line: streaming (the question answered y)
    time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        out = proc.stdout.read().decode()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    reader.join(10)
    text = b"".join(err).decode()
    assert proc.returncode == 130, text
    assert "is not one of" not in text and text.count("[r]esume or [s]top") == 1, text
    assert "stopped by the user after line " in out + text, text


def test_the_question_off_a_terminal_is_stop_without_reading_stdin(monkeypatch):
    said: list[str] = []
    read: list[str] = []
    monkeypatch.setattr("scratchfab.cli.stream_cmd.stdin_is_a_terminal", lambda: False)
    monkeypatch.setattr("click.prompt", lambda *a, **k: read.append("asked") or "r")
    assert ask_resume_or_stop(said.append) == "stop"
    assert len(said) == 1 and not read
