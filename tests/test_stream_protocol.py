"""The sender's reading of the controller: end of job, grblHAL, safety door, offsets."""

from __future__ import annotations

import json
import threading
import time
import urllib.parse
from dataclasses import replace
from pathlib import Path

import pytest
import serial
from stream_helpers import FAST, stream_program

from scratchfab.cli import main
from scratchfab.errors import ScratchfabError
from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.sender import (
    Streamer,
    StreamFault,
    StreamOptions,
    StreamStopped,
    open_port,
)
from scratchfab.machine.sender_checks import _machine_frame_refusals, same_offset
from scratchfab.machine.sender_journal import Journal, read_journal
from scratchfab.machine.sender_program import load_program
from scratchfab.machine.stream_job import _check_same_zero


def test_done_only_once_the_last_move_has_run(tmp_path):
    """GRBL serves a ``?`` that came while it planned the last block after that block's
    ``ok`` and before the cycle start: that Idle report is not the end of the job."""
    job = tmp_path / "end.gcode"
    job.write_text("G21 G90\nG0 Z1\nG1 X2 F600\nM5\nG0 Z5\n")
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"
    port = open_port("grblsim://?baud=0&plan_time=0.3", 115200)
    try:
        stream_program(port, prog, journal)
        record = list(port.sim.record)  # what had run when the sender said done
    finally:
        port.close()
    moves = [e for e in record if e["ev"] == "exec"]
    assert moves and moves[-1]["to"] == [2.0, 0.0, 5.0]
    events = read_journal(journal)
    acks = [e for e in events if e["ev"] == "ack"]
    # the wait the sender adds is not a file line: only the file's blocks are journaled
    assert [e.get("i") for e in acks] == list(range(len(prog.blocks)))
    assert events[-1]["ev"] == "end"


GRBLHAL = "GrblHAL 1.1f ['$' or '$HELP' for help]"
HAL_URL = "grblsim://?baud=0&banner=" + urllib.parse.quote(GRBLHAL)


def test_grblhal_banner_is_recognised_and_named(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z1\nG1 X2 F600\nG0 Z2\n")
    rec = tmp_path / "rec.jsonl"
    main(["stream", str(job), "--port", f"{HAL_URL}&time_scale=0.01&record={rec}", "--yes",
          "--banner-timeout", "0.5"])  # fmt: skip
    got = capsys.readouterr()
    assert "connected: grblHAL 1.1f, RX buffer 128 bytes" in got.out + got.err
    received = [e["text"] for e in map(json.loads, rec.read_text().splitlines())
                if e["ev"] == "rx" and e["g"]]  # fmt: skip
    assert received == ["G21G90", "G0Z1", "G1X2F600", "G0Z2", "G4P0"]


def test_grblhal_reset_mid_job_is_seen(tmp_path):
    """A reset is recognised by grblHAL's banner too: lines on the way are flushed."""
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\n" + "".join(f"G1 X{k % 7} F3000\n" for k in range(60)))
    port = open_port(f"{HAL_URL}&time_scale=0.01&reset_after=20", 115200)
    try:
        with pytest.raises(StreamFault, match="reset itself mid-job"):
            stream_program(port, load_program(job), tmp_path / "j.jsonl")
    finally:
        port.close()


def test_grblhal_tool_offset_on_every_axis(tmp_path):
    """grblHAL's ``[TLO:x,y,z]`` (every axis by default): Z's offset is the third."""
    port = open_port(f"{HAL_URL}&boot=0.3", 115200)
    try:
        port.sim.startup_lines[0] = "G43.1Z2"  # before the power-up's banner
        info = Streamer(port, FAST).connect()
    finally:
        port.close()
    assert info.firmware == "grblHAL" and info.wco_source == "$#"
    assert info.wco == pytest.approx((0.0, 0.0, 2.0))


@pytest.mark.parametrize(
    "banner",
    # grblHAL, as itself and at a compatibility level above 0 (no [FIRMWARE:] in $I), and
    # Grbl 1.1, which would answer error:20 after the lines before it ran
    [GRBLHAL, "Grbl 1.1f ['$' for help]", ""],
)
def test_a_tool_change_is_refused_before_sending(tmp_path, banner):
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z1\nT2 M06\nG1 X2 F600\n")
    url = (
        f"grblsim://?baud=0&banner={urllib.parse.quote(banner)}&"
        if banner
        else "grblsim://?baud=0&"
    )
    port = open_port(f"{url}time_scale=0.01", 115200)
    try:
        with pytest.raises(StreamFault, match=r"job\.gcode:3: M6 \(tool change\): Grbl 1\.1"):
            stream_program(port, load_program(job), tmp_path / "j.jsonl")
    finally:
        port.close()
    assert not [e for e in port.sim.record if e["ev"] == "rx" and e["g"]]


def test_an_unknown_banner_is_refused(tmp_path):
    port = open_port("grblsim://?baud=0&banner=Smoothie%20edge&boot=0", 115200)
    try:
        with pytest.raises(StreamFault, match=r"no GRBL banner \('Grbl 1\.1\.\.\.' or 'GrblHAL"):
            Streamer(port, StreamOptions(banner_timeout=0.2, banner_settle=0.02)).connect()
    finally:
        port.close()


def _door_job(tmp_path) -> Path:
    job = tmp_path / "door.gcode"
    moves = "".join(f"G1 X{k % 5} Y{k % 3} F600\n" for k in range(40))
    job.write_text("G21 G90\nM3 S1000\n" + moves + "M5\n")
    return job


def test_safety_door_pauses_without_a_stall_and_the_job_goes_on(tmp_path):
    """The door stays open longer than the stall timeout: a pause the user is told about,
    no fault; the job goes on after the door is closed and cycle start is pressed."""
    prog = load_program(_door_job(tmp_path))
    journal = tmp_path / "j.jsonl"
    port = open_port("grblsim://?baud=0&time_scale=0.1", 115200)
    sim = port.sim
    messages: list[str] = []
    states: list[str] = []
    helper: list[threading.Thread] = []

    def close_and_start():
        time.sleep(1.5)  # three stall timeouts
        sim.close_door()
        time.sleep(0.3)
        sim.cycle_start()

    def progress(p):
        states.append(p.state)
        if p.acked > 10 and not helper:
            sim.open_door()
            helper.append(threading.Thread(target=close_and_start))
            helper[0].start()

    # 0.5 s, not less: a loaded 2-core CI machine must not see a false stall
    options = StreamOptions(banner_timeout=0.5, banner_settle=0.02, stall_timeout=0.5)
    try:
        stream_program(
            port, prog, journal, options, on_progress=progress, on_message=messages.append
        )
    finally:
        port.close()
        for thread in helper:
            thread.join()
    assert helper and "Door:1" in states
    told = " | ".join(messages)
    assert "safety door open (Door:1)" in told and "safety door closed (Door:0)" in told
    assert "controller resumed after the safety door" in told
    acks = [e["i"] for e in read_journal(journal) if e["ev"] == "ack"]
    assert acks == list(range(len(prog.blocks)))
    assert not [
        e for e in sim.record if e["ev"] == "alarm" or (e["ev"] == "rt" and e["ch"] == 0x18)
    ]


def test_stop_with_the_door_open_resets_at_once(tmp_path):
    """Door:1 stands still: a stop resets it without waiting for a Hold:0 that never comes."""
    prog = load_program(_door_job(tmp_path))
    journal = tmp_path / "j.jsonl"
    port = open_port("grblsim://?baud=0&time_scale=0.1", 115200)
    sim = port.sim
    fired: list[float] = []

    def progress(p):
        if p.acked > 10 and not fired and p.state == "Run":
            sim.open_door()
        if p.state == "Door:1" and not fired:
            fired.append(time.monotonic())
            raise KeyboardInterrupt

    options = StreamOptions(
        banner_timeout=0.5, banner_settle=0.02, stall_timeout=0.5, hold_timeout=10.0
    )
    try:
        with pytest.raises(StreamStopped):
            stream_program(
                port, prog, journal, options, on_progress=progress, ask_interrupt=lambda: "stop"
            )
        stopped = time.monotonic()
    finally:
        port.close()
    assert fired and stopped - fired[0] < 5.0  # not the 10 s hold timeout
    assert not [e for e in sim.record if e["ev"] == "alarm"]
    assert [e["ev"] for e in read_journal(journal)][-1] == "stop"


def test_a_door_open_at_connect_is_refused():
    port = open_port("grblsim://?baud=0&time_scale=0.1", 115200)
    try:
        port.sim.open_door()
        with pytest.raises(StreamFault, match=r"reports Door:1: its safety door is open"):
            Streamer(port, FAST).connect()
    finally:
        port.close()
    assert not [e for e in port.sim.record if e["ev"] == "rx"]


def _busy_pty_controller(pty) -> None:
    """An earlier sender queued a long move (3.6 s, scaled) on a port without DTR reset."""
    first = serial.Serial(pty.path, 115200, timeout=2.0)
    first.write(b"\x18")  # opening flushed the power-up banner: a reset sends another
    assert b"Grbl" in first.read_until(b"help]\r\n")
    first.write(b"G21G90\nG1X6F100\n")
    time.sleep(0.2)
    first.close()


@pytest.mark.parametrize("closed", [False, True], ids=["Door:1", "Door:0"])
def test_a_controller_its_door_stopped_is_reset_at_once_on_connect(closed):
    """Door:0/Door:1 at connect: the machine stands still, so the soft reset comes at once
    and the user is told why; an open door then refuses the stream as at any connect."""
    with GrblPty(SimOptions(baud=0, time_scale=0.5)) as pty:
        _busy_pty_controller(pty)
        pty.sim.open_door()
        if closed:
            pty.sim.close_door()
        time.sleep(0.1)  # Door:2 (stopping) is over
        said: list[str] = []
        port = serial.Serial(pty.path, 115200, timeout=0.01)
        try:
            streamer = Streamer(port, FAST, on_message=said.append)
            if closed:
                assert streamer.connect().status.state == "Idle"
            else:
                with pytest.raises(StreamFault, match="reports Door:1"):
                    streamer.connect()
        finally:
            port.close()
        record = pty.sim.record
    state = "Door:0" if closed else "Door:1"
    assert any(s.startswith(f"controller is in {state}: its safety door") for s in said)
    assert not [s for s in said if "still moving" in s]
    assert not [e for e in record if e["ev"] == "alarm"]


def test_a_door_that_stops_a_busy_controller_on_connect_resets_it_without_the_hold_wait():
    """A controller still running at connect is held after busy_timeout; a safety door
    that stops it meanwhile (Door:1: GRBL ignores the hold then) stands it still too: the
    reset comes at once, not after hold_timeout waiting for a Hold:0 that never comes."""
    options = replace(FAST, busy_timeout=0.3, hold_timeout=5.0)
    with GrblPty(SimOptions(baud=0, time_scale=0.5)) as pty:
        _busy_pty_controller(pty)
        said: list[str] = []

        def on_message(text: str) -> None:
            said.append(text)
            if "feed hold, then a soft reset" in text:
                pty.sim.open_door()  # the door opens as the sender gives up waiting

        port = serial.Serial(pty.path, 115200, timeout=0.01)
        began = time.monotonic()
        try:
            with pytest.raises(StreamFault, match="reports Door:1"):
                Streamer(port, options, on_message=on_message).connect()
        finally:
            port.close()
        took = time.monotonic() - began
        record = pty.sim.record
    assert any(s.startswith("controller is in Door:1: its safety door is open") for s in said)
    assert took < options.hold_timeout
    resets = [e["t"] for e in record if e["ev"] == "reset"]
    assert len(resets) == 2  # the first sender's and the connect's
    assert not [e for e in record if e["ev"] == "alarm"]


def _zero_events(wco, g92, inches=False) -> list[dict]:
    start = {"ev": "start", "sha256": "x", "resume": False, "blocks": 1, "wco": wco, "g92": g92}
    return [{**start, "inches": inches}]


#: GRBL's report digit in mm (3 decimals of mm, 4 of an inch under $13=1), read off the
#: emulator's printing rather than taken from the module under test.
_DIGIT = {False: 0.001, True: 0.0001 * 25.4}


@pytest.mark.parametrize("inches", [False, True], ids=["mm", "inch"])
@pytest.mark.parametrize("digits", [2, 3])
def test_one_offset_tolerance_for_check_mode_and_resume(tmp_path, digits, inches):
    """A G92 of ``digits`` report digits that a reset cleared: check mode's reset and
    --resume judge it alike. Two honest readings of one zero differ by up to 2 digits
    (each reading sums up to 3 rounded numbers, and both are whole digits), so 2 digits
    is the same zero and 3 is a moved one, in mm and in inch reports ($13=1: 2 digits is
    0.00508 mm, which a fixed 0.005 mm tolerance refused)."""
    shift = digits * _DIGIT[inches]
    same = digits == 2
    # --resume: the journal's zero had the G92 part, now the reset cleared it
    said: list[str] = []
    before = [10.0 + shift, 20.0, -5.0]
    events = _zero_events(before, [shift, 0.0, 0.0], inches)
    call = (events, (10.0, 20.0, -5.0), (0.0, 0.0, 0.0), tmp_path / "j.jsonl", said.append)
    if same:
        _check_same_zero(*call)
        assert said == []
    else:
        with pytest.raises(ScratchfabError, match="included a G92 offset"):
            _check_same_zero(*call)
    # check mode: a G92 set before $C is cleared by the reset that ends it
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z1\nG1 X2 F600\n")
    port = open_port(f"grblsim://?baud=0&time_scale=0.01&$13={int(inches)}", 115200)
    try:
        port.write(f"G92 X{-shift:.6f}\n".encode())  # at X0: the work offset becomes +shift
        streamer = Streamer(port, FAST)
        info = streamer.connect()
        assert info.g92 == pytest.approx((shift, 0.0, 0.0), abs=1e-9)
        if same:
            assert streamer.check(load_program(job)).errors == []
        else:
            with pytest.raises(StreamFault, match="cleared its G92 or tool length offset"):
                streamer.check(load_program(job))
    finally:
        port.close()


def _offset_readings(inches: bool, g54: float, g92: float, tlo: float):
    """The work offset as the sender reads it with $# (at connect) and from a status
    report's WCO, for a Z zero set as G54 + G92 + tool length offset (mm)."""
    port = open_port(f"grblsim://?baud=0&time_scale=0&$13={int(inches)}&wco=0,0,{g54:.6f}", 115200)
    try:
        # at MPos Z0, G92 Z-(G54 + v) makes the G92 offset +v (TLO still 0)
        port.write(f"G21\nG92 Z{-g54 - g92:.6f}\nG43.1 Z{tlo:.6f}\n".encode())
        streamer = Streamer(port, FAST)
        by_hash = streamer.connect().wco
        for _ in range(12):  # WCO: comes at least every 10th report while idle
            port.write(b"?")
            line = port.read_until(b">").decode()
            if "WCO:" in line:
                field = line.split("WCO:")[1].split("|")[0].rstrip(">")
                wco = tuple(float(v) * (25.4 if inches else 1.0) for v in field.split(","))
                return by_hash, wco
        raise AssertionError("no WCO field in 12 reports")
    finally:
        port.close()


@pytest.mark.parametrize("inches", [False, True], ids=["mm", "inch"])
def test_readings_of_one_zero_at_the_worst_rounding_are_the_same_zero(inches):
    """One Z zero of 1.8 digits, once as 0.6 + 0.6 + 0.6 digits of G54, G92 and tool
    length offset ($# prints each one digit up: 3) and once as 0.4 + 0.4 + 1.0 digits
    ($# prints 0 + 0 + 1); WCO prints the sum once (2). The two $# readings are 2 digits
    apart, the worst case, and each is a digit from WCO: one zero in either unit; 3 digits
    is not (GRBL reports 3 decimals in mm, 4 in inches: 2 digits is 0.002 or 0.00508 mm)."""
    d = _DIGIT[inches]
    up, up_wco = _offset_readings(inches, 0.6 * d, 0.6 * d, 0.6 * d)
    down, down_wco = _offset_readings(inches, 0.4 * d, 0.4 * d, 1.0 * d)
    assert up[2] == pytest.approx(3 * d, abs=1e-9) and down[2] == pytest.approx(d, abs=1e-9)
    assert up_wco == down_wco == pytest.approx((0.0, 0.0, 2 * d), abs=1e-9)
    for a, b in ((up, down), (up, up_wco), (down, down_wco)):
        assert same_offset(a, b, inches)
        moved = (b[0], b[1], a[2] + 3 * d)
        assert not same_offset(a, moved, inches)


@pytest.mark.parametrize("inches", [False, True], ids=["mm", "inch"])
def test_a_changed_zero_is_told_from_the_reporting_resolution_up(tmp_path, inches):
    """2 report digits off is one zero, 3 digits a changed one (told, not refused); the
    journal's run in inch reports widens it as this run's would."""
    d = _DIGIT[inches]
    said: list[str] = []
    events = _zero_events([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], inches)
    _check_same_zero(events, (1.0 + 2 * d, 2.0, 3.0), None, tmp_path / "j.jsonl", said.append)
    assert said == []
    _check_same_zero(events, (1.0, 2.0, 3.0 + 3 * d), None, tmp_path / "j.jsonl", said.append)
    assert len(said) == 1 and "the work offset changed" in said[0]
    # this run in inch reports, the journal's in mm: the coarser digit again
    said.clear()
    mm_events = _zero_events([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    near = (1.0 + 2 * d, 2.0, 3.0)
    _check_same_zero(mm_events, near, None, tmp_path / "j.jsonl", said.append, inches)
    assert said == []


@pytest.mark.parametrize("inches", [False, True], ids=["mm", "inch"])
def test_a_machine_frame_profile_takes_the_same_offset_tolerance(inches):
    d = _DIGIT[inches]
    assert _machine_frame_refusals("m", (2 * d, 0.0, -2 * d), inches) == []
    (refusal,) = _machine_frame_refusals("m", (0.0, 3 * d, 0.0), inches)
    assert f"GRBL's work offset is X0 Y{3 * d:g} Z0 mm" in refusal


def test_stop_while_the_door_restores_holds_before_the_cycle_resumes(tmp_path):
    """Ctrl-C, stop in ``Door:3`` (spindle spinning up after cycle start): GRBL ignores a
    feed hold in a door state and then resumes the cycle, so the sender holds again as
    soon as it runs; the reset comes with the machine standing still (no ALARM:3)."""
    job = tmp_path / "door.gcode"
    moves = "".join(f"G1 X{10 * (k % 2)} Y{k} F600\n" for k in range(30))  # 1 s each
    job.write_text("G21 G90\nM3 S1000\n" + moves + "M5\n")
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.25", 115200)  # spindle spin-up: 1 s
    sim = port.sim
    fired: list[float] = []
    opened: list[bool] = []

    def progress(p):
        if p.acked > 3 and not opened and p.state == "Run":
            opened.append(True)
            sim.open_door()
            sim.close_door()  # Door:0 once stopped
        elif p.state == "Door:0":
            sim.cycle_start()
        elif p.state == "Door:3" and not fired:
            fired.append(time.monotonic())
            raise KeyboardInterrupt

    options = StreamOptions(
        banner_timeout=0.5, banner_settle=0.02, stall_timeout=0.5, hold_timeout=3.0
    )
    try:
        with pytest.raises(StreamStopped):
            stream_program(
                port, prog, tmp_path / "j.jsonl", options, on_progress=progress,
                ask_interrupt=lambda: "stop",
            )  # fmt: skip
    finally:
        port.close()
    assert fired
    assert not [e for e in sim.record if e["ev"] == "alarm"]
    reset = next(e["t"] for e in sim.record if e["ev"] == "reset")
    ran = [e for e in sim.record if e["ev"] in ("exec", "partial") and e["t"] > fired[0]]
    assert len(ran) <= 1 and reset - fired[0] < 2.0  # at most the move the hold cut short


def _open_door_in(sim, state: str) -> threading.Thread:
    def opener():
        deadline = time.monotonic() + 5.0
        while sim.state != state and time.monotonic() < deadline:
            time.sleep(0.001)
        sim.open_door()

    thread = threading.Thread(target=opener)
    thread.start()
    return thread


def test_a_door_opened_in_check_mode_is_refused_after_its_reset(tmp_path):
    """GRBL ignores the door in check mode; the reset that ends it comes back in Door:1,
    where no line is read: nothing may be left waiting there (a late answer would pair
    with the wrong line of the job)."""
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z1\nG1 X2 F600\nG0 Z5\n")
    # at the line's speed (not baud=0), so that the door opens while it is in check mode
    port = open_port("grblsim://?time_scale=0.05", 115200)
    sim = port.sim
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        opener = _open_door_in(sim, "Check")
        with pytest.raises(StreamFault, match=r"Door:1: its safety door is open"):
            streamer.check(load_program(job))
        opener.join()
    finally:
        port.close()
    rx = [e["text"] for e in sim.record if e["ev"] == "rx"]
    assert rx[-1] == "$C" and rx.count("$C") == 2  # nothing after leaving check mode


def test_a_door_opened_before_the_stream_starts_is_refused(tmp_path):
    """Opened after connect (say while the user clamps the board): nothing is sent."""
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 Z1\nG1 X2 F600\nG0 Z5\n")
    port = open_port("grblsim://?baud=0&time_scale=0.05", 115200)
    sim = port.sim
    journal = Journal(tmp_path / "j.jsonl").open()
    try:
        streamer = Streamer(port, FAST)
        streamer.connect()
        sim.open_door()
        sim.close_door()  # Door:0: closed, waiting for cycle start
        # were lines queued, cycle start would run them (and end an unguarded test)
        threading.Timer(2.0, sim.cycle_start).start()
        with pytest.raises(StreamFault, match=r"Door:0: its safety door is open \(or was"):
            streamer.stream(load_program(job), journal)
    finally:
        journal.close()
        port.close()
    assert not [e for e in sim.record if e["ev"] == "rx" and e["g"]]
    assert read_journal(tmp_path / "j.jsonl") == []


def test_an_unanswered_offset_query_is_not_passed_over():
    """``$#`` unanswered (here: the door opened just before it) stays in GRBL's buffer and
    is answered later, pairing its ``ok`` with a job line: a fault, not a fallback."""
    port = open_port("grblsim://?baud=0&time_scale=0.05", 115200)
    try:
        streamer = Streamer(port, replace(FAST, command_timeout=0.3))
        streamer.connect()
        port.sim.open_door()
        with pytest.raises(StreamFault, match=r"no answer to '\$#' within 0.3 s"):
            streamer._read_work_offset()
    finally:
        port.close()


@pytest.mark.parametrize(
    ("port", "query"),
    [
        ("grblsim://?time_scale=0.5&$110=900", {"time_scale": "0.5", "$110": "900"}),
        ("GrblSim://?time_scale=0&recor%64=x", {"time_scale": "0", "record": "x"}),
        ("grblsim://?time_scale=0&record", {"time_scale": "0", "record": ""}),
        ("grblsim://", {}),
        ("/dev/ttyUSB0", None),
        ("socket://localhost:7777?grblsim://", None),
    ],
)
def test_one_reader_of_grblsim_urls(port, query):
    """The handler, the pipeline's record= check and the stream's ETA read a grblsim URL
    with one function: the handler opens the emulator with what it reads."""
    from scratchfab.machine.protocol_grblsim import grblsim_query, sim_options
    from scratchfab.pipeline.config import _grblsim_record

    assert grblsim_query(port) == query
    assert _grblsim_record(port) == (query is not None and "record" in query)
    if query is None:
        assert sim_options(port, 9600) is None
        return
    options = sim_options(port, 9600)
    assert options is not None and options.baud == 9600  # the port's, the URL sets none
    if "record" not in query:
        ser = serial.serial_for_url(port, baudrate=9600, timeout=0.01)
        try:
            assert ser.sim.options == options
        finally:
            ser.close()


def test_a_grblsim_key_given_twice_is_one_error_line():
    from scratchfab.errors import ConfigError
    from scratchfab.machine.protocol_grblsim import grblsim_query

    port = "grblsim://?time_scale=0&time_scale=1"
    with pytest.raises(ConfigError, match=r"^port '.*': time_scale: given more than once$"):
        grblsim_query(port)
    with pytest.raises(ConfigError, match="time_scale: given more than once"):
        serial.serial_for_url(port, baudrate=115200)
