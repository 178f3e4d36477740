"""pyserial URL handler for ``grblsim://``: the built-in GRBL 1.1 emulator as a serial port.

``serial.serial_for_url("grblsim://?time_scale=0.01&error_at=500")`` looks for a module
named ``protocol_grblsim`` in ``serial.protocol_handler_packages``; importing
:mod:`scratchfab.machine.sender` adds ``scratchfab.machine`` to that list. Query keys are the
fields of :class:`~scratchfab.machine.grblsim.SimOptions` plus ``$N=value`` setting overrides,
all checked on opening (a bad one raises :class:`~scratchfab.errors.ConfigError`).
Opening the port powers the emulator up (like the DTR reset of an Arduino); closing it lets the
controller finish what it received, then writes its record. The emulator is :attr:`Serial.sim`.
"""

from __future__ import annotations

import time
import urllib.parse
from typing import Any

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from scratchfab.errors import ConfigError
from scratchfab.machine.grblsim import GrblSim, LinkDown, SimOptions


def grblsim_query(port: str) -> dict[str, str] | None:
    """The pairs of a ``grblsim://`` URL's query (percent-decoded); None for another port.

    The one reader of such URLs: the scheme as pyserial picks a handler (the text before
    ``://``, any case), the query as this handler takes it.

    Raises:
        ConfigError: A key given more than once (one line naming the port).
    """
    scheme, sep, _ = port.partition("://")
    if not sep or scheme.lower() != "grblsim":
        return None
    query: dict[str, str] = {}
    for key, value in urllib.parse.parse_qsl(
        urllib.parse.urlsplit(port).query, keep_blank_values=True
    ):
        if key in query:
            raise ConfigError(f"port {port!r}: {key}: given more than once")
        query[key] = value
    return query


def sim_options(port: str, baud: int) -> SimOptions | None:
    """The options the emulator of a ``grblsim://`` port opens with; None for another port.

    Args:
        port: The URL.
        baud: The port's baud rate: the line speed unless the URL sets ``baud``.

    Raises:
        ConfigError: A bad option (one line naming the port and the key).
    """
    query = grblsim_query(port)
    if query is None:
        return None
    query.setdefault("baud", str(baud))
    return SimOptions.from_query(query, f"port {port!r}")


class Serial(SerialBase):
    """A pyserial port whose other end is a :class:`~scratchfab.machine.grblsim.GrblSim`."""

    is_open: bool

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.sim: GrblSim | None = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        """Create and power up the emulator described by the URL.

        Raises:
            ConfigError: A bad option in the URL (one line naming the URL and the key).
        """
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        options = sim_options(self.portstr or "", self._baudrate)
        if options is None:
            raise SerialException(f"expected a grblsim:// URL, got {self.portstr!r}")
        self.sim = GrblSim(options)
        self.sim.start()
        self.is_open = True

    def close(self) -> None:
        """Close the port; the emulator drains what it received and writes its record."""
        if self.is_open and self.sim is not None:
            self.is_open = False
            self.sim.close()
        super().close()

    def _reconfigure_port(self) -> None:
        """Settings are taken from the URL; nothing to configure."""

    def _need(self) -> GrblSim:
        if not self.is_open or self.sim is None:
            raise PortNotOpenError()
        return self.sim

    @property
    def in_waiting(self) -> int:
        """Bytes ready to read."""
        try:
            return self._need().host_in_waiting()
        except LinkDown as exc:
            raise SerialException(f"device disconnected: {exc}") from exc

    def read(self, size: int = 1) -> bytes:
        """Read up to ``size`` bytes, honouring the port's timeout."""
        sim = self._need()
        out = bytearray()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        while len(out) < size:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                chunk = sim.host_read(size - len(out), left)
            except LinkDown as exc:
                raise SerialException(f"device disconnected: {exc}") from exc
            out += chunk
            if not chunk or (deadline is not None and time.monotonic() >= deadline):
                break
        return bytes(out)

    def write(self, data: bytes | bytearray | memoryview) -> int:  # type: ignore[override]
        """Send bytes to the emulator."""
        try:
            return self._need().host_write(bytes(data))
        except LinkDown as exc:
            raise SerialException(f"device disconnected: {exc}") from exc

    def reset_input_buffer(self) -> None:
        """Discard received bytes."""
        self._need().host_flush_input()

    def reset_output_buffer(self) -> None:
        """Nothing is buffered on the way out."""
        self._need()

    @property
    def out_waiting(self) -> int:
        """Nothing is buffered on the way out."""
        return 0

    def _update_dtr_state(self) -> None:
        """DTR is not modelled beyond the power-up on open."""

    def _update_rts_state(self) -> None:
        """RTS is not modelled."""

    def _update_break_state(self) -> None:
        """Break is not modelled."""

    @property
    def cts(self) -> bool:
        """Always clear to send."""
        return True

    @property
    def dsr(self) -> bool:
        """Always ready."""
        return True

    @property
    def ri(self) -> bool:
        """No ring indicator."""
        return False

    @property
    def cd(self) -> bool:
        """Carrier always detected."""
        return True
