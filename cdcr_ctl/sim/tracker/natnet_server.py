"""Simulated NatNet server (Motive stand-in) for one rigid body on loopback, unicast.

Packets are :mod:`cdcr_ctl.sensors.natnet`'s. Fault hooks: :meth:`~SimNatNetServer.pause` (stop
serving: no frames, no answers), :meth:`~SimNatNetServer.resume`, :meth:`~SimNatNetServer.occlude`
(force the body lost), :meth:`~SimNatNetServer.inject` (send raw bytes, e.g. garbage).
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

from cdcr_ctl.sensors.natnet import (
    DEFAULT_VERSION,
    FrameOfData,
    LabeledMarker,
    MarkerSet,
    MessageId,
    NatNetDecodeError,
    NatNetVersion,
    RigidBodyPose,
    ServerInfo,
    check_version,
    pack_frame_of_data,
    pack_message,
    pack_server_info,
    split_message,
)
from cdcr_ctl.sensors.tracker import TrackerTransform
from cdcr_ctl.sensors.tracker.frames import quaternion_xyzw
from cdcr_ctl.sim.tracker.feed import Truth, TruthSampler
from cdcr_ctl.sim.tracker.server import LOOP_WAIT_S, _ServerThread, require_loopback

#: One logger for the simulated trackers (the name of the former single module).
log = logging.getLogger("cdcr_ctl.sim.tracker")

#: Ticks per second of the simulated server's high-resolution clock (Motive's is QPC-based).
SIM_CLOCK_HZ = 10_000_000
#: Mean marker error the simulated server reports for a tracked body (tracker units).
MEAN_ERROR_UNITS = 0.0002
#: A unicast client that sent neither NAT_CONNECT nor a keep-alive for this long is dropped (s).
SUBSCRIBER_TIMEOUT_S = 5.0


class SimNatNetServer(_ServerThread):
    """A NatNet server for one rigid body on 127.0.0.1, unicast.

    Command port: answers NAT_CONNECT with NAT_SERVERINFO (``version``, clock, data port) and
    registers the sender as a unicast subscriber; NAT_KEEPALIVE refreshes it (dropped after
    :data:`SUBSCRIBER_TIMEOUT_S` without one); other requests get NAT_UNRECOGNIZED_REQUEST.
    Data: every ``1/rate_hz`` s a NAT_FRAMEOFDATA (from the data port's socket) to every
    subscriber, ``latency_s`` after the truth was sampled, with the camera mid-exposure and
    transmit stamps set accordingly. ``dropout``: probability that a frame has the body occluded,
    either flagged (``dropout_mode="invalid"``: tracking-valid bit cleared, pose zeroed) or left
    out (``"missing"``). ``include_markers``: also send a marker set and labeled markers (the
    client must skip them). ``command_port``/``data_port`` 0: ephemeral (see
    :attr:`command_address`).
    """

    name = "sim natnet"

    def __init__(
        self,
        truth: Truth,
        *,
        transform: TrackerTransform | None = None,
        truth_frame: Literal["base", "tracker"] = "base",
        rigid_body_id: int = 1,
        host: str = "127.0.0.1",
        command_port: int = 0,
        data_port: int = 0,
        rate_hz: float = 120.0,
        latency_s: float = 0.0,
        noise_mm: float = 0.0,
        dropout: float = 0.0,
        dropout_mode: Literal["invalid", "missing"] = "invalid",
        version: NatNetVersion = DEFAULT_VERSION,
        include_markers: bool = False,
        seed: int = 1,
        application: str = "cdcr-ctl sim",
    ) -> None:
        super().__init__()
        check_version(version)
        if not rate_hz > 0 or latency_s < 0 or not 0 <= dropout <= 1:
            raise ValueError("need rate_hz > 0, latency_s >= 0 and 0 <= dropout <= 1")
        if dropout_mode not in ("invalid", "missing"):
            raise ValueError(f"dropout_mode must be 'invalid' or 'missing', not {dropout_mode!r}")
        host = require_loopback(host)
        self.transform = transform or TrackerTransform.identity(1000.0)
        self.rng = np.random.default_rng(seed)
        self.sampler = TruthSampler(truth, self.transform, truth_frame, noise_mm, self.rng)
        self.rigid_body_id = rigid_body_id
        self.period_s = 1.0 / rate_hz
        self.latency_s = float(latency_s)
        self.dropout = float(dropout)
        self.dropout_mode = dropout_mode
        self.version = NatNetVersion(*version)
        self.include_markers = include_markers
        self.application = application
        self.cmd_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.data_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.cmd_sock.bind((host, command_port))
            self.data_sock.bind((host, data_port))
        except OSError:
            self._close_sockets()
            raise
        self.subscribers: dict[tuple[str, int], float] = {}
        self._lock = threading.Lock()
        self._queue: collections.deque[tuple[float, FrameOfData]] = collections.deque()
        self._t0 = time.monotonic()
        self.frame_number = 0
        self.frames_sent = 0
        self.commands_received = 0

    @property
    def command_address(self) -> tuple[str, int]:
        """(host, port) of the command socket."""
        return self.cmd_sock.getsockname()

    @property
    def data_address(self) -> tuple[str, int]:
        """(host, port) the frames are sent from."""
        return self.data_sock.getsockname()

    def server_info(self) -> ServerInfo:
        """What this server answers to NAT_CONNECT."""
        return ServerInfo(
            self.application,
            (3, 1, 0, 0),
            self.version,
            SIM_CLOCK_HZ,
            self.data_address[1],
            False,
            "0.0.0.0",
        )

    def inject(self, data: bytes) -> None:
        """Fault hook: send ``data`` as one datagram to every subscriber (garbage, bad frames)."""
        for address in self._live_subscribers(time.monotonic()):
            self.data_sock.sendto(data, address)

    def make_frame(self, now: float, transmit_s: float | None = None) -> FrameOfData:
        """Sample the truth and build the frame for time ``now`` (s, monotonic); its transmit
        stamp is ``transmit_s`` (s, default ``now``)."""
        self.frame_number += 1
        occluded = self._occluded or (self.dropout > 0 and self.rng.random() < self.dropout)
        bodies: list[RigidBodyPose] = []
        if occluded and self.dropout_mode == "invalid":
            bodies.append(
                RigidBodyPose(self.rigid_body_id, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), 0.0, False)
            )
        elif not occluded:
            pose = self._pose()
            if pose is not None:
                bodies.append(RigidBodyPose(self.rigid_body_id, *pose, MEAN_ERROR_UNITS, True))
        markers: tuple[MarkerSet, ...] = ()
        labeled: tuple[LabeledMarker, ...] = ()
        if self.include_markers and bodies:
            x, y, z = bodies[0].position
            pts = ((x + 0.01, y, z), (x, y + 0.01, z), (x, y, z + 0.01))
            markers = (MarkerSet("tip", pts), MarkerSet("all", pts))
            labeled = tuple(
                LabeledMarker((self.rigid_body_id << 16) | (i + 1), pt, 0.008, 0x04, 0.0001)
                for i, pt in enumerate(pts)
            )
        ticks, transmit = self._ticks(now, transmit_s)
        return FrameOfData(
            frame_number=self.frame_number,
            rigid_bodies=tuple(bodies),
            timestamp_s=now - self._t0,
            stamp_mid_exposure=ticks,
            stamp_data_received=ticks,
            stamp_transmit=transmit,
            marker_sets=markers,
            labeled_markers=labeled,
        )

    def make_datagram(self, now: float, transmit_s: float | None = None) -> bytes:
        """:meth:`make_frame` packed for the stream's version (the datagram to send)."""
        return pack_frame_of_data(self.make_frame(now, transmit_s), self.version)

    def _pose(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]] | None:
        """The body's pose sampled now: (position in tracker units, quaternion xyzw), or None
        when the truth failed (counted, logged)."""
        try:
            p, rows = self.sampler.sample_floats()
        except Exception:
            self.truth_errors += 1
            log.exception("sim natnet: truth callable failed")
            return None
        x, y, z = p
        qx, qy, qz, qw = quaternion_xyzw(rows)
        return (x, y, z), (qx, qy, qz, qw)

    def _ticks(self, now: float, transmit_s: float | None) -> tuple[int, int]:
        """(mid-exposure, transmit) stamps of a frame at ``now`` sent at ``transmit_s`` (s; None:
        at ``now``), in ticks of :data:`SIM_CLOCK_HZ`."""
        ticks = int(now * SIM_CLOCK_HZ)
        return ticks, ticks if transmit_s is None else int(transmit_s * SIM_CLOCK_HZ)

    # -- loop -------------------------------------------------------------------------------

    def _run(self) -> None:
        next_tick = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            due = self._queue[0][0] if self._queue else math.inf
            wait = max(0.0, min(next_tick, due, now + LOOP_WAIT_S) - now)
            try:
                ready, _, _ = select.select([self.cmd_sock], [], [], wait)
            except (OSError, ValueError):
                return  # closed under us
            if ready:
                self._command()
            now = time.monotonic()
            if now >= next_tick:
                if not self._paused.is_set():
                    self._queue.append((now + self.latency_s, self.make_frame(now)))
                next_tick += self.period_s
                if next_tick < now:  # fell behind (loaded CPU): skip, don't burst
                    next_tick = now + self.period_s
            while self._queue and self._queue[0][0] <= now:
                _, frame = self._queue.popleft()
                if not self._paused.is_set():
                    self._send_frame(frame, now)

    def _send_frame(self, frame: FrameOfData, now: float) -> None:
        frame = FrameOfData(
            frame_number=frame.frame_number,
            rigid_bodies=frame.rigid_bodies,
            timestamp_s=frame.timestamp_s,
            stamp_mid_exposure=frame.stamp_mid_exposure,
            stamp_data_received=frame.stamp_data_received,
            stamp_transmit=int(now * SIM_CLOCK_HZ),
            marker_sets=frame.marker_sets,
            labeled_markers=frame.labeled_markers,
        )
        data = pack_frame_of_data(frame, self.version)
        for address in self._live_subscribers(now):
            with contextlib.suppress(OSError):
                self.data_sock.sendto(data, address)
        self.frames_sent += 1

    def _live_subscribers(self, now: float) -> list[tuple[str, int]]:
        with self._lock:
            for address, seen in list(self.subscribers.items()):
                if now - seen > SUBSCRIBER_TIMEOUT_S:
                    del self.subscribers[address]
            return list(self.subscribers)

    def _command(self) -> None:
        try:
            data, address = self.cmd_sock.recvfrom(65536)
        except OSError:
            return
        if self._paused.is_set():
            return
        self.commands_received += 1
        try:
            message_id, _ = split_message(data)
        except NatNetDecodeError:
            return
        now = time.monotonic()
        if message_id == MessageId.NAT_CONNECT:
            with self._lock:
                self.subscribers[address] = now
            reply = pack_server_info(self.server_info())
        elif message_id == MessageId.NAT_KEEPALIVE:
            with self._lock:
                self.subscribers[address] = now
            return
        else:
            reply = pack_message(MessageId.NAT_UNRECOGNIZED_REQUEST)
        with contextlib.suppress(OSError):
            self.cmd_sock.sendto(reply, address)

    def _close_sockets(self) -> None:
        for s in (self.cmd_sock, self.data_sock):
            with contextlib.suppress(OSError):
                s.close()
