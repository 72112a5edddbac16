"""Pseudo-terminal fixtures for serial-sensor tests.

``pty_pair``: a pty whose master end the test drives as the device (write what the device sends,
read what the code under test sent) while the code under test opens ``pty_pair.path`` with
pyserial like any serial port. ``open_serial``: opens pyserial ports that are closed at teardown.

A pty is not an RS485 line: it has no baud-rate timing (writes arrive at once), no parity
errors, and closing the master end (``close_master``) is the nearest thing to pulling the cable:
the other end's next read or write fails with EIO.
"""

from __future__ import annotations

import contextlib
import os
import select
import time
import tty
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest
import serial


@dataclass
class PtyPair:
    """A pseudo-terminal: ``master_fd`` is the device side, ``path`` the port the code opens.

    The slave end stays open (``slave_fd``, raw mode) so the master does not see a hang-up
    before the code under test opens ``path``.
    """

    master_fd: int
    slave_fd: int
    path: str
    closed: bool = field(default=False)

    def write(self, data: bytes) -> None:
        """Send ``data`` to the code under test, as the device."""
        view = memoryview(data)
        while view:
            view = view[os.write(self.master_fd, view) :]

    def read(self, n: int, timeout_s: float = 2.0) -> bytes:
        """Read what the code under test sent, until ``n`` bytes or ``timeout_s`` (s) passed."""
        out = bytearray()
        deadline = time.monotonic() + timeout_s
        while len(out) < n:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            ready, _, _ = select.select([self.master_fd], [], [], left)
            if ready:
                out += os.read(self.master_fd, n - len(out))
        return bytes(out)

    def drain(self, timeout_s: float = 0.0) -> bytes:
        """All the code under test sent so far (waiting up to ``timeout_s`` for a first byte)."""
        out = bytearray()
        wait = timeout_s
        while True:
            ready, _, _ = select.select([self.master_fd], [], [], wait)
            if not ready:
                return bytes(out)
            out += os.read(self.master_fd, 4096)
            wait = 0.0

    def close_master(self) -> None:
        """Hang up: close the device side (and the keep-alive slave fd), like pulling the cable."""
        if not self.closed:
            self.closed = True
            for fd in (self.master_fd, self.slave_fd):
                with contextlib.suppress(OSError):
                    os.close(fd)


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    """A fresh raw-mode pty; closed at teardown."""
    master, slave = os.openpty()
    tty.setraw(slave)
    pair = PtyPair(master, slave, os.ttyname(slave))
    try:
        yield pair
    finally:
        pair.close_master()


@pytest.fixture
def open_serial() -> Iterator[Callable[..., serial.Serial]]:
    """``open_serial(path, **kwargs)`` -> an open pyserial port, closed at teardown."""
    ports: list[serial.Serial] = []

    def opener(path: str, **kwargs: object) -> serial.Serial:
        kwargs.setdefault("baudrate", 115200)
        kwargs.setdefault("timeout", 0.05)
        port = serial.Serial(path, **kwargs)
        ports.append(port)
        return port

    yield opener
    for port in ports:
        with contextlib.suppress(Exception):
            port.close()
