"""sd_notify(3) in a few lines: READY, STATUS, WATCHDOG, STOPPING to systemd's notify socket.

With no ``NOTIFY_SOCKET`` in the environment (not started by systemd) every call is a no-op.
"""

from __future__ import annotations

import contextlib
import os
import socket


class SystemdNotifier:
    """Sends datagrams to ``$NOTIFY_SOCKET``; abstract-namespace sockets (``@...``) supported."""

    def __init__(self, address: str | None = None) -> None:
        addr = address if address is not None else os.environ.get("NOTIFY_SOCKET", "")
        self._addr = "\0" + addr[1:] if addr.startswith("@") else addr
        self._sock: socket.socket | None = None
        if self._addr:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, state: str) -> None:
        """Send one state string, e.g. ``READY=1\\nSTATUS=running``; errors are swallowed."""
        if self._sock is None:
            return
        with contextlib.suppress(OSError):
            self._sock.sendto(state.encode(), self._addr)

    def ready(self, status: str = "") -> None:
        self.notify("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def status(self, status: str) -> None:
        self.notify(f"STATUS={status}")

    def watchdog(self) -> None:
        self.notify("WATCHDOG=1")

    def stopping(self) -> None:
        self.notify("STOPPING=1")

    @staticmethod
    def watchdog_period_s() -> float | None:
        """Half of ``$WATCHDOG_USEC`` (systemd's advice), or None when no watchdog is armed."""
        usec = os.environ.get("WATCHDOG_USEC")
        if not usec or not usec.isdigit():
            return None
        pid = os.environ.get("WATCHDOG_PID")
        if pid and pid.isdigit() and int(pid) != os.getpid():
            return None
        return int(usec) / 2e6

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
