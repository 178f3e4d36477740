"""A machine without homing (`$22=0`) is not told to home it.

`$H` answers error:5 where homing is off, so after a reset or an alarm that may have lost
the position such a machine is told to unlock it (`$X`) and set the work zero again. The
sender knows `$22` from the `$$` it reads at connect, and the journal's `start` records it
for a resume's question, asked before connecting; where it is not known (an older
journal) the words are as before.
"""

from __future__ import annotations

import json
import time

import pytest
from test_stream_cli_input import _stream
from test_stream_reset_fault import PORT, reset_job  # noqa: F401  (the fixture)

from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender import (
    Streamer,
    StreamFault,
    StreamOptions,
    link_lost_next,
    machine_coordinates,
    open_port,
    refind,
    silent_next,
    unlock_advice,
)
from scratchfab.machine.sender_journal import default_journal_path, read_journal, run_homing
from scratchfab.machine.stream_job import lost_position_warning

PROFILES = ["grbl-3018-diamond", "grbl-plotter-scribe", None]
OFF = "homing is off, $22=0: $H answers error:5"
ZERO = "set the work zero again on the board's origin"
#: The bundled plotter's board: its lower-left corner at [board] offset_mm = [20, 20].
PLOTTER_ZERO = (
    "set the work zero again: jog to the board's lower-left corner and send "
    "`G10 L20 P0 X20 Y20` there"
)


def _zero(name):
    """How the work zero is set again: the profile's exact command, else the words."""
    if name is None:
        return ZERO
    if name != "grbl-plotter-scribe":
        return "set the work zero again: jog to the board's"
    board = load_profile(name).board
    assert (board.offset_mm, board.origin) == ((20.0, 20.0), "lower-left")  # as bundled
    return PLOTTER_ZERO


@pytest.mark.parametrize("name", PROFILES)
@pytest.mark.parametrize("homing", [True, False, None])
def test_the_advice_homes_only_where_homing_is_on_or_unknown(name, homing):
    profile = None if name is None else load_profile(name)
    frame = machine_coordinates(profile)
    how = refind(profile, homing)
    texts = [how.do, how.done, link_lost_next(profile, homing), silent_next(profile, homing)]
    if homing is not False:
        # as before $22 was read: the profile's frame alone decides
        assert how == refind(profile, None)
        assert "home the machine ($H)" in how.do and OFF not in how.do
        assert (_zero(name) in how.do) == (not frame)
        assert "X0 Y0" not in how.do
        assert unlock_advice(profile, homing) is None
        return
    advice = unlock_advice(profile, homing)
    assert advice is not None and advice.startswith("unlock it ($X)") and OFF in advice
    for lost in (True, False):  # a tool that may be down is raised before the zeroing
        ordered = unlock_advice(profile, homing, lost, raise_it="RAISE")
        assert ordered is not None and ordered.startswith("unlock it ($X) yourself, RAISE, then")
        assert ordered.endswith(f"{how.again} ({OFF})"), ordered
    if frame:  # machine coordinates: only homing finds them, so homing is to be turned on
        assert all("$22=1" in text for text in (how.do, how.done, advice)), how
        # a 3018 often has no homing switches: $22=1 only where it has them
        switches = "if it has homing switches, turn homing on ($22=1)"
        assert all(switches in text for text in (how.do, how.verb, advice)), how
        assert (
            'without switches a work-coordinate profile fits it ([envelope] coordinates = "work"'
            in how.do
        )
        assert ZERO not in how.do and "set no work zero" in how.do
    else:
        assert how.do == f"unlock it ($X) and {_zero(name)} ({OFF})"
        assert "$H" not in how.done and "$X" in how.done
        assert all("re-home" not in text for text in texts[2:]), texts
        assert all("re-zero" in text for text in texts[2:]), texts


@pytest.mark.parametrize("homing", [True, False, None])
def test_an_alarm_at_speed_asks_what_fits_homing(homing):
    events = [
        {"ev": "start", "sha256": "x", "resume": False, "blocks": 3},
        {"ev": "alarm", "code": 1, "lost": True},
        {"ev": "stop", "reason": "alarm", "executed_through": 0},
    ]
    warning = lost_position_warning(events, None, homing)
    assert (
        warning is not None and "after an unlock ($X) alone the strokes would land off" in warning
    )
    assert ("homed ($H) since" in warning) == (homing is not False), warning
    assert ("unlocked ($X) and its work zero set again on the board's origin since" in warning) == (
        homing is False
    )


def test_a_controller_in_alarm_with_homing_off_is_told_to_unlock_and_zero():
    """ALARM:3 (a reset in motion) on a controller without homing: the connect's refusal
    names $X and the work zero, not $H (test_stop_soft_limit: with homing on, $H)."""
    port = open_port("grblsim://?baud=0&time_scale=1", 115200)
    try:
        time.sleep(0.2)
        port.write(b"G1X50F100\n")
        time.sleep(0.3)
        port.write(b"\x18")  # a reset while the machine moves
        with pytest.raises(StreamFault) as exc:
            Streamer(port, StreamOptions(banner_timeout=0.3)).connect()
    finally:
        port.close()
    assert any(e["ev"] == "alarm" and e["code"] == 3 for e in port.sim.record)
    text = str(exc.value)
    assert text.startswith("controller is in Alarm: unlock it ($X)")
    assert ZERO in text and OFF in text and "home it ($H)" not in text


@pytest.mark.parametrize("recorded", [True, False])
def test_a_resume_after_a_reset_names_the_work_zero_where_the_journal_says_homing_is_off(
    reset_job,  # noqa: F811
    tmp_path,
    monkeypatch,
    recorded,
):
    """The journal records $22 (the emulator's 0); a journal without it (older) keeps the
    profile's words, which name $H."""
    job, _ = reset_job
    journal = default_journal_path(job)
    assert run_homing(read_journal(journal)) is False
    if not recorded:
        lines = [json.loads(line) for line in journal.read_text().splitlines()]
        for ev in lines:
            ev.pop("homing", None)
        journal.write_text("".join(json.dumps(ev) + "\n" for ev in lines))
        assert run_homing(read_journal(journal)) is None
    monkeypatch.setattr("scratchfab.machine.stream_job.is_emulator", lambda port: False)
    rec = tmp_path / "rec.jsonl"
    code, _, err = _stream([str(job), "--port", f"{PORT}&record={rec}", "--resume", "--yes"], "")
    last = err.rstrip().splitlines()[-1]
    assert code == 2 and last.startswith("error: refusing to resume with --yes: ")
    assert not rec.exists()  # refused before connecting
    if recorded:
        assert f"unlock it ($X) and {ZERO} ({OFF}), then run the same command with --homed" in last
        assert "$H)" not in last.replace(OFF, "")
    else:
        assert f"home the machine ($H), or unlock it ($X) and {ZERO}, then run" in last
