"""Where the profile's travel and GRBL's ``$130``-``$132`` disagree, fix the one that is wrong.

A 3018 owner's profile said 400 mm of X travel while GRBL had ``$130=300``: stream refused
rightly, but on an emulator whose URL set ``$130=300`` it suggested adding ``$130=400`` to
that URL (a key given twice, which the emulator refuses, and a rehearsal machine made to
match the wrong profile). Where the setting is the machine's own (a real controller, or a
URL that sets the key) the advice is to fix the profile's ``[envelope]`` or the setting;
the URL keys are named only for an emulator running with GRBL's default travel, and never
a key the URL has. Following the advice streams the job.
"""

from __future__ import annotations

import re
from pathlib import Path

from test_stream_cli_input import _stream

from scratchfab.machine.profile import load_profile
from scratchfab.machine.protocol_grblsim import grblsim_query

#: Fits X -300..0: X -290..-280, Y -160, Z -30.2..-27 in machine coordinates.
JOB = "G21 G90\nG0 Z-27\nG0 X-290 Y-160\nG1 Z-30.2 F200\nG1 X-280 F600\nG0 Z-27\nM2\n"
#: A homed GRBL with soft limits on: travel refusals are refusals.
SIM = "grblsim://?baud=0&time_scale=0&soft_limits=1&homed=1"


def _profile(tmp_path: Path, x_mm: str, y_mm: str = "[-180.0, 0.0]") -> Path:
    """The bundled 3018 profile with its X and Y envelope replaced (the owner's copy)."""
    text = Path(load_profile("grbl-3018-diamond").source).read_text()
    for name, value in (("x_mm", x_mm), ("y_mm", y_mm)):
        text, n = re.subn(rf"^{name} = \[[^]]*\]", f"{name} = {value}", text, flags=re.M)
        assert n == 1, name
    path = tmp_path / f"mine{len(list(tmp_path.glob('mine*')))}.toml"
    path.write_text(text)
    return path


def _run(tmp_path: Path, port: str, profile: Path) -> tuple[int, str]:
    job = tmp_path / "job.gcode"
    job.write_text(JOB)
    code, out, err = _stream([str(job), "--port", port, "--machine", str(profile), "--yes"], "")
    assert "Traceback" not in err, err
    return code, err + out


def _urls(text: str) -> list[str]:
    return re.findall(r"--port '(grblsim://[^']*)'", text)


def test_a_url_setting_the_travel_is_the_machine_the_profile_must_match(tmp_path):
    wrong = _profile(tmp_path, "[-400.0, 0.0]")
    port = f"{SIM}&$130=300&$131=180&$132=45"
    code, said = _run(tmp_path, port, wrong)
    last = said.strip().splitlines()[-1] if code else said
    assert code == 2 and "expects 400 mm of X travel but GRBL has $130=300" in said, said
    assert _urls(said) == [], said  # no emulator hint: its URL already sets $130
    assert "x_mm = [-400, 0] (400 mm) and GRBL's $130=300 disagree" in last, last
    fix = re.search(r"set the profile's x_mm = \[(-?\d+), (-?\d+)\]", last)
    assert fix is not None and "set $130=400 in the emulator's URL" in last, last
    # the profile's fix, as said, streams the job on the same machine
    fixed = _profile(tmp_path, f"[{fix[1]}.0, {fix[2]}.0]")
    assert load_profile(fixed).envelope.max_travel_mm[0] == 300.0
    code, said = _run(tmp_path, port, fixed)
    assert code == 0 and "done:" in said, said


def test_an_emulator_with_default_travel_gets_only_the_keys_its_url_lacks(tmp_path):
    # X as bundled 300 mm (default $130=200 is short); Y 250 mm, URL sets $131=180
    profile = _profile(tmp_path, "[-300.0, 0.0]", "[-250.0, 0.0]")
    port = f"{SIM}&$131=180&$132=45"
    code, said = _run(tmp_path, port, profile)
    last = said.strip().splitlines()[-1]
    assert code == 2, said
    (url,) = _urls(last)
    query = grblsim_query(url)  # raises on a key given twice
    assert query is not None and query["$130"] == "300" and query["$131"] == "180", url
    assert "y_mm = [-250, 0] (250 mm) and GRBL's $131=180 disagree" in last, last
    assert "x_mm = [" not in last, last  # X is the emulator's default, not a disagreement


def test_a_real_controller_is_told_to_fix_the_profile_or_its_setting(tmp_path, monkeypatch):
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    wrong = _profile(tmp_path, "[-400.0, 0.0]")
    code, said = _run(tmp_path, f"{SIM}&$130=300&$131=180&$132=45", wrong)
    last = said.strip().splitlines()[-1]
    assert code == 2 and _urls(said) == [], said
    assert "if the machine travels 300 mm, set the profile's x_mm = [-300, 0]" in last, last
    assert "if it travels 400 mm, set $130=400 on the controller" in last, last
