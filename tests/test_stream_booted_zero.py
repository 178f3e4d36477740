"""A controller without homing that boots as the port opens keeps an earlier work offset.

With ``$22=0`` GRBL's machine zero is where the tool stands at boot; an Arduino-based
controller boots when the port opens (its banner comes unasked), and the G54 offset it
keeps in EEPROM was set in another session's frame. A first stream is warned once at
connect (not refused). Every ``grblsim://`` open is such a boot; its ``wco=`` is the
EEPROM's offset.
"""

from __future__ import annotations

import pytest
from test_stream import write_job
from test_stream_cli_input import _stream

WARNING = "warning: the controller booted as the port opened (its banner came)"


@pytest.mark.parametrize(
    ("query", "warned"),
    [
        ("wco=12,-7,0", True),  # an offset set in an earlier session
        ("wco=0,0,0", False),  # the safe workflow: machine zero is the work zero
        ("wco=-100,-100,-10&soft_limits=1&homed=1", False),  # homing references it
    ],
)
def test_a_booted_controller_with_an_offset_is_warned_once(tmp_path, query, warned):
    job = tmp_path / "job.gcode"
    write_job(job, 2)
    port = f"grblsim://?baud=0&time_scale=0.01&{query}"
    code, _, err = _stream([str(job), "--port", port, "--yes"], "")
    assert code == 0, err
    assert err.count(WARNING) == (1 if warned else 0), err
    if warned:
        line = next(x for x in err.splitlines() if x.startswith(WARNING))
        assert "keeps (X12 Y-7 Z0 mm, set in an earlier session)" in line
        assert "`G10 L2 P0 X0 Y0 Z0`" in line
        assert "--zero-here" not in line  # no profile: no board point to zero at
