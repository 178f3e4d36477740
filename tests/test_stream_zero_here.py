"""``stream --zero-here``: the work zero set where the tool stands, once connected.

A controller without homing that resets as its port opens (most Arduino boards) makes
machine zero wherever the tool stands then, and a work offset kept in its EEPROM from an
earlier session puts the work zero that far away. ``--zero-here`` sends the profile's own
``G10 L20 P0 X.. Y..`` after the reset, so the point where the tool stands becomes the
board's origin point. Every ``grblsim://`` open is such a boot at machine zero, its
``wco=`` the EEPROM's offset; the emulator records each move in work coordinates, so the
first move's start is where the tool stood, as the G-code counts it.
"""

from __future__ import annotations

import pytest
from test_stream import read_record
from test_stream_cli_input import _stream
from test_stream_lift import servo_job

from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender import work_zero_command
from scratchfab.machine.sender_journal import check_event, read_journal
from scratchfab.machine.stream_job import ask_if_homed

PLOTTER = "grbl-plotter-scribe"
GRBL = "$130=300&$131=200"


def _port(tmp_path, name: str, extra: str = "") -> tuple[str, object]:
    rec = tmp_path / f"{name}.jsonl"
    return f"grblsim://?baud=0&time_scale=0.01&wco=12,-7,0&{GRBL}&record={rec}{extra}", rec


def _first_exec(record: list[dict]) -> dict:
    return next(e for e in record if e["ev"] == "exec")


def _received(record: list[dict]) -> list[str]:
    return [e["text"] for e in record if e["ev"] == "rx"]


def test_zero_here_makes_the_tools_place_the_boards_origin(tmp_path):
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=2)
    x, y = load_profile(PLOTTER).board.offset_mm  # where the G-code puts the board's corner
    port, rec = _port(tmp_path, "zeroed")
    args = [str(job), "--machine", PLOTTER, "--yes"]
    code, _, err = _stream([*args, "--port", port, "--zero-here"], "")
    assert code == 0, err
    record = read_record(rec)
    start = _first_exec(record)["frm"]
    assert start[:2] == pytest.approx([x, y])  # the tool stood at the board's corner
    sent = _received(record)
    zero = next(k for k, t in enumerate(sent) if t.startswith("G21G10L20P0"))
    first_move = next(k for k, t in enumerate(sent) if t.startswith(("G0", "G1")))
    assert zero < first_move
    assert sent[zero] == "G21" + work_zero_command(load_profile(PLOTTER))[1].replace(" ", "")
    assert "warning: the controller booted as the port opened" not in err
    assert f"work offset now X{-x:g} Y{-y:g} Z0 mm" in err
    (start_event,) = [e for e in read_journal(f"{job}.journal.jsonl") if e["ev"] == "start"]
    assert start_event["zeroed"] == work_zero_command(load_profile(PLOTTER))[1]
    assert start_event["wco"][:2] == pytest.approx([-x, -y])
    # without the flag the EEPROM's offset holds: the job counts from elsewhere
    port, rec = _port(tmp_path, "kept")
    code, _, err = _stream([*args, "--port", port, "--journal", str(tmp_path / "j2.jsonl")], "")
    assert code == 0, err
    assert _first_exec(read_record(rec))["frm"][:2] == pytest.approx([-12.0, 7.0])
    assert "warning: the controller booted as the port opened" in err
    assert "jog the tool to the board's lower-left corner and stream with --zero-here" in err


@pytest.mark.parametrize(
    ("answer", "zeroed", "moved"),
    [("n\n", False, False), ("y\nn\n", True, False), ("y\ny\n", True, True)],
)
def test_without_yes_the_tools_place_is_asked_first(tmp_path, answer, zeroed, moved):
    """The zero is set once the tool's place is confirmed, before check mode and the
    stream's own question (check mode's soft limits count from it)."""
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=1)
    port, rec = _port(tmp_path, "asked")
    code, _, err = _stream([str(job), "--port", port, "--machine", PLOTTER, "--zero-here"], answer)
    assert "--zero-here: does the tool stand at the board's lower-left corner?" in err
    received = _received(read_record(rec))
    assert any(t.startswith("G21G10") for t in received) is zeroed
    assert any(t.startswith(("G0", "G1")) for t in received) is moved
    last = err.rstrip().splitlines()[-1]
    if not zeroed:
        assert code == 2 and "jog the tool to the board's lower-left corner first" in last
        assert "nothing was sent" in last
    elif not moved:
        assert code == 2 and "nothing moved (the work zero was set: `G10 L20 P0" in last
    else:
        assert code == 0, err


def test_the_checks_before_sending_count_from_the_zero_to_be_set(tmp_path):
    """A homed machine (MPos -1, -1) zeroed at the board's corner would put the job at
    positive machine X: soft limits refuse it before the zero or anything else is sent."""
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=1)
    rec = tmp_path / "rec.jsonl"
    port = f"grblsim://?baud=0&time_scale=0.01&soft_limits=1&homed=1&{GRBL}&record={rec}"
    args = [str(job), "--port", port, "--machine", PLOTTER, "--yes", "--zero-here"]
    code, _, err = _stream(args, "")
    x = load_profile(PLOTTER).board.offset_mm[0]
    assert code == 2 and f"(work offset {-1 - x:g})" in err and "nothing was sent" in err
    assert all(t.startswith("$") for t in _received(read_record(rec)))


@pytest.mark.parametrize(
    ("machine", "expected"),
    [(None, "give --machine"), ("grbl-3018-diamond", "works in GRBL's machine coordinates")],
)
def test_zero_here_without_a_work_coordinate_profile_is_refused_before_connecting(
    tmp_path, machine, expected
):
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=1)
    port, rec = _port(tmp_path, "refused")
    args = [str(job), "--port", port, "--yes", "--zero-here"]
    code, _, err = _stream(args + (["--machine", machine] if machine else []), "")
    assert code == 2 and expected in err and "nothing was sent" in err
    assert not rec.exists()  # the port was never opened


def test_a_resume_after_a_reset_with_zero_here_zeroes_again_and_goes_on(tmp_path):
    """The controller reset itself mid-job (its machine zero lost); the user jogs back to
    the corner: ``--resume --zero-here`` stands for --homed and sets the zero again."""
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=3)
    x, y = load_profile(PLOTTER).board.offset_mm
    port, _ = _port(tmp_path, "first", "&reset_after=40")
    base = [str(job), "--machine", PLOTTER, "--yes", "--zero-here"]
    code, _, err = _stream([*base, "--port", port], "")
    assert code == 3, err
    advice = "before --resume jog the tool back to the board's lower-left corner and add"
    assert advice in err  # the stop's own advice
    events = read_journal(f"{job}.journal.jsonl")
    assert events[-1]["ev"] == "stop" and events[-1]["lost"] is True
    # the EEPROM keeps the offset the first run set; the tool stands at the corner again
    port, rec = _port(tmp_path, "resumed")
    port = port.replace("wco=12,-7,0", f"wco={-x:g},{-y:g},0")
    code, out, err = _stream([*base, "--port", port, "--resume"], "")
    assert code == 0, err
    assert "--zero-here: the work zero is set again here" in err
    assert "warning (repeated)" not in err  # answered, as --homed answers it
    assert "resuming at line" in out
    record = read_record(rec)
    assert _first_exec(record)["frm"][:2] == pytest.approx([x, y])
    starts = [e for e in read_journal(f"{job}.journal.jsonl") if e["ev"] == "start"]
    assert [s["resume"] for s in starts] == [False, True]
    assert all(s["zeroed"].startswith("G10 L20 P0") for s in starts)


def test_a_refused_resume_of_a_run_zeroed_here_names_zero_here(tmp_path):
    """On a machine, under --yes, a resume after a reset is refused; where the run was
    zeroed with --zero-here the refusal names that way too."""
    profile = load_profile(PLOTTER)
    start = {"ev": "start", "sha256": "0", "blocks": 3, "resume": False, "homing": False}
    stop = {"ev": "stop", "executed_through": 1, "lost": True, "mpos": [5.0, 5.0, 0.0]}
    for zeroed, named in ((None, False), ("G10 L20 P0 X20 Y20", True)):
        first = {**start, **({} if zeroed is None else {"zeroed": zeroed})}
        with pytest.raises(ScratchfabError) as exc:
            ask_if_homed([first, stop], False, "/dev/ttyUSB0", None, print, profile, False)
        assert ("resuming with --zero-here instead" in str(exc.value)) is named


def test_a_journal_zeroed_field_must_be_a_command():
    start = {"ev": "start", "sha256": "0", "blocks": 3, "resume": False}
    assert check_event({**start, "zeroed": "G10 L20 P0 X0 Y0"}, None, "j:1") == 3
    with pytest.raises(ConfigError, match=r"j:1: 'zeroed': expected a G10 L20 command.*got 5"):
        check_event({**start, "zeroed": 5}, None, "j:1")


def test_run_passes_zero_here_to_its_stream_stage(tmp_path, capsys):
    """`scratchfab run --zero-here` zeroes as `stream --zero-here` does, before any move."""
    from conftest import write_pipeline

    from scratchfab.cli import main

    port = f'port = "grblsim://?time_scale=0&wco=12,-7,0&{GRBL}"'
    path = write_pipeline(
        tmp_path,
        formats='["gcode"]',
        edits={
            'machine = "grbl-3018-diamond"': f'machine = "{PLOTTER}"',
            'port = "grblsim://?time_scale=0&$130=300&$131=180&$132=45"': port,
        },
    )
    job = tmp_path / "job"
    with pytest.raises(SystemExit) as exc:
        main(["run", str(path), "--out", str(job), "--yes", "--zero-here"])
        raise SystemExit(0)
    assert exc.value.code == 0, capsys.readouterr().err
    x, y = load_profile(PLOTTER).board.offset_mm
    (start,) = [e for e in read_journal(job / "stream" / "journal.jsonl") if e["ev"] == "start"]
    assert start["zeroed"] == work_zero_command(load_profile(PLOTTER))[1]
    assert start["wco"][:2] == pytest.approx([-x, -y])  # the tool stood at machine 0, 0


def _work_mill(mode: str):
    """The 3018 as a work-coordinate mill (its envelope around the work zero), ``mode``'s tool."""
    import dataclasses

    mill = load_profile("grbl-3018-diamond")
    return dataclasses.replace(
        mill,
        envelope=dataclasses.replace(
            mill.envelope,
            coordinates="work",
            x_mm=(-300.0, 300.0),
            y_mm=(-180.0, 180.0),
            z_mm=(-45.0, 45.0),
        ),
        tool_control=dataclasses.replace(mill.tool_control, mode=mode),
    )


@pytest.mark.parametrize("mode", ["z", "spindle"])
def test_a_z_tool_is_zeroed_in_z_too_where_it_touches_the_board(tmp_path, mode):
    """A Z tool (any but a servo) stands on the board's surface at the corner: Z0 there too,
    not the Z offset an earlier boot left (-10 here)."""
    from test_stream import write_job

    from scratchfab.machine.stream_job import StreamCallbacks, StreamRequest, stream_file

    mill = _work_mill(mode)
    job = tmp_path / "job.gcode"
    write_job(job, 2)
    rec = tmp_path / "rec.jsonl"
    port = f"grblsim://?baud=0&time_scale=0&wco=12,-7,-10&$130=300&$131=180&$132=45&record={rec}"
    said: list[str] = []
    asked: list[str] = []

    def confirm(question: str) -> bool:
        asked.append(question)
        return True

    request = StreamRequest(job, port, machine=mill, zero_here=True, banner_timeout=0.3)
    stream_file(request, StreamCallbacks(lambda _: None, said.append, lambda: "stop", confirm))
    assert "touching the board's surface?" in asked[0]
    assert not any("keeps its offset" in line for line in said)
    x, y = mill.board.offset_mm
    record = read_record(rec)
    zero = next(e["text"] for e in record if e["ev"] == "rx" and e["text"].startswith("G21G10"))
    assert zero.endswith("Z0")
    start = _first_exec(record)
    assert start["frm"] == pytest.approx([x, y, 0.0])  # Z: the board's surface, not 10
    assert start["to"][:2] == pytest.approx([x, y])  # the first move raises Z alone
    assert start["to"][2] > 0.0


def test_a_z_tool_whose_first_move_is_not_a_rise_is_refused_before_connecting(tmp_path):
    from test_stream import write_job

    from scratchfab.machine.stream_job import StreamCallbacks, StreamRequest, stream_file

    job = tmp_path / "job.gcode"
    write_job(job, 2)
    lines = job.read_text().splitlines()
    del lines[2:4]  # the header's and the first stroke's rise: it moves in X and Y first
    job.write_text("\n".join(lines) + "\n")
    rec = tmp_path / "rec.jsonl"
    port = f"grblsim://?baud=0&time_scale=0&$130=300&$131=180&$132=45&record={rec}"
    request = StreamRequest(job, port, machine=_work_mill("z"), zero_here=True)
    with pytest.raises(ScratchfabError) as exc:
        stream_file(request, StreamCallbacks(lambda _: None, print, lambda: "stop", None))
    text = str(exc.value)
    assert "first move must raise it alone" in text and "nothing was sent" in text
    assert "`G0X" in text  # the first move as sent: X and Y at the tool's height
    assert not rec.exists()


@pytest.mark.parametrize(("mode", "z_zeroed"), [("z", True), ("spindle", True), ("servo", False)])
def test_the_zero_advice_zeroes_z_for_every_tool_that_z_lowers(mode, z_zeroed):
    from scratchfab.machine.sender import Z_ZERO, zero_kept_advice

    assert (f"`{Z_ZERO}`" in zero_kept_advice(_work_mill(mode))) is z_zeroed
