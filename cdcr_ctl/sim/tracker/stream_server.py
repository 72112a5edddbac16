"""Simulated line-stream tracker: lines of :mod:`cdcr_ctl.sensors.tracker.linestream` on loopback.

Fault hooks as the NatNet server's, and for TCP :meth:`SimLineStreamServer.hang_up` (close the
connection).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import select
import socket
import threading
import time
from typing import Literal

import numpy as np

from cdcr_ctl.sensors.tracker import TrackerTransform, format_stream_line, quaternion_from_rotation
from cdcr_ctl.sim.tracker.feed import Truth, TruthSampler
from cdcr_ctl.sim.tracker.server import LOOP_WAIT_S, _ServerThread, require_loopback

#: One logger for the simulated trackers (the name of the former single module).
log = logging.getLogger("cdcr_ctl.sim.tracker")


class SimLineStreamServer(_ServerThread):
    """Sends the line stream (see :mod:`cdcr_ctl.sensors.tracker.linestream`) on loopback.

    ``transport="udp"``: one line per datagram to ``target`` (the reader's bound address).
    ``transport="tcp"``: listens on ``host``:``port`` (0: ephemeral, see :attr:`address`) and
    streams to the first client that connects. ``units_per_mm``: tracker units of the lines are
    ``transform.mm_per_unit``. ``with_orientation``: append the body quaternion. ``dropout``:
    probability that a line is not sent. ``latency_s``: delay between sampling and sending.
    """

    name = "sim line stream"

    def __init__(
        self,
        truth: Truth,
        *,
        transport: Literal["udp", "tcp"],
        target: tuple[str, int] | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
        transform: TrackerTransform | None = None,
        truth_frame: Literal["base", "tracker"] = "base",
        rate_hz: float = 100.0,
        latency_s: float = 0.0,
        noise_mm: float = 0.0,
        dropout: float = 0.0,
        with_orientation: bool = False,
        seed: int = 1,
    ) -> None:
        super().__init__()
        host = require_loopback(host)
        if transport == "udp":
            if target is None:
                raise ValueError("a UDP line stream needs a target address")
            require_loopback(target[0])
        elif transport != "tcp":
            raise ValueError(f"transport must be 'udp' or 'tcp', not {transport!r}")
        self.transport = transport
        self.target = target
        self.transform = transform or TrackerTransform.identity(1.0)
        self.rng = np.random.default_rng(seed)
        self.sampler = TruthSampler(truth, self.transform, truth_frame, noise_mm, self.rng)
        self.period_s = 1.0 / rate_hz
        self.latency_s = float(latency_s)
        self.dropout = float(dropout)
        self.with_orientation = with_orientation
        self.lines_sent = 0
        self._queue: collections.deque[tuple[float, bytes]] = collections.deque()
        self._conn: socket.socket | None = None
        self._t0 = time.monotonic()
        self.sock = socket.socket(
            socket.AF_INET, socket.SOCK_DGRAM if transport == "udp" else socket.SOCK_STREAM
        )
        try:
            if transport == "tcp":
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self.sock.bind((host, port))
                self.sock.listen(1)
            else:
                self.sock.bind((host, 0))
        except OSError:
            self.sock.close()
            raise
        self.connected = threading.Event()

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) of the TCP listening socket or the UDP sending socket."""
        return self.sock.getsockname()

    def inject(self, data: bytes) -> None:
        """Fault hook: send raw ``data`` (one datagram / written to the TCP stream)."""
        self._write(data)

    def hang_up(self) -> None:
        """Fault hook (TCP): close the client connection, like a sender that died."""
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
            conn.close()

    def make_line(self, now: float) -> bytes | None:
        """Sample the truth and format the line for time ``now`` (None on a dropout)."""
        if self._occluded or (self.dropout > 0 and self.rng.random() < self.dropout):
            return None
        try:
            p, R = self.sampler.sample()
        except Exception:
            self.truth_errors += 1
            log.exception("sim line stream: truth callable failed")
            return None
        q = quaternion_from_rotation(R) if self.with_orientation else None
        return format_stream_line(now - self._t0, p, q)

    def _run(self) -> None:
        next_tick = time.monotonic()
        while not self._stop.is_set():
            if self.transport == "tcp" and self._conn is None and not self._accept():
                continue
            now = time.monotonic()
            due = self._queue[0][0] if self._queue else math.inf
            wait = max(0.0, min(next_tick, due, now + LOOP_WAIT_S) - now)
            if self._stop.wait(wait):
                return
            now = time.monotonic()
            if now >= next_tick:
                if not self._paused.is_set():
                    line = self.make_line(now)
                    if line is not None:
                        self._queue.append((now + self.latency_s, line))
                next_tick += self.period_s
                if next_tick < now:
                    next_tick = now + self.period_s
            while self._queue and self._queue[0][0] <= now:
                _, line = self._queue.popleft()
                if not self._paused.is_set() and self._write(line):
                    self.lines_sent += 1

    def _accept(self) -> bool:
        try:
            ready, _, _ = select.select([self.sock], [], [], LOOP_WAIT_S)
            if not ready:
                return False
            conn, _ = self.sock.accept()
        except OSError:
            self._stop.wait(LOOP_WAIT_S)
            return False
        self._conn = conn
        self.connected.set()
        return True

    def _write(self, data: bytes) -> bool:
        try:
            if self.transport == "udp":
                assert self.target is not None
                self.sock.sendto(data, self.target)
            elif self._conn is not None:
                self._conn.sendall(data)
            else:
                return False
        except OSError:
            if self.transport == "tcp":
                self.hang_up()
            return False
        return True

    def _close_sockets(self) -> None:
        self.hang_up()
        with contextlib.suppress(OSError):
            self.sock.close()
