"""The emulator's travel comes from its URL; a Python caller's paths may be ``str``.

A plain ``grblsim://`` has GRBL's default travel ($130-$132 = 200 mm), so a job for a
bigger machine is refused there: the refusal names the URL keys to give, from the
profile's envelope (else the job's span); streaming with them is not refused.
"""

from __future__ import annotations

import re

from test_stream_cli_input import _stream

from scratchfab.machine.profile import load_profile
from scratchfab.machine.stream_job import StreamCallbacks, StreamRequest, stream_file

PLOT = ["G21 G90 G17 G94", "M5", "G1 X10 Y20 F3000", "M3 S60", "G4 P0.1", "G1 X250 Y20 F1200",
        "M5", "G4 P0.1", "G1 X0 Y0 F3000", "M2"]  # fmt: skip


SIM = "grblsim://?baud=0&time_scale=0.01"


def _url(err: str) -> str | None:
    found = re.search(r"--port '(grblsim://[^']*)'", err)
    return None if found is None else found[1]


def test_a_refused_travel_on_the_emulator_names_its_url_keys(tmp_path):
    job = tmp_path / "plot.gcode"
    job.write_text("\n".join(PLOT) + "\n")
    machine = ["--machine", "grbl-plotter-scribe", "--yes"]
    code, _, err = _stream([str(job), "--port", SIM, *machine], "")
    assert code == 2 and "but GRBL's travel is $130=200 mm" in err, err
    env = load_profile("grbl-plotter-scribe").envelope
    assert env.x_mm[1] - env.x_mm[0] == 300.0  # as bundled: wider than GRBL's default
    url = _url(err)
    assert url == f"{SIM}&$130=300", err
    code, out, err = _stream([str(job), "--port", url, *machine], "")
    assert code == 0 and "done:" in out, err
    # no profile: the job's own span (X0 to X250); a URL without a query gets one
    code, _, err = _stream([str(job), "--port", "grblsim://", "--yes"], "")
    assert code == 2 and _url(err) == "grblsim://?$130=250", err


def test_a_str_path_is_taken_as_a_path(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z2\nG1 X1 Y1 F600\nM2\n")
    said: list[str] = []
    request = StreamRequest(gcode=str(job), port=SIM, journal=str(tmp_path / "j"))
    assert request.gcode == job and request.journal == tmp_path / "j"
    stream_file(request, StreamCallbacks(lambda p: None, said.append, lambda: "stop", None))
    assert (tmp_path / "j").is_file()
