"""What `stream` says when its serial port will not open: one line a maker can act on.

A missing port names the ports pyserial sees and how to list them on this system; a
refused one (Linux) the ``dialout`` group; a port another program holds says so.
"""

from __future__ import annotations

import errno
import os
from types import SimpleNamespace

import pytest
import serial
from test_stream import write_job

from scratchfab.cli import main
from scratchfab.errors import ScratchfabError
from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.sender import open_port, port_trouble

#: pyserial's message for a COM port that does not exist (serialwin32.Serial.open).
_WIN_MISSING = (
    "could not open port 'COM7': FileNotFoundError(2, 'The system cannot find the file "
    "specified.', None, 2)"
)


def _seen(monkeypatch, devices):
    """pyserial's port listing, as a machine with ``devices`` plugged in gives it."""
    ports = [SimpleNamespace(device=d) for d in devices]
    monkeypatch.setattr("serial.tools.list_ports.comports", lambda: ports)


def _missing(tmp_path) -> serial.SerialException:
    """What pyserial raises for a device path that does not exist."""
    with pytest.raises(serial.SerialException) as info:
        serial.Serial(str(tmp_path / "ttyUSB9"), 115200)
    return info.value


@pytest.mark.skipif(os.name != "posix", reason="POSIX device paths")
def test_a_missing_port_on_the_command_line_is_one_line_naming_the_ports_seen(
    tmp_path, monkeypatch, capsys
):
    job = tmp_path / "job.gcode"
    write_job(job, 2)
    _seen(monkeypatch, ["/dev/ttyACM0", "/dev/ttyUSB1"])
    port = tmp_path / "ttyUSB0"
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(job), "--port", str(port), "--yes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"error: cannot open port '{port}': no such port (")
    assert "ports seen here: /dev/ttyACM0, /dev/ttyUSB1" in err


@pytest.mark.parametrize(
    ("platform", "listing"),
    [
        ("linux", "`ls /dev/ttyUSB* /dev/ttyACM*`"),
        ("darwin", "`ls /dev/cu.*`"),
        ("win32", "Device Manager's Ports (COM & LPT)"),
        ("freebsd14", None),
    ],
)
def test_a_missing_port_says_how_to_list_the_ports_on_each_system(
    tmp_path, monkeypatch, platform, listing
):
    _seen(monkeypatch, [])
    exc = serial.SerialException(_WIN_MISSING) if platform == "win32" else _missing(tmp_path)
    text = port_trouble("COM7" if platform == "win32" else "/dev/ttyUSB0", exc, platform)
    assert "no such port" in text and "no serial port is seen here" in text
    assert "plugged in" in text
    if listing is None:
        assert "list them" not in text and "Device Manager" not in text
    else:
        assert text.endswith(listing) or listing in text


def test_many_ports_seen_are_cut_short(monkeypatch, tmp_path):
    devices = [f"/dev/ttyS{k}" for k in range(11)]
    _seen(monkeypatch, devices)
    text = port_trouble("/dev/ttyUSB0", _missing(tmp_path), "linux")
    shown = sorted(devices)[:8]
    assert f"ports seen here: {', '.join(shown)} and 3 more;" in text


def test_a_listing_that_fails_loses_only_the_hint(monkeypatch, tmp_path):
    def broken():
        raise OSError("no /sys")

    monkeypatch.setattr("serial.tools.list_ports.comports", broken)
    text = port_trouble("/dev/ttyUSB0", _missing(tmp_path), "linux")
    assert "no such port" in text and "could not be listed" in text


@pytest.mark.parametrize("platform", ["linux", "darwin"])
def test_a_refused_port_names_the_dialout_group_on_linux(platform):
    exc = serial.SerialException(
        errno.EACCES,
        "could not open port /dev/ttyUSB0: [Errno 13] Permission denied: '/dev/ttyUSB0'",
    )
    text = port_trouble("/dev/ttyUSB0", exc, platform)
    assert text.startswith("Permission denied: your user may not open")
    assert ("dialout group" in text) == (platform == "linux")


def test_a_port_in_use_on_windows_says_another_program_has_it():
    exc = serial.SerialException(
        "could not open port 'COM3': PermissionError(13, 'Access is denied.', None, 5)"
    )
    text = port_trouble("COM3", exc, "win32")
    assert "another program has the port open" in text and "dialout" not in text


@pytest.mark.skipif(os.name != "posix", reason="a pseudo-terminal")
def test_a_port_another_stream_holds_says_so():
    with GrblPty(SimOptions()) as pty:
        first = open_port(pty.path, 115200)
        try:
            with pytest.raises(ScratchfabError) as info:
                open_port(pty.path, 115200)
        finally:
            first.close()
    text = str(info.value)
    assert text.startswith(f"cannot open port '{pty.path}': another program has the port open")


def test_a_url_gets_pyserials_message_alone(monkeypatch):
    def listed():
        raise AssertionError("a URL needs no port listing")

    monkeypatch.setattr("serial.tools.list_ports.comports", listed)
    exc = ValueError("grblsim: unknown key 'bogus'")
    assert port_trouble("grblsim://?bogus=1", exc, "linux") == str(exc)
