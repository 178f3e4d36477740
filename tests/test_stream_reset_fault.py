"""A controller that resets itself mid-job (a power or USB glitch): lines named, resume warned.

A Ctrl-C stop names the last line GRBL accepted, the last it surely ran and where a resume
restarts; the reset's fault named only the first. Its position may be lost (a brown-out
boots at another one), yet `--resume` said nothing of it, where after an alarm that lost
the position it warns, asks on a machine and refuses under --yes without --homed. And
"the tool was NOT raised" came twice, as a line of its own and in the error's clauses.
"""

from __future__ import annotations

import re

import pytest
from test_stream import read_record
from test_stream_cli_input import _gcode_received, _stream

from scratchfab.machine.sender_journal import default_journal_path, read_journal

PORT = "grblsim://?baud=0&time_scale=0.02"


@pytest.fixture()
def reset_job(tmp_path):
    """A 12-stroke job whose controller reset itself after its 20th line: (G-code, stderr)."""
    job = tmp_path / "job.gcode"
    lines = ["G21 G90", "G0 Z2"]
    for k in range(12):
        lines += [f"G0 X{2 * k} Y0", "G1 Z-0.05 F200", f"G1 X{2 * k} Y8 F600", "G0 Z2"]
    job.write_text("\n".join(lines) + "\n")
    code, _, err = _stream([str(job), "--port", f"{PORT}&reset_after=20", "--yes"], "")
    assert code == 3, err
    return job, err


def test_the_reset_fault_names_the_lines_and_the_tool_once(reset_job):
    job, err = reset_job
    error = next(line for line in err.splitlines() if line.startswith("error: "))
    found = re.search(
        r"the controller reset itself mid-job \(its banner came\) after line (\d+) \(the last "
        r"one GRBL accepted; the machine had run (through line \d+|no line): a resume restarts "
        r"at line (\d+)\)",
        error,
    )
    assert found, error
    stop = [ev for ev in read_journal(default_journal_path(job)) if ev["ev"] == "stop"][-1]
    acked = [ev["line"] for ev in read_journal(default_journal_path(job)) if ev["ev"] == "ack"]
    assert int(found[1]) == acked[-1]  # the last line GRBL accepted, as journaled
    through = stop["executed_through"]
    assert found[2] == ("no line" if through < 0 else f"through line {acked[through]}")
    assert stop["lost"] is True
    assert err.count("the tool was NOT raised") == 1, err
    # where a resume restarts is where --resume does restart
    code, out, err = _stream([str(job), "--port", PORT, "--resume", "--yes"], "")
    assert code == 0, err
    assert f"resuming at line {found[3]} " in out


def test_a_resume_after_the_reset_warns_and_repeats_it_on_the_emulator(reset_job):
    job, _ = reset_job
    code, _, err = _stream([str(job), "--port", PORT, "--resume", "--yes"], "")
    assert code == 0, err
    warnings = [line for line in err.splitlines() if "a reset of the controller" in line]
    assert len(warnings) == 2 and warnings[-1].startswith("warning (repeated): ")
    # the emulator's homing is off ($22=0, as the journal recorded): $H would answer error:5
    assert "unlocked ($X) and its work zero set again on the board's origin" in warnings[0]
    assert "$H" not in warnings[0]


def test_a_resume_after_the_reset_on_a_machine_needs_homed(reset_job, tmp_path, monkeypatch):
    job, _ = reset_job
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    rec = tmp_path / "rec.jsonl"
    code, _, err = _stream([str(job), "--port", f"{PORT}&record={rec}", "--resume", "--yes"], "")
    last = err.rstrip().splitlines()[-1]
    assert code == 2 and last.startswith("error: refusing to resume with --yes: ")
    assert "a reset of the controller" in last and "--homed" in last
    assert not rec.exists()  # refused before connecting
    code, out, err = _stream(
        [str(job), "--port", f"{PORT}&record={rec}", "--resume", "--yes", "--homed"], ""
    )
    assert code == 0, err
    assert "note: the run before this resume ended with a reset of the controller" in err
    assert _gcode_received(read_record(rec))
