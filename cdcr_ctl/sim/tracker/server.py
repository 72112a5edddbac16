"""Loopback-only serving thread shared by the simulated trackers (start, stop, context manager).

Serves on 127.0.0.1 only (a non-loopback address is refused: the simulator never sends to a real
interface, and never multicasts).
"""

from __future__ import annotations

import ipaddress
import threading
from typing import Self

#: Longest wait of the server loop between checks of its stop flag (s).
LOOP_WAIT_S = 0.02


def require_loopback(host: str) -> str:
    """``host`` if it is an IPv4 loopback address, else ValueError (loopback only)."""
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        raise ValueError(f"simulated tracker host must be a loopback IP, got {host!r}") from None
    if not ip.is_loopback or ip.version != 4:
        raise ValueError(f"simulated tracker serves IPv4 loopback only, not {host}")
    return host


class _ServerThread:
    """Start/stop/context-manager plumbing shared by the two simulators."""

    name = "sim tracker"

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._occluded = False
        self._thread: threading.Thread | None = None
        self.truth_errors = 0

    def start(self) -> Self:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def close(self) -> None:
        self.stop()
        self._close_sockets()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def pause(self) -> None:
        """Fault hook: stop serving (no frames, no answers) until :meth:`resume`."""
        self._paused.set()

    def resume(self) -> None:
        """Serve again after :meth:`pause`."""
        self._paused.clear()

    def occlude(self, on: bool = True) -> None:
        """Fault hook: report the body as lost in every frame while ``on``."""
        self._occluded = on

    def _run(self) -> None:
        raise NotImplementedError

    def _close_sockets(self) -> None:
        raise NotImplementedError
