"""The GRBL 1.1 emulator against the documented Grbl 1.1 behaviour (grbl-1.1-facts.md)."""

from __future__ import annotations

import collections
import math
import re
import threading
import time
from dataclasses import FrozenInstanceError, replace

import grbl_planner_sim as planner_sim
import numpy as np
import pytest
import serial
from grbl_stepper_ticks import ticks_taken
from test_export import random_scratches

import scratchfab.machine.sender  # noqa: F401  (registers grblsim://)
from scratchfab.cli import main
from scratchfab.export import export
from scratchfab.machine.grbl_codes import ALARM_CODES, ERROR_CODES, error_meaning
from scratchfab.machine.grblsim import BANNER, GrblSim, SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender_journal import default_journal_path
from scratchfab.model.design import Board
from scratchfab.toolpath import plan_toolpath


def _open(query: str = "time_scale=0.01") -> serial.SerialBase:
    return serial.serial_for_url(f"grblsim://?{query}", baudrate=115200, timeout=0.05)


def _read_until(port: serial.SerialBase, predicate, timeout: float = 3.0) -> list[str]:
    """Lines from the port until ``predicate(lines)`` holds."""
    lines: list[str] = []
    buf = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        buf += port.read(max(1, port.in_waiting))  # what has come, else wait for a byte
        *done, buf = buf.split(b"\n")
        lines += [d.decode().strip() for d in done if d.strip()]
        if predicate(lines):
            return lines
    raise AssertionError(f"timeout; got {lines!r}")


def _lines_for(port: serial.SerialBase, seconds: float) -> list[str]:
    """Every line the port gives within ``seconds``."""
    buf = b""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        buf += port.read(4096)
    return [d.decode().strip() for d in buf.split(b"\n") if d.strip()]


def _banner(port: serial.SerialBase) -> list[str]:
    """Lines read until a start-up banner (``Grbl 1.1h ...``) has come."""
    return _read_until(port, lambda ls: any(x.startswith("Grbl") for x in ls))


def _status(port: serial.SerialBase) -> str:
    """The next status report after asking for one with ``?``."""
    port.write(b"?")
    return _read_until(port, lambda ls: any(x.startswith("<") for x in ls))[-1]


def _answers(lines: list[str]) -> list[str]:
    return [ln for ln in lines if ln == "ok" or ln.startswith("error:")]


def _cmd(port: serial.SerialBase, text: bytes, n: int = 1) -> list[str]:
    port.write(text)
    return _read_until(port, lambda ls: len(_answers(ls)) >= n)


def test_codes_tables_complete():
    assert sorted(ERROR_CODES) == list(range(1, 39))
    assert sorted(ALARM_CODES) == list(range(1, 11))
    assert "feed rate" in error_meaning(22)
    assert "unknown" in error_meaning(99)


def test_banner_info_and_line_ends():
    port = _open()
    try:
        lines = _banner(port)
        assert lines[-1] == BANNER.strip()
        lines = _cmd(port, b"$I\n")
        assert "[VER:1.1h.20190830:]" in lines and "[OPT:V,15,128]" in lines
        # CR and LF each end a line: CRLF gets two oks; an empty line gets ok
        assert _answers(_cmd(port, b"G21\r\n", 2)) == ["ok", "ok"]
        assert _answers(_cmd(port, b"\n")) == ["ok"]
        # comments, spaces and case are stripped before parsing
        assert _answers(_cmd(port, b"g90 (comment) ; tail\n")) == ["ok"]
    finally:
        port.close()


@pytest.mark.parametrize(
    ("line", "code"),
    [
        ("G1X1", 22),  # no feed rate yet
        ("M6", 20),
        ("G64", 20),
        ("G0X1X2", 25),
        ("G0G1X1", 21),
        ("G4", 28),
        ("G1.5X1", 23),
        ("X", 2),
        ("1", 1),
        ("T300", 38),
        ("F-1", 4),
        ("G53G2X1I1", 30),
        ("G10L2P8X0", 29),
        ("G80X1", 31),
        ("G0X1P2", 36),
        ("G92", 26),
        ("G2X1F100", 35),
        ("G43.1X1", 37),
        ("N99999999G0", 27),
        ("$Q", 3),
        ("$H", 5),
        ("$20=1", 10),
        ("$0=2", 6),
        ("G" + "0" * 80, 11),
    ],
)
def test_error_codes(line, code):
    port = _open()
    try:
        _banner(port)
        assert _answers(_cmd(port, line.encode() + b"\n")) == [f"error:{code}"]
    finally:
        port.close()


def test_rx_buffer_overflow_drops_bytes_and_realtime_still_works():
    port = _open("time_scale=1")
    try:
        _banner(port)
        port.write(b"G4P0.6\n")  # dwell: the main loop stops reading the RX buffer
        time.sleep(0.1)
        extra = b"G0X0\n" * 40  # 200 bytes: 72 must be dropped
        port.write(extra + b"?")
        lines = _read_until(port, lambda ls: any(x.startswith("<") for x in ls), timeout=0.5)
        assert any(x.startswith("<Idle") or x.startswith("<Run") for x in lines)
        time.sleep(0.8)
        sim = port.sim
        assert sim.overruns == len(extra) - 128
        assert any(e["ev"] == "overrun" for e in sim.record)
    finally:
        port.close()


def test_realtime_picked_off_inside_comments():
    port = _open()
    try:
        _banner(port)
        port.write(b"G21 (careful!)\n")  # the ! is a feed hold, from Idle complete at once
        time.sleep(0.05)
        assert _status(port).startswith("<Hold:0|")
        assert _answers(_lines_for(port, 0.2)) == []  # held: the line waits for the resume
        port.write(b"~")
        assert _answers(_read_until(port, lambda ls: "ok" in ls)) == ["ok"]
    finally:
        port.close()


def test_planner_holds_15_blocks_so_ok_lags():
    port = _open("time_scale=1")
    try:
        _banner(port)
        _cmd(port, b"G1F60\n")  # 60 mm/min: 1 mm takes one second
        port.write(b"".join(f"G1X{k + 1}\n".encode() for k in range(20)))
        time.sleep(0.5)
        lines = _lines_for(port, 0.05)
        assert _answers(lines) == ["ok"] * 15  # the 16th line waits in the parser
        port.write(b"\x18")  # reset while moving -> ALARM:3
        lines = _read_until(port, lambda ls: any(x.startswith("[MSG:'$H'") for x in ls))
        assert "ALARM:3" in lines and BANNER.strip() in lines
    finally:
        port.close()


def test_motion_time_follows_feed_and_time_scale():
    port = _open("time_scale=0.2")
    try:
        _banner(port)
        t0 = time.monotonic()
        _cmd(port, b"G1X10F600\n")  # 10 mm at 600 mm/min = 1 s, scaled to 0.2 s
        status = _status(port)
        while not status.startswith("<Idle"):
            status = _status(port)
        elapsed = time.monotonic() - t0
        assert 0.18 <= elapsed <= 0.6
        assert status.startswith("<Idle|MPos:10.000,0.000,0.000|")
    finally:
        port.close()


def test_serial_byte_time_at_baud():
    port = serial.serial_for_url("grblsim://?baud=9600", baudrate=9600, timeout=0.05)
    try:
        _banner(port)
        t0 = time.monotonic()
        port.write(b"\n" * 100)  # 100 bytes in, 100 x "ok\r\n" out, 10 bits per byte
        _read_until(port, lambda ls: len(_answers(ls)) >= 100)
        assert time.monotonic() - t0 >= 400 * 10 / 9600 * 0.95
    finally:
        port.close()


def test_feed_hold_resume_and_state_rules():
    port = _open("time_scale=1")
    try:
        _banner(port)
        _cmd(port, b"G1X5F60\n")
        # read while the hold decelerates (Hold:1, v/a = 0.1 s): not while holding
        assert _answers(_cmd(port, b"!$$\n$C\n", n=2)) == ["error:8", "error:8"]
        time.sleep(0.2)
        assert _status(port).startswith("<Hold:0|")
        port.write(b"$$\n")
        assert _answers(_lines_for(port, 0.2)) == []  # Hold:0: no line is read
        port.write(b"~")
        assert _answers(_read_until(port, lambda ls: len(_answers(ls)) >= 1)) == ["error:8"]
        assert _status(port).startswith("<Run|")
        port.write(b"!")
        time.sleep(0.2)
        port.write(b"\x18")  # reset from Hold:0: no alarm, position kept
        lines = _banner(port)
        assert not any(x.startswith("ALARM") for x in lines)
        assert _status(port).startswith("<Idle|")
    finally:
        port.close()


def test_check_mode_and_its_reset():
    port = _open("time_scale=1")
    try:
        _banner(port)
        lines = _cmd(port, b"$C\n")
        assert "[MSG:Enabled]" in lines
        assert _answers(_cmd(port, b"G1X100F10\nM6\n", 2)) == ["ok", "error:20"]
        assert _status(port).startswith("<Check|MPos:0.000,0.000,0.000")  # no motion
        port.write(b"$C\n")
        lines = _banner(port)
        assert lines[:2] == ["[MSG:Disabled]", "ok"]
        assert not any(e["ev"] == "exec" for e in port.sim.record)
    finally:
        port.close()


def test_soft_limit_alarm_locks_until_reset():
    port = _open("soft_limits=1&homed=1&time_scale=0.01")
    try:
        _banner(port)
        port.write(b"G0X10\n")  # machine space is -$130..0: +10 is outside
        lines = _read_until(port, lambda ls: "[MSG:Reset to continue]" in ls)
        assert "ALARM:2" in lines and not _answers(lines)
        port.write(b"?")
        time.sleep(0.2)
        assert port.read(100) == b""  # no status report while locked
        port.write(b"\x18")
        lines = _read_until(port, lambda ls: "[MSG:'$H'|'$X' to unlock]" in ls)
        assert _answers(_cmd(port, b"G0X-1\n")) == ["error:9"]
        assert "[MSG:Caution: Unlocked]" in _cmd(port, b"$X\n")
        assert _answers(_cmd(port, b"G0X-1\n")) == ["ok"]
    finally:
        port.close()


BAD_URL_OPTIONS = [
    ("wco=1,2", "wco: expected x,y,z (3 numbers in mm), got '1,2'"),
    ("wco=1,x,3", "wco: expected x,y,z (3 numbers in mm), got '1,x,3'"),
    ("wco=1,2,inf", "wco[2]: expected a finite number, got inf"),
    ("time_scale=nan", "time_scale: expected a finite number, got nan"),
    ("time_scale=-1", "time_scale: expected a value at least 0, got -1.0"),
    ("latency=", "latency: expected a number, got ''"),
    ("slow=1_0", "slow: expected a number, got '1_0'"),
    ("error_at=-3", "error_at: expected a value at least 0, got -3"),
    ("error_at=2.5", "error_at: expected an integer, got '2.5'"),
    ("error_code=0", "error_code: expected a value in [1, 255], got 0"),
    ("baud=fast", "baud: expected an integer, got 'fast'"),
    ("usb_powered=maybe", "usb_powered: expected 1, 0, true, false, yes or no, got 'maybe'"),
    ("homed=on", "homed: expected 1, 0, true, false, yes or no, got 'on'"),
    ("boto=1", "unknown key 'boto' (did you mean 'boot'?); valid keys: baud, time_scale"),
    ("$110=abc", "$110: expected a number at least 0, got 'abc'"),
    ("$110=-5", "$110: expected a number at least 0, got '-5'"),
    ("$110=nan", "$110: expected a number at least 0, got 'nan'"),
    ("$999=1", "$999: not a Grbl 1.1 setting (settings: $0, $1,"),
    ("settings=1", "settings: set GRBL settings as $N=value"),
    ("error_at=1&error_at=2", "error_at: given more than once"),
    ("banner=", "banner: expected one line of 1 to 100 printable ASCII characters"),
    ("banner=Grbl%0D%0Aok", "banner: expected one line of 1 to 100 printable ASCII"),
    ("plan_time=-1", "plan_time: expected a value at least 0, got -1"),
]


@pytest.mark.parametrize(("query", "expected"), BAD_URL_OPTIONS)
def test_bad_url_option_is_one_line_error(tmp_path, capsys, query, expected):
    """`scratchfab stream --port grblsim://?...` names the URL, key and value; no traceback."""
    job = tmp_path / "job.gcode"
    job.write_text("G21 G90\nG0 X1 Y1\nM2\n")
    url = f"grblsim://?{query}"
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", url, "--yes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: port {url!r}: ") and err.count("\n") == 1, err
    assert expected in err and "Traceback" not in err
    assert not default_journal_path(job).exists()  # nothing streamed, nothing written


@pytest.mark.parametrize(
    ("query", "expected"),
    [
        ("baud=9600", {"baud": 9600}),
        ("time_scale=0.25&latency=1e-3", {"time_scale": 0.25, "latency": 0.001}),
        ("error_at=7&error_code=255", {"error_at": 7, "error_code": 255}),
        ("usb_powered=YES&homed=No&soft_limits=true&wco_field=0",
         {"usb_powered": True, "homed": False, "soft_limits": True, "wco_field": False}),
        ("wco=-1.5,2,3e1", {"wco": (-1.5, 2.0, 30.0)}),
        ("$110=900&$20=1", {"settings": {110: 900.0, 20: 1.0}}),
        ("record=", {"record": ""}),
        ("banner=GrblHAL+1.1f+%5B%27%24%27%5D&plan_time=0.5",
         {"banner": "GrblHAL 1.1f ['$']", "plan_time": 0.5}),
    ],
)  # fmt: skip
def test_url_options_parse_to_typed_values(query, expected):
    port = serial.serial_for_url(f"grblsim://?{query}", baudrate=expected.get("baud", 115200))
    try:
        assert port.sim is not None
        options = port.sim.options
    finally:
        port.close()
    assert options == replace(SimOptions(), **expected)
    for key, value in expected.items():
        assert type(getattr(options, key)) is type(value)
    assert all(type(v) is float for v in options.wco)
    with pytest.raises(FrozenInstanceError):
        options.baud = 1  # type: ignore[misc]


def test_pty_speaks_grbl_to_pyserial():
    with GrblPty(SimOptions(time_scale=0.01)) as pty:
        port = serial.Serial(pty.path, 115200, timeout=0.05)
        try:
            port.write(b"\x18")  # opening flushed the power-up banner
            _banner(port)
            assert _answers(_cmd(port, b"G21\r\n", 2)) == ["ok", "ok"]
            assert _status(port).startswith("<Idle|MPos:")
        finally:
            port.close()


def test_sim_record_of_executed_motion():
    sim = GrblSim(SimOptions(time_scale=0.0))
    sim.start()
    sim.host_write(b"G1X3Y4F100\nG0Z1\n")
    deadline = time.monotonic() + 2
    while time.monotonic() < deadline and sum(e["ev"] == "exec" for e in sim.record) < 2:
        time.sleep(0.01)
    sim.close()
    execs = [e for e in sim.record if e["ev"] == "exec"]
    assert [(e["to"], e["rapid"]) for e in execs] == [
        ([3.0, 4.0, 0.0], False),
        ([3.0, 4.0, 1.0], True),
    ]


def test_wco_field_after_reset_and_after_a_change():
    """Grbl clears its report counters on every reset and flags a WCO change at once."""
    port = _open("time_scale=0.01&wco=-10,-20,-5")
    try:
        _banner(port)
        assert "|WCO:-10.000,-20.000,-5.000" in _status(port)
        assert "WCO:" not in _status(port)  # then only every 10th report while idle
        port.write(b"\x18")
        _banner(port)
        assert "|WCO:-10.000,-20.000,-5.000" in _status(port)  # the counter was reset
        assert "WCO:" not in _status(port)
        _cmd(port, b"G92X1\n")  # MPos 0: G92 makes work X 1, so WCO X = -1
        assert "|WCO:-1.000,-20.000,-5.000" in _status(port)
        assert "WCO:" not in _status(port)
    finally:
        port.close()
    port = _open("time_scale=0.01&wco_field=0")  # a build without the WCO field
    try:
        _banner(port)
        assert not [r for r in (_status(port) for _ in range(12)) if "WCO:" in r]
        assert "[G54:0.000,0.000,0.000]" in _cmd(port, b"$#\n")
    finally:
        port.close()


@pytest.mark.parametrize("laser", [0, 1])
def test_which_spindle_lines_wait_for_the_planner(laser):
    """Grbl 1.1 ``gc_execute_line``: a spindle state change waits for the planner to empty
    even in laser mode; an S change with motion waits only with ``$32=0``; a repeated M5
    and M1 (ignored by Grbl 1.1) never wait."""
    sim = GrblSim(SimOptions(time_scale=0.2, settings={32: laser}))
    sim.start()
    lines = ["G21G90G1F600", "M3S100", "G1X5", "G1X10S200", "M5", "G1X0", "M5", "M1", "G1X1"]
    sim.host_write("".join(f"{ln}\n" for ln in lines).encode())
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and sum(e["ev"] == "exec" for e in sim.record) < 4:
        time.sleep(0.01)
    sim.close()
    n_of = {e["text"]: e["n"] for e in reversed(sim.record) if e["ev"] == "rx"}  # first of each
    resp = {e["n"]: e["t"] for e in sim.record if e["ev"] == "resp"}
    done = {e["n"]: e["t"] for e in sim.record if e["ev"] == "exec"}
    assert len(done) == 4 and all(e["r"] == "ok" for e in sim.record if e["ev"] == "resp")
    # the S change with motion: waits for X5 to finish only outside laser mode
    assert (resp[n_of["G1X10S200"]] >= done[n_of["G1X5"]]) == (laser == 0)
    assert resp[n_of["M5"]] >= done[n_of["G1X10S200"]]  # a state change: always waits
    second_m5 = max(e["n"] for e in sim.record if e["ev"] == "rx" and e["text"] == "M5")
    assert resp[second_m5] < done[n_of["G1X0"]]  # M5 again: no change, no wait
    assert resp[n_of["M1"]] < done[n_of["G1X0"]]  # M1 ignored: no wait, no pause
    assert not any(e["ev"] == "state" and e["state"].startswith("Hold") for e in sim.record)


def test_program_end_keeps_g92_and_a_reset_clears_it():
    """Grbl 1.1's M2/M30 resets G1 G17 G90 G94 G54 M5 M9 only; a soft reset clears G92."""
    port = _open("time_scale=0")
    try:
        _banner(port)
        _cmd(port, b"G92X5Y-3\n")
        assert _answers(_cmd(port, b"G91G55M2\n")) == ["ok"]
        lines = _cmd(port, b"$#\n")
        assert "[G92:-5.000,3.000,0.000]" in lines
        assert any(x.startswith("[GC:G1 G54 G17 G21 G90 G94 M5 M9") for x in _cmd(port, b"$G\n"))
        port.write(b"\x18")
        _banner(port)
        assert "[G92:0.000,0.000,0.000]" in _cmd(port, b"$#\n")
    finally:
        port.close()


def test_status_asked_while_planning_comes_after_the_ok_and_says_idle():
    """Grbl serves a ``?`` that came while it planned a block after the line's ``ok`` and
    before the cycle start: Idle at the old position, then the move runs."""
    port = _open("plan_time=0.2")
    try:
        _banner(port)
        port.write(b"G0Z5\n?")
        lines = _read_until(port, lambda ls: any(x.startswith("<") for x in ls))
        assert lines[-2] == "ok"
        assert lines[-1].startswith("<Idle|MPos:0.000,0.000,0.000|")
        assert _status(port).startswith("<Run|")
    finally:
        port.close()


def test_grblhal_banner_and_its_answers():
    """``banner=GrblHAL ...``: grblHAL's banner after every reset and its ``$I``/``$#``."""
    port = _open("banner=" + "GrblHAL 1.1f ['$' or '$HELP' for help]".replace(" ", "%20"))
    try:
        assert _banner(port)[-1] == "GrblHAL 1.1f ['$' or '$HELP' for help]"
        lines = _cmd(port, b"$I\n")
        assert "[OPT:V,15,128,3,0]" in lines and "[FIRMWARE:grblHAL]" in lines
        assert "[TLO:0.000,0.000,0.000]" in _cmd(port, b"$#\n")
        port.write(b"\x18")
        assert _banner(port)[-1].startswith("GrblHAL 1.1f")
    finally:
        port.close()


def test_safety_door_stops_cuts_the_spindle_and_resumes_once_closed():
    """0x84: stop, spindle off, ``Door:1`` while open (``~`` ignored, no line parsed),
    ``Door:0`` once closed, then ``~``: ``Door:3`` while the spindle spins up, and Run."""
    port = _open("time_scale=0.1")  # G1 X10 F60: 1 s; the spindle delay 0.4 s
    try:
        _banner(port)
        _cmd(port, b"M3S1000\nG1X10F60\n", 2)
        time.sleep(0.2)
        port.write(b"\x84")
        time.sleep(0.05)
        assert _status(port).startswith("<Door:1|")
        port.write(b"~G1X0\n")
        time.sleep(0.1)
        assert _status(port).startswith("<Door:1|")  # ~ is ignored while the door is open
        port.sim.close_door()
        lines = [_status(port)]
        assert lines[0].startswith("<Door:0|")
        port.write(b"~")
        time.sleep(0.05)
        lines.append(_status(port))
        assert lines[-1].startswith("<Door:3|")
        lines += _read_until(port, lambda ls: "ok" in ls)  # G1X0 parsed only now
        assert _status(port).startswith("<Run|")
        port.write(b"!")  # held: closing the port does not wait for the moves
        time.sleep(0.05)
    finally:
        port.close()
    assert not any(line == "ok" for line in lines[:2])
    spindle = [e["spindle"] for e in port.sim.record if e["ev"] == "spindle"]
    assert spindle == ["M3", "M5", "M3"]
    states = [e["state"] for e in port.sim.record if e["ev"] == "state"]
    door = states.index("Door:2")
    assert states[door - 1 : door + 5] == ["Run", "Door:2", "Door:1", "Door:0", "Door:3", "Run"]
    assert not any(e["ev"] == "alarm" for e in port.sim.record)


def _mpos_x(report: str) -> float:
    return float(report.split("MPos:")[1].split(",")[0])


def test_feed_hold_or_jog_cancel_during_a_jog_cancels_it():
    """Grbl 1.1: ``!`` in Jog does not hold, it cancels the jog: decelerate, flush the jog
    blocks, Idle where it stopped (``~`` resumes nothing); ``0x85`` does the same."""
    port = _open("time_scale=0.1")  # a 10 mm jog at F60: 1 s
    try:
        _banner(port)
        for cancel in (b"!", b"\x85"):
            assert _answers(_cmd(port, b"$J=G91X10F60\n")) == ["ok"]
            time.sleep(0.3)
            assert _status(port).startswith("<Jog|")
            port.write(cancel)
            time.sleep(0.1)
            report = _status(port)
            assert report.startswith("<Idle|"), report
            x = _mpos_x(report)
            port.write(b"~")
            time.sleep(0.1)  # a resumed jog would have moved 1 mm by now
            report = _status(port)
            assert report.startswith("<Idle|") and _mpos_x(report) == x
            assert _answers(_cmd(port, b"G90G0X0\n")) == ["ok"]  # G-code is accepted again
            time.sleep(0.15)  # back at X0 (under 10 mm at 500 mm/min, scaled: 0.12 s)
    finally:
        port.close()
    states = [e["state"] for e in port.sim.record if e["ev"] == "state"]
    assert "Hold:0" not in states and "Hold:1" not in states
    partial = [e for e in port.sim.record if e["ev"] == "partial"]
    assert len(partial) == 2 and all(0 < e["to"][0] < 10 for e in partial)


def test_a_door_during_a_jog_reports_jog_until_the_jog_stopped_then_door():
    """Grbl 1.1 (protocol.c): a door during a jog only flags the jog cancel; the state
    stays Jog while it decelerates, and once stopped the jog blocks are flushed and the
    state becomes the door's, already stopped (no Door:2). A resume then runs nothing."""
    port = _open("time_scale=2")  # a 10 mm jog at F60: 20 s; the stop v/a = 0.1 s: 0.2 s
    try:
        _banner(port)
        assert _answers(_cmd(port, b"$J=G91X10F60\n")) == ["ok"]
        time.sleep(0.2)
        port.sim.open_door()
        assert _status(port).startswith("<Jog|")  # still stopping
        time.sleep(0.4)
        assert _status(port).startswith("<Door:1|")
        port.sim.close_door()
        x = _mpos_x(_status(port))
        port.write(b"~")  # restore from Door:0: the flushed jog does not come back
        time.sleep(0.2)
        report = _status(port)
        assert report.startswith("<Idle|") and _mpos_x(report) == x
    finally:
        port.close()
    states = [e["state"] for e in port.sim.record if e["ev"] == "state"]
    jog = states.index("Jog")
    assert states[jog : jog + 5] == ["Jog", "Door:1", "Door:0", "Door:3", "Idle"]
    partial = [e for e in port.sim.record if e["ev"] == "partial"]
    assert len(partial) == 1 and 0 < partial[0]["to"][0] < 1


def test_a_feed_hold_reads_lines_while_it_stops_and_none_once_held():
    """Grbl 1.1: while a hold decelerates (Hold:1) the main loop still reads and plans
    lines; once it is complete (Hold:0) the suspend loop reads none until the resume. A
    hold from Idle is complete at once, and M0's ok comes after the resume too."""
    # the G1 takes 6 s; a hold acts after the 5 segments prepared, 20 ms each (F20 runs
    # less than 1.25 steps in 10 ms: st_prep_buffer stretches them), then stops in v/a =
    # 1/30 s: within 0.16 s, 0.32 s at time_scale 2
    port = _open("time_scale=2")
    try:
        _banner(port)
        port.write(b"!")  # from Idle: Hold:0 at once
        time.sleep(0.05)
        assert _status(port).startswith("<Hold:0|")
        port.write(b"G4P0\n")
        assert _answers(_lines_for(port, 0.3)) == []
        port.write(b"~")
        assert _answers(_read_until(port, lambda ls: "ok" in ls)) == ["ok"]
        port.write(b"M0\n")  # a program pause: held, its ok after the resume
        assert _answers(_lines_for(port, 0.3)) == []
        assert _status(port).startswith("<Hold:0|")
        port.write(b"~")
        assert _answers(_read_until(port, lambda ls: "ok" in ls)) == ["ok"]
        assert _answers(_cmd(port, b"G21G90G1X1F20\n")) == ["ok"]
        time.sleep(0.1)
        port.write(b"!G1X2\n")  # the line arrives while the hold is under way
        assert _answers(_read_until(port, lambda ls: "ok" in ls, timeout=0.08)) == ["ok"]
        time.sleep(0.4)
        assert _status(port).startswith("<Hold:0|")
        port.write(b"G1X3\n")
        assert _answers(_lines_for(port, 0.3)) == []
        port.write(b"~")
        assert _answers(_read_until(port, lambda ls: "ok" in ls)) == ["ok"]  # G1X3 now
        port.write(b"!")  # held, closing the port does not wait for the moves
        time.sleep(0.15)
    finally:
        port.close()


def test_a_feed_hold_suspends_a_dwell_which_goes_on_after_the_resume():
    """Grbl 1.1's dwell (``mc_dwell`` -> ``delay_sec``) runs the realtime loop between its
    steps: a hold during the dwell is complete at once (``Hold:0``; the machine stands
    still), the suspend loop stops the dwell's count, and after ``~`` (Idle again) the dwell
    runs the time it had left, so its ``ok`` comes that long after the resume."""
    port = _open("time_scale=1")
    try:
        _banner(port)
        port.write(b"G4P0.5\n")
        time.sleep(0.1)
        port.write(b"!")
        time.sleep(0.05)
        assert _status(port).startswith("<Hold:0|")
        assert _answers(_lines_for(port, 0.45)) == []  # past the dwell's end: still held
        port.write(b"~")
        assert _answers(_lines_for(port, 0.2)) == []  # about 0.4 s of the dwell are left
        assert _status(port).startswith("<Idle|")  # dwelling again, Idle as before the hold
        assert _answers(_read_until(port, lambda ls: "ok" in ls)) == ["ok"]
        port.write(b"G4P0.3\n")  # the safety door suspends a dwell the same way
        time.sleep(0.1)
        port.write(b"\x84")
        assert _answers(_lines_for(port, 0.35)) == []
        port.sim.close_door()
        port.write(b"~")
        assert _answers(_read_until(port, lambda ls: "ok" in ls)) == ["ok"]
    finally:
        port.close()
    rec = port.sim.record
    for text, stop, seconds in (("G4P0.5", "!", 0.5), ("G4P0.3", "\x84", 0.3)):
        rx = next(e["t"] for e in rec if e["ev"] == "rx" and e["text"] == text)
        held = next(e["t"] for e in rec if e["ev"] == "rt" and e["ch"] == ord(stop) and e["t"] > rx)
        resume = next(
            e["t"] for e in rec if e["ev"] == "rt" and e["ch"] == ord("~") and e["t"] > rx
        )
        ok = next(e["t"] for e in rec if e["ev"] == "resp" and e["t"] > rx)
        assert resume - held > seconds  # the hold outlasted the whole dwell
        # the dwell counted only while not held: ``seconds`` in all, its rest after the resume
        assert ok - resume == pytest.approx(seconds - (held - rx), abs=1e-5)


# ------------------------------------------------------------- motion time: Grbl's planner


def _sim_in_own_time(options: SimOptions) -> tuple[GrblSim, list[float]]:
    """An emulator run by a fake clock (``clock[0]``, seconds) that the test moves on."""
    clock = [0.0]
    sim = GrblSim(options, clock=lambda: clock[0])
    sim.start(thread=False)
    return sim, clock


def _run_until_still(sim: GrblSim, clock: list[float]) -> None:
    """Move the fake clock from event to event until the emulator waits for input."""
    while (t := sim.next_event()) < math.inf:
        clock[0] = max(clock[0], t)
        sim.advance(clock[0])
        sim.host_read(1 << 16, 0.0)


def _stream_in_own_time(
    lines: list[str], options: SimOptions, one_at_a_time: bool = False
) -> GrblSim:
    """Stream ``lines`` into an emulator that runs in its own time, until motion ends.

    The host answers at once: character counting keeps the 128-byte RX buffer as full as
    the lines allow; ``one_at_a_time`` sends a line only after the previous one's ``ok``
    (a simple send-response sender), so over a slow link the planner runs short.
    """
    sim, clock = _sim_in_own_time(options)
    todo = collections.deque((ln + "\n").encode() for ln in lines)
    waiting: collections.deque[int] = collections.deque()  # bytes of lines awaiting an ok
    buf = b""
    while todo or waiting:
        while todo and (not waiting if one_at_a_time else sum(waiting) + len(todo[0]) <= 127):
            waiting.append(sim.host_write(todo.popleft()))
        sim.advance(clock[0])
        buf += sim.host_read(1 << 16, 0.0)
        *answers, buf = buf.split(b"\n")
        acks = [a.strip() for a in answers if a.strip() == b"ok" or a.startswith(b"error")]
        assert b"".join(acks).count(b"error") == 0, acks
        for _ in acks:
            waiting.popleft()
        if not acks:
            clock[0] = max(clock[0], sim.next_event())
            assert clock[0] < math.inf, "the emulator waits, yet lines await their ok"
    _run_until_still(sim, clock)
    sim.close()
    return sim


def _motion_seconds(sim: GrblSim) -> float:
    """From the first line's arrival until the last move or line ended (the record's times)."""
    start = next(e["t"] for e in sim.record if e["ev"] == "rx")
    return max(e["t"] for e in sim.record if e["ev"] in ("exec", "resp")) - start


def _grbl_settings(profile) -> dict[int, float]:
    m = profile.motion
    out = {110 + k: m.max_rate_mm_min[k] for k in range(3)}
    out |= {120 + k: m.acceleration_mm_s2[k] for k in range(3)}
    out[11] = m.junction_deviation_mm
    return out


def _reference(settings: dict[int, float], **kw) -> planner_sim.Settings:
    return planner_sim.Settings(
        tuple(settings[110 + k] for k in range(3)),  # type: ignore[arg-type]
        tuple(settings[120 + k] for k in range(3)),  # type: ignore[arg-type]
        settings[11],
        **kw,
    )


@pytest.mark.parametrize("name", ["grbl-3018-diamond", "grbl-plotter-scribe"])
def test_motion_time_of_an_exported_job_follows_grbls_planner(name, tmp_path):
    """The emulator times a job as Grbl 1.1's planner does (accelerations, corners by $11,
    look-ahead over its 15 blocks, stops where a line empties the planner): against the
    tests' own planner model, not distance / feed (which the check can tell apart)."""
    profile = load_profile(name)
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    tp = plan_toolpath(random_scratches(np.random.default_rng(3), 150), board, profile)
    out = tmp_path / "board.gcode"
    export(tp, profile, out)
    lines = out.read_text().splitlines()
    settings = _grbl_settings(profile)
    sim = _stream_in_own_time(lines, SimOptions(baud=115200, settings=settings))
    want = planner_sim.simulate(lines, _reference(settings), (0.0, 0.0, 0.0))
    assert _motion_seconds(sim) == pytest.approx(want.seconds, rel=1e-3)
    no_accel = {**settings, 120: 1e12, 121: 1e12, 122: 1e12}  # distance / feed
    flat = planner_sim.simulate(lines, _reference(no_accel), (0.0, 0.0, 0.0)).seconds
    assert abs(flat - want.seconds) > 0.05 * want.seconds


def _polygon(segments: int, radius: float, feed: float) -> list[str]:
    angles = np.linspace(0.0, 2.0 * np.pi, segments + 1)[1:]
    points = [f"G1 X{radius * np.cos(a):.3f} Y{radius * np.sin(a):.3f}" for a in angles]
    return ["G21 G90 G94", f"G0 X{radius:g} Y0", f"F{feed:g}", *points]


def test_a_starved_planner_stops_where_a_full_one_goes_round_corners():
    """Send-response over a link slower than the moves keeps Grbl's planner short of blocks:
    the newest always ends at rest, so the machine slows down at every block; character
    counting keeps the 15 blocks queued and the job takes the full planner's time."""
    lines = _polygon(80, 8.0, 1500.0)  # 0.6 mm sides: 25 ms each at full speed
    settings = {110: 3000.0, 111: 3000.0, 112: 600.0, 120: 200.0, 121: 200.0, 122: 50.0, 11: 0.02}
    options = SimOptions(baud=115200, latency=0.02, settings=settings)  # 20 ms each way
    full = _motion_seconds(_stream_in_own_time(lines, options))
    starved = _motion_seconds(_stream_in_own_time(lines, options, one_at_a_time=True))
    want = planner_sim.simulate(lines, _reference(settings), (0.0, 0.0, 0.0)).seconds
    assert full == pytest.approx(want, rel=2e-3)
    one_block = planner_sim.simulate(lines, _reference(settings), (0.0, 0.0, 0.0), 1).seconds
    assert full * 1.3 < starved  # a stop or near-stop at most corners
    assert one_block > full * 1.3  # (the reference agrees that stopping costs that much)


def test_a_move_that_comes_while_the_last_one_runs_joins_it():
    """Grbl re-plans the running block when a block is queued behind it: a straight
    continuation that arrives while the first move still accelerates runs as one move; one
    that arrives after the first stopped starts from rest. ``$120`` = 10 mm/s^2 (default)."""
    for gap, joined in ((0.3, True), (2.5, False)):
        sim, clock = _sim_in_own_time(SimOptions(baud=0, settings={110: 1000.0}))
        sim.host_write(b"G1X10F600\n")  # 10 mm/s needs 1 s and 5 mm to reach
        while clock[0] < gap:
            sim.host_read(1 << 16, 0.0)
            clock[0] = min(gap, sim.next_event())
            sim.advance(clock[0])
        sim.host_write(b"G1X20\n")
        _run_until_still(sim, clock)
        sim.close()
        end = max(e["t"] for e in sim.record if e["ev"] == "exec")
        # from rest to rest over 20 mm: 1 s up, 1 s at 10 mm/s, 1 s down
        one = planner_sim.block_seconds(20.0, 0.0, 0.0, 10.0, 10.0)
        assert one == pytest.approx(3.0)
        alone = 2.0 * planner_sim.block_seconds(10.0, 0.0, 0.0, 10.0, 10.0)  # 2 s each
        assert end == pytest.approx(one if joined else gap + alone / 2.0, abs=1e-6)


def test_position_and_rate_in_a_status_follow_the_acceleration():
    """Half a second into ``G1X10F600`` from rest at 10 mm/s^2: x = a t^2 / 2 = 1.25 mm, at
    5 mm/s; ``FS:`` is the speed where the segments prepared end (``st_get_realtime_rate``:
    the one from 0.5 s and 4 more, to 0.55 s: 5.5 mm/s, FS:330); Grbl reports the steps its
    interrupt took: at 1250 steps/s AMASS runs 8 ticks an event and the 313th event's
    step comes on its 5th tick, from 312.5 events on (313 steps at 250 steps/mm: 1.252)."""
    sim, clock = _sim_in_own_time(SimOptions(baud=0))
    sim.host_write(b"G1X10F600\n")
    sim.advance(0.0)
    clock[0] = 0.5
    sim.advance(0.5)
    sim.host_read(1 << 16, 0.0)
    sim.host_write(b"?")
    sim.advance(0.5)
    report = sim.host_read(1 << 16, 0.0).decode()
    x = ticks_taken((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), 1.25, 5.0)[0]
    assert x == 1.252
    assert (
        report.startswith(f"<Run|MPos:{x:.3f},0.000,0.000|")
        and f"|FS:{60.0 * 10.0 * 0.55:.0f},0" in report
    )
    sim.close()


def _report_at(sim: GrblSim, clock: list[float], t: float) -> str:
    """The status report the emulator answers to a ``?`` at ``t`` (its own time)."""
    clock[0] = t
    sim.advance(t)
    sim.host_read(1 << 16, 0.0)
    sim.host_write(b"?")
    sim.advance(t)
    return sim.host_read(1 << 16, 0.0).decode()


@pytest.mark.parametrize(("report", "shown"), [(1, "MPos"), (0, "WPos")])
def test_a_target_off_the_step_grid_is_reported_at_its_whole_steps(report, shown):
    """Grbl's planner moves to ``lround(target x $100)`` steps and reports its steps over
    $100: X0.01 is 2.5 steps at 250 steps/mm, 3 steps (0.012); Y-0.007 is -1.75, -2
    (-0.008); Z0.001 (0.25 step) does not move. WPos is that less the offset."""
    sim, clock = _sim_in_own_time(SimOptions(baud=0, wco=(0.001, 0.0, 0.0), settings={10: report}))
    sim.host_write(b"G53G1X0.01Y-0.007Z0.001F600\n")
    _run_until_still(sim, clock)
    want = planner_sim.steps_taken((0.0,) * 3, (0.01, -0.007, 0.001), 1.0)
    assert want == (0.012, -0.008, 0.0)  # the reference's own rounding
    if not report:
        want = (want[0] - 0.001, want[1], want[2])
    text = _report_at(sim, clock, clock[0] + 1.0)
    assert text.startswith("<Idle|" + shown + ":" + ",".join(f"{v:.3f}" for v in want) + "|")
    sim.close()


def test_a_report_mid_move_counts_the_steps_each_axis_has_taken():
    """Mid-move Grbl reports ``sys_position``: the step events run so far, shared out to
    each axis by the stepper's Bresenham counters, tick by tick (at 10 mm/s X steps at
    2.5 kHz: AMASS level 2, 4 ticks an event, so Y may step within an event before X).
    G1X1Y0.3 at 10 mm/s ($120-$121 so high that it is at speed within 10 us) is
    ``done = v t - v^2 / 2a`` mm in at ``t``; against the reference's interrupt ticks
    (:mod:`grbl_stepper_ticks`) at 40 random times."""
    settings = {110: 1000.0, 111: 1000.0, 120: 1e6, 121: 1e6}
    sim, clock = _sim_in_own_time(SimOptions(baud=0, settings=settings))
    sim.host_write(b"G1X1Y0.3F600\n")
    sim.advance(0.0)
    accel = settings[120] * math.hypot(1.0, 0.3)  # X's, the larger share, limits it
    for t in np.sort(np.random.default_rng(7).uniform(0.001, 0.1, 40)):
        done = 10.0 * t - 10.0**2 / (2.0 * accel)
        want = ticks_taken((0.0,) * 3, (1.0, 0.3, 0.0), done, 10.0)
        text = _report_at(sim, clock, float(t))
        assert text.startswith("<Run|MPos:" + ",".join(f"{v:.3f}" for v in want) + "|"), (t, text)
    sim.close()


def test_idle_mid_job_at_a_small_time_scale_only_with_the_planner_empty():
    """At ``time_scale=0.001`` short moves run 1000 times faster than 115200 baud brings
    their lines, so the planner runs dry and Grbl goes Idle between lines (its stepper's
    cycle stop) as it would at that speed: a report says Idle mid-job only with no block
    queued (``Bf:15``), nothing moving (``FS:0``) and the RX buffer empty (no line waits
    to be read: ``protocol_auto_cycle_start`` runs when the serial input runs dry)."""
    rng = np.random.default_rng(3)
    path = np.cumsum(rng.uniform(-0.1, 0.2, (300, 2)), axis=0) + 1.0
    lines = ["G21G90", "G1F1200"] + [f"G1X{x:.3f}Y{y:.3f}" for x, y in path]
    sim, clock = _sim_in_own_time(SimOptions(time_scale=0.001, settings={10: 3}))
    todo = collections.deque((ln + "\n").encode() for ln in lines)
    waiting: collections.deque[int] = collections.deque()  # bytes of lines awaiting an ok
    buf, poll, idle = b"", 0.0, []
    while todo or waiting:
        while todo and sum(waiting) + len(todo[0]) <= 127:  # character counting
            waiting.append(sim.host_write(todo.popleft()))
        sim.advance(clock[0])
        if clock[0] >= poll:  # a report every 8 ms (one takes 4 ms on the line)
            sim.host_write(b"?")
            poll += 0.008
        buf += sim.host_read(1 << 16, 0.0)
        *answers, buf = buf.split(b"\n")
        for a in (a.strip().decode() for a in answers):
            if a == "ok":
                waiting.popleft()
            elif a.startswith("<Idle") and (todo or waiting):
                idle.append(a)
        if "ok" not in (a.strip().decode() for a in answers):
            clock[0] = min(sim.next_event(), poll)
    sim.close()
    assert len(idle) >= 2  # it does happen
    assert all("|Bf:15,128|FS:0,0" in report for report in idle), idle


@pytest.mark.parametrize(
    ("before", "line", "laser", "waits"),
    [
        ("", "G92X0", 0, True),  # G92 / G92.1: the work offset changes
        ("", "G92.1", 0, True),
        ("", "G10L20P1X0", 0, True),  # G10 writes EEPROM
        ("", "G10L2P2X5", 0, True),
        ("", "G28.1", 0, True),
        ("", "G55", 0, True),  # another coordinate system
        ("", "G54", 0, False),  # the one already active: no change
        ("", "G43.1Z1", 0, True),
        ("", "G49", 0, False),  # no length offset to cancel
        ("", "G90G21", 0, False),
        ("M3S100", "M4", 1, True),  # laser mode: a spindle state change still waits
        ("M3S100", "G0", 1, True),  # laser mode M3: G1 -> G0 without motion (force sync)
        ("M3S100", "S200G1X20", 1, False),  # laser mode: a new S with motion goes along
        ("M3S100", "S200G1X20", 0, True),
        ("M4S100", "G0", 1, False),  # M4 (dynamic power) needs no sync there
    ],
)
def test_which_lines_wait_for_the_planner_to_empty(before, line, laser, waits):
    """Grbl 1.1 answers these only once the motion before them has ended
    (``protocol_buffer_synchronize`` via ``system_flag_wco_change``,
    ``settings_write_coord_data`` or ``spindle_sync``); the others are queued at once."""
    text = "".join(f"{ln}\n" for ln in (before, "G1X10F600", line) if ln)
    sim = _stream_in_own_time(text.splitlines(), SimOptions(baud=0, settings={32: laser}))
    rx = {e["text"]: e["n"] for e in sim.record if e["ev"] == "rx"}
    ok = next(e["t"] for e in sim.record if e["ev"] == "resp" and e["n"] == rx[line])
    moved = next(e["t"] for e in sim.record if e["ev"] == "exec" and e["n"] == rx["G1X10F600"])
    assert moved > 0.5
    assert (ok >= moved) == waits


def _run_in_own_time_or_fail(sim: GrblSim, clock: list[float], seconds: float = 10.0) -> bytes:
    """``_run_until_still`` on a watchdog thread: a controller that spins fails the test."""
    out = bytearray()

    def run() -> None:
        while (t := sim.next_event()) < math.inf:
            clock[0] = max(clock[0], t)
            sim.advance(clock[0])
            out.extend(sim.host_read(1 << 16, 0.0))

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(seconds)
    assert not worker.is_alive(), "the emulator never got past a move"
    return bytes(out)


@pytest.mark.parametrize(
    ("setting", "answer"),
    [
        ("$120=nan", "error:2"),  # read_float takes no nan or inf (a NaN move spun forever)
        ("$110=inf", "error:2"),
        ("$11=nan", "error:2"),
        ("$120=1e3", "error:3"),  # no exponent: the 'E' after the number is left over
        ("$120=50.", "ok"),
        ("$110=+400", "ok"),
    ],
)
def test_a_setting_is_read_as_grbls_read_float_reads_it(setting, answer):
    """``$N=value`` goes through Grbl's ``read_float`` (sign, digits, one point; error:2
    without digits) and must end there (error:3), as in ``system_execute_line``; a move
    after it still ends, at the time of the settings Grbl then has."""
    sim, clock = _sim_in_own_time(SimOptions(baud=0))
    sim.host_write(f"{setting}\nG1X10F600\n".encode())
    lines = _run_in_own_time_or_fail(sim, clock).decode().split()
    sim.close()
    assert lines[-2:] == [answer, "ok"]
    if answer == "ok":
        key, value = setting[1:].split("=")
        assert sim.settings[int(key)] == float(value)
    rate, accel = min(600.0, sim.settings[110]) / 60.0, sim.settings[120]
    end = max(e["t"] for e in sim.record if e["ev"] == "exec")
    assert end == pytest.approx(planner_sim.block_seconds(10.0, 0.0, 0.0, rate, accel), abs=1e-6)


@pytest.mark.parametrize("key", [110, 120])
def test_a_zero_rate_or_acceleration_limits_only_moves_along_its_axis(key):
    """Grbl's ``limit_value_by_axis_maximum`` skips the axes a move does not use: ``$110=0``
    or ``$120=0`` leaves a Y move as it was (0/0 spun the emulator before), and an X
    move crawls at ``MINIMUM_FEED_RATE`` (1 mm/min) or ends up at a finite time."""
    sim, clock = _sim_in_own_time(SimOptions(baud=0, settings={111: 600.0, key: 0.0}))
    sim.host_write(b"G0Y10\nG4P0\nG1X10Y10F600\n")
    _run_in_own_time_or_fail(sim, clock)
    sim.close()
    ends = [e["t"] for e in sim.record if e["ev"] == "exec"]
    assert ends[0] == pytest.approx(planner_sim.block_seconds(10.0, 0.0, 0.0, 10.0, 10.0))
    assert math.isfinite(ends[1]) and ends[1] - ends[0] > 10.0
    if key == 110:  # 10 mm at 1 mm/min
        assert ends[1] - ends[0] == pytest.approx(600.0, rel=1e-3)


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"time_scale": math.nan}, "SimOptions.time_scale"),  # NaN times spun the thread
        ({"time_scale": math.inf}, "SimOptions.time_scale"),
        ({"latency": -0.001}, "SimOptions.latency"),
        ({"settings": {120: math.nan}}, "$120=nan"),
        ({"settings": {110: -1.0}}, "$110=-1.0"),
        ({"settings": {999: 1.0}}, "$999=1.0"),
    ],
)
def test_options_built_in_code_meet_the_bounds_of_a_url(kwargs, named):
    """SimOptions from code are checked as a ``grblsim://`` query is (finite, in bounds,
    Grbl 1.1 settings at least 0), so no emulator starts with a time or limit that is NaN;
    the URL's own checks still answer first, as one line."""
    with pytest.raises(ValueError, match=re.escape(named)):
        SimOptions(**kwargs)
    assert SimOptions(settings={110: 0.0}, time_scale=0.0).settings == {110: 0.0}


@pytest.mark.parametrize("middle", ["G1X10F100", "G1X10.001F100", "G1Y0.0019F100"])
def test_a_move_of_no_steps_does_not_slow_the_moves_around_it(middle):
    """Grbl drops a block whose target rounds to the steps it is at (``plan_buffer_line``
    returns ``PLAN_EMPTY_BLOCK``: no entry speed, no nominal speed, no direction), so a
    repeated point or one less than a step away, even at a slower feed, leaves the two
    moves around it one straight 20 mm move, as the planner reference times it."""
    settings = {110: 1000.0, 111: 1000.0, 112: 1000.0, 120: 10.0, 121: 10.0, 122: 10.0, 11: 0.01}
    lines = ["G1X10F1000", middle, "G1X20F1000"]
    sim = _stream_in_own_time(lines, SimOptions(baud=0, settings=settings))
    want = planner_sim.simulate(lines, _reference(settings), (0.0, 0.0, 0.0)).seconds
    assert want == pytest.approx(planner_sim.block_seconds(20.0, 0.0, 0.0, 1000 / 60, 10.0))
    assert _motion_seconds(sim) == pytest.approx(want, rel=1e-4)
