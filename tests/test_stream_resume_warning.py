"""A ``--resume`` after an alarm that may have lost the position warns in its closing lines.

Grbl 1.1 answers ``$H`` and ``$X`` alike, so the sender cannot tell whether the machine
was homed since: the warning comes once connected, and with ``--yes`` nothing waits on it
while the progress scrolls it away, so the resumed run's closing lines repeat it.
"""

from __future__ import annotations

import json

import pytest
from stream_helpers import stopped_after

from scratchfab.cli import main
from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.sender_program import load_program
from scratchfab.machine.stream_job import lost_position_warning


@pytest.mark.parametrize("lost", [True, "maybe"])
def test_the_lost_position_warning_is_repeated_after_the_resumed_run(tmp_path, capsys, lost):
    job = tmp_path / "job.gcode"
    lines = ["G21 G90", "G0 Z2"]
    for k in range(12):
        lines += [f"G0 X{2 * k} Y0", "G1 Z-0.05 F200", f"G1 X{2 * k} Y8 F600", "G0 Z2"]
    job.write_text("\n".join(lines) + "\n")
    journal = default_journal_path(job)
    stopped_after(journal, load_program(job), 12, "grblsim://?baud=0&time_scale=0.02")
    # the alarm the stop met (as test_stop_alarm's emulator runs journal it), before the stop
    text = journal.read_text().splitlines()
    alarm = {"ev": "alarm", "code": 2, "lost": lost, "time": "2026-01-01T00:00:00"}
    journal.write_text("\n".join([*text[:-1], json.dumps(alarm), text[-1]]) + "\n")
    warning = lost_position_warning(read_journal(journal))
    assert warning is not None
    capsys.readouterr()
    main(["stream", str(job), "--port", "grblsim://?baud=0&time_scale=0.001", "--resume",
          "--yes", "--banner-timeout", "0.3"])  # fmt: skip
    out, err = capsys.readouterr()
    assert "done:" in out
    shown = [line for line in err.splitlines() if line.strip()]
    assert sum(warning in line for line in shown) == 2
    assert shown[-1] == f"warning (repeated): {warning}"
    assert f"warning: {warning}" in shown
