"""A ``--resume`` after an alarm that may have lost the position warns in its closing lines.

Grbl 1.1 answers ``$H`` and ``$X`` alike, so the sender cannot tell whether the machine
was homed since: the warning comes once connected, and with ``--yes`` nothing waits on it
while the progress scrolls it away, so the resumed run's closing lines repeat it.
"""

from __future__ import annotations

import pytest
from stream_helpers import alarmed_job

from scratchfab.cli import main


@pytest.mark.parametrize("lost", [True, "maybe"])
def test_the_lost_position_warning_is_repeated_after_the_resumed_run(tmp_path, capsys, lost):
    job = tmp_path / "job.gcode"
    # the alarm the stop met (as test_stop_alarm's emulator runs journal it), before the stop
    warning = alarmed_job(job, lost, 2)
    capsys.readouterr()
    main(["stream", str(job), "--port", "grblsim://?baud=0&time_scale=0.001", "--resume",
          "--yes", "--banner-timeout", "0.3"])  # fmt: skip
    out, err = capsys.readouterr()
    assert "done:" in out
    shown = [line for line in err.splitlines() if line.strip()]
    assert sum(warning in line for line in shown) == 2
    assert shown[-1] == f"warning (repeated): {warning}"
    assert f"warning: {warning}" in shown
