"""Line-stream tracker reader: the records of :mod:`.linestream` read over UDP or TCP."""

from __future__ import annotations

import contextlib
import re
import select
import socket
import time
from typing import Literal

import numpy as np

from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.sample import Clock
from cdcr_ctl.sensors.tracker.frames import TrackerTransform, rotation_from_quaternion
from cdcr_ctl.sensors.tracker.linestream import MAX_LINE_BYTES, parse_stream_line
from cdcr_ctl.sensors.tracker.reader import (
    MAX_DATAGRAMS_PER_POLL,
    RECV_BUFFER_BYTES,
    RECV_POLL_S,
    REORDER_WINDOW_S,
    TipTracker,
)


class LineStreamTracker(TipTracker):
    """Reads the line stream (:mod:`cdcr_ctl.sensors.tracker.linestream`) from an injected socket.

    ``sock``: a bound UDP socket (``transport="udp"``) or a connected TCP socket
    (``transport="tcp"``); made non-blocking here and closed by :meth:`close`. ``port_name``
    names the link in errors (``udp://127.0.0.1:5000``). A TCP peer closing the connection is a
    :class:`SensorError` (the reader stops); UDP silence marks the tracker lost until data returns.
    """

    def __init__(
        self,
        sock: socket.socket,
        transform: TrackerTransform,
        *,
        transport: Literal["udp", "tcp"],
        port_name: str,
        stale_after_s: float = 0.1,
        lost_after_s: float = 1.0,
        clock: Clock = time.monotonic,
    ) -> None:
        super().__init__(
            transform,
            port_name=port_name,
            stale_after_s=stale_after_s,
            lost_after_s=lost_after_s,
            clock=clock,
        )
        self.sock = sock
        self.transport = transport
        try:
            sock.setblocking(False)
        except OSError as exc:
            raise SensorError(port_name, f"cannot use socket: {exc}") from exc
        self._buffer = bytearray()
        self._skipping = False
        self._last_t: float | None = None
        self._lines = 0

    def poll(self) -> None:
        """Take in what arrived (waiting <= RECV_POLL_S)."""
        self._check_lost(self.clock())
        try:
            ready, _, _ = select.select([self.sock], [], [], RECV_POLL_S)
        except (OSError, ValueError) as exc:
            raise SensorError(self.port_name, f"socket failed: {exc}") from exc
        for _ in range(MAX_DATAGRAMS_PER_POLL if ready else 0):
            try:
                data = self.sock.recv(RECV_BUFFER_BYTES)
            except BlockingIOError:
                return
            except OSError as exc:
                raise SensorError(self.port_name, f"connection failed: {exc}") from exc
            if not data and self.transport == "tcp":
                raise SensorError(self.port_name, "connection closed by the sender")
            self.handle_bytes(data, self.clock())
            if self.transport == "tcp":
                return

    def handle_bytes(self, data: bytes, t_rx: float | None = None) -> None:
        """Decode one UDP datagram or one TCP read that arrived at ``t_rx`` (s, reader clock)."""
        t = self.clock() if t_rx is None else t_rx
        self.stats.received += 1
        if self.transport == "udp":
            for line in bytes(data).splitlines():
                self._line(line, t)
            return
        for piece in re.split(rb"(\n)", bytes(data)):
            if piece == b"\n":
                if not self._skipping:
                    self._line(bytes(self._buffer), t)
                self._buffer.clear()
                self._skipping = False
            elif piece:
                if self._skipping:
                    self.stats.discarded_bytes += len(piece)
                    continue
                self._buffer += piece
                if len(self._buffer) > MAX_LINE_BYTES + 1:
                    self._bad(bytes(self._buffer), "line too long")
                    self._buffer.clear()
                    self._skipping = True

    def _line(self, line: bytes, t_rx: float) -> None:
        line = line.rstrip(b"\r")
        if not line.strip() or line.lstrip().startswith(b"#"):
            return
        point = parse_stream_line(line)
        if point is None:
            self._bad(line, "not a t,x,y,z[,qx,qy,qz,qw] line")
            return
        last = self._last_t
        if last is not None and 0 <= last - point.t_s < REORDER_WINDOW_S:
            self.stats.out_of_order += 1
            return
        self._last_t = point.t_s
        self._lines += 1
        self._alive(t_rx)
        if point.orientation_xyzw is None:
            R, has_rotation = np.eye(3), False
        else:
            R, has_rotation = rotation_from_quaternion(point.orientation_xyzw), True
        self._publish(
            point.position,
            R,
            has_rotation=has_rotation,
            frame=self._lines,
            tracker_time_s=point.t_s,
            latency_s=0.0,
            t_rx=t_rx,
        )

    def _close_transport(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()
