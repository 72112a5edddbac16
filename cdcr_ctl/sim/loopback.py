"""A simulated device's loopback TCP listener: what stands in for a serial link when the link's
bytes must not wait for the kernel's tty worker (:mod:`cdcr_ctl.sim.slcan_device`)."""

from __future__ import annotations

import socket


def listen_loopback(port: int = 0) -> tuple[socket.socket, str]:
    """A listener on 127.0.0.1:``port`` (0: one the kernel picks) for one client at a time, and
    the URL clients open it by (pyserial's ``socket://127.0.0.1:PORT``)."""
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", port))
    listener.listen(1)
    return listener, f"socket://127.0.0.1:{listener.getsockname()[1]}"
