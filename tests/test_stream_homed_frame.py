"""The advice after a lost position fits the profile's coordinates.

"Home the machine ($H), or unlock it ($X) and set the work zero again on the board's
origin" contradicts a machine-coordinate profile (grbl-3018-diamond: `[envelope]
coordinates = "machine"`, which refuses a work offset): for it, homing alone is said. A
work-coordinate profile, or none known (no --machine), keeps both.
"""

from __future__ import annotations

import pytest
from test_stream import SIM
from test_stream_cli_input import _stream
from test_stream_homed import alarmed  # noqa: F401  (the fixture)

from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender import machine_coordinates
from scratchfab.machine.sender_journal import default_journal_path, read_journal
from scratchfab.machine.stream_job import lost_position_warning

WORK_ZERO = "set the work zero again on the board's origin"


@pytest.mark.parametrize(
    ("machine", "answers"),
    [
        ("grbl-3018-diamond", ""),
        ("grbl-3018-diamond", "n\n"),
        ("grbl-plotter-scribe", ""),
        (None, ""),
        (None, "n\n"),
    ],
)
def test_the_homing_advice_follows_the_profiles_coordinates(
    alarmed,  # noqa: F811
    tmp_path,
    monkeypatch,
    machine,
    answers,
):
    job, _ = alarmed
    frame = machine is not None and load_profile(machine).envelope.coordinates == "machine"
    assert frame == (machine == "grbl-3018-diamond")  # the bundled profiles, as they are
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    args = [str(job), "--port", SIM, "--resume"] + (["--yes"] if not answers else [])
    args += ["--machine", machine, "--z-threshold", "0"] if machine is not None else []
    code, _, err = _stream(args, answers)
    assert code == 2 and "Traceback" not in err
    last = err.rstrip().splitlines()[-1]
    assert "home the machine ($H)" in last and "--homed" in last
    # a work-coordinate profile names its exact command (the plotter's board at X20 Y20)
    zero = WORK_ZERO if machine is None else "jog to the board's lower-left corner and send"
    assert (zero in last) == (not frame), last
    assert ("G10 L20 P0 X20 Y20" in last) == (machine == "grbl-plotter-scribe"), last
    assert ("unlock it ($X) and set" in last) == (not frame), last
    if frame:
        assert "(its profile works in GRBL's machine coordinates: set no work zero)" in last
    if answers:  # the question asks only what fits the frame
        question = "Was the machine homed ($H), or its work zero set again"
        assert (question in err) == (not frame), err
        assert "Was the machine homed ($H) since then" in err or not frame


def test_a_reset_stop_warning_names_the_work_zero_only_in_work_coordinates(alarmed):  # noqa: F811
    job, _ = alarmed
    events = read_journal(default_journal_path(job))
    for event in events:
        if event["ev"] == "alarm":  # the run ended in a reset of the controller's own
            event.update(ev="stop", reason="reset", lost=True)
    for name in ["grbl-3018-diamond", "grbl-plotter-scribe", None]:
        profile = None if name is None else load_profile(name)
        warning = lost_position_warning(events, profile)
        assert warning is not None and "homed ($H)" in warning
        assert ("work zero" in warning) == (not machine_coordinates(profile)), warning


def test_the_senders_reconnect_advice_rezeroes_only_in_work_coordinates():
    from scratchfab.machine.sender import link_lost_next, silent_next

    for name in ["grbl-3018-diamond", "grbl-plotter-scribe", None]:
        profile = None if name is None else load_profile(name)
        for text in (link_lost_next(profile), silent_next(profile)):
            assert "re-home" in text and "--resume" in text
            assert ("re-zero" in text) == (not machine_coordinates(profile)), text
