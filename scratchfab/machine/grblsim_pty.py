"""The GRBL emulator behind a pseudo-terminal, so any sender can open it as a serial device."""

from __future__ import annotations

import contextlib
import errno
import os
import select
import threading
import tty

from scratchfab.machine.grblsim import GrblSim, LinkDown, SimOptions


class GrblPty:
    """A :class:`GrblSim` on the master side of a pty; :attr:`path` is the device to open.

    The slave side is kept open here as well, so senders can close and reopen it. A pty has no
    DTR line: the emulator powers up (banner) once at :meth:`start`; a sender that misses the
    banner soft-resets (``0x18``) to get a fresh one, as it would with a real board.

    Args:
        options: Emulator behaviour and fault injection.
    """

    def __init__(self, options: SimOptions | None = None) -> None:
        self.sim = GrblSim(options)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._closed = threading.Event()
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self.sim.on_link_down = self._close_master

    def start(self) -> GrblPty:
        """Start the emulator and the two pump threads; returns self."""
        self.sim.start()
        for target in (self._pump_in, self._pump_out):
            th = threading.Thread(target=target, name=f"grblpty-{target.__name__}", daemon=True)
            th.start()
            self._threads.append(th)
        return self

    def _pump_in(self) -> None:
        while not self._closed.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(self._master, 4096)
            except OSError:
                return
            if not data:
                continue
            try:
                self.sim.host_write(data)
            except LinkDown:
                return

    def _pump_out(self) -> None:
        while not self._closed.is_set():
            try:
                data = self.sim.host_read(4096, 0.05)
            except LinkDown:
                return
            view = memoryview(data)
            while view and not self._closed.is_set():
                try:
                    written = os.write(self._master, view)
                    view = view[written:]
                except BlockingIOError:
                    select.select([], [self._master], [], 0.05)
                except OSError as exc:
                    if exc.errno in (errno.EIO, errno.EBADF):
                        return
                    raise

    def _close_master(self) -> None:
        with self._lock:
            if not self._closed.is_set():
                self._closed.set()
                for th in self._threads:
                    if th is not threading.current_thread():
                        th.join(timeout=1.0)
                with contextlib.suppress(OSError):
                    os.close(self._master)
                with contextlib.suppress(OSError):
                    os.close(self._slave)

    def close(self) -> None:
        """Stop the pumps, close the pty and let the emulator drain and write its record."""
        self._close_master()
        self.sim.close()

    def __enter__(self) -> GrblPty:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
