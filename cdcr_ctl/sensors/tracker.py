"""Tip tracker: OptiTrack NatNet rigid body or a plain line stream, as the tip in the base frame.

Two readers, one output. :class:`NatNetTracker` is a NatNet client (protocol in
:mod:`cdcr_ctl.sensors.natnet`) for one rigid body; :class:`LineStreamTracker` reads the plain
line stream below over UDP or TCP (laser trackers, bridges). Both turn every good measurement
into the tip position in the ROBOT BASE FRAME (mm) with :class:`TrackerTransform` and publish it
with its acquisition time; the control loop calls ``latest()`` and never waits on the network.

Frames and units. The tracker reports the rigid body's pose in its own frame and units:
position ``p_b`` (units) and rotation ``R_tb`` (body -> tracker). With ``s`` = mm per unit,
``(R_mb, t_mb)`` = ``marker_to_tip`` (tip frame -> body frame, mm) and ``(R_bt, t_bt)`` =
``base_from_tracker`` (tracker frame -> base frame, mm)::

    p_tip_tracker_mm = s * p_b + R_tb @ t_mb
    p_tip_base_mm    = R_bt @ p_tip_tracker_mm + t_bt
    R_base_tip       = R_bt @ R_tb @ R_mb

Line stream format (ASCII, one measurement per line, ``\\n`` or ``\\r\\n`` terminated)::

    t_s,x,y,z[,qx,qy,qz,qw]

``t_s``: the sender's timestamp (s, any epoch, increasing). ``x,y,z``: the measured point in the
tracker frame, in tracker units (mm unless ``units_to_mm`` says otherwise). ``qx,qy,qz,qw``:
optional unit quaternion (scalar last) of the target's orientation (6-DoF trackers); without it
the orientation is taken as the identity, so ``marker_to_tip.translation_mm`` is then an offset
along the tracker's axes. Numbers are decimals (``-12.5``, ``1e-3``); spaces around fields are
allowed; lines starting with ``#`` and empty lines are ignored; anything else that is not such a
line (wrong field count, non-finite numbers, a quaternion of norm far from 1, over
:data:`MAX_LINE_BYTES`) is counted as bad and skipped. Over UDP a datagram carries whole lines
(its end also ends a line); over TCP lines may be split anywhere.
"""

from __future__ import annotations

import contextlib
import ipaddress
import math
import re
import select
import socket
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from cdcr_ctl.config.tracking import RigidTransformConfig, TrackerConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.loadcell import TrafficLog
from cdcr_ctl.sensors.natnet import (
    MessageId,
    NatNetDecodeError,
    NatNetVersion,
    ServerInfo,
    check_version,
    pack_connect,
    pack_keepalive,
    parse_frame_of_data,
    parse_server_info,
    split_message,
)
from cdcr_ctl.sensors.polling import PollingReader
from cdcr_ctl.sensors.sample import Clock, LatestValue

#: Longest wait of one poll on the socket (s); bounds how long ``stop()`` takes.
RECV_POLL_S = 0.02
#: Receive buffer per datagram (bytes): a NatNet datagram is at most 65535 + 4.
RECV_BUFFER_BYTES = 65536 + 4
#: Most datagrams taken in by one poll (a flood must not keep ``stop()`` waiting).
MAX_DATAGRAMS_PER_POLL = 256
#: How often a unicast NatNet client tells the server it is still there (s).
KEEPALIVE_PERIOD_S = 0.5
#: How often NAT_CONNECT is re-sent while no server info or no frames arrive (s).
RECONNECT_PERIOD_S = 1.0
#: Unit quaternions must have a norm within this of 1 (float32 rounding is ~1e-7).
QUATERNION_NORM_TOL = 1e-3
#: A frame number this much or less below the newest is a reordered/duplicate datagram;
#: further below is a server restart and is accepted.
REORDER_WINDOW_FRAMES = 1000
#: The same for line-stream timestamps (s).
REORDER_WINDOW_S = 1.0
#: Longest line of the line stream (bytes, without the line end).
MAX_LINE_BYTES = 200


# -- rotations ------------------------------------------------------------------------------


def rotation_from_rotvec(rotvec: np.ndarray | list[float]) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis * angle, rad), by Rodrigues' formula."""
    v = np.asarray(rotvec, dtype=float)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def rotation_from_quaternion(q_xyzw: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w; scalar last), normalised first.

    ValueError when the norm is not within :data:`QUATERNION_NORM_TOL` of 1 or not finite.
    """
    q = np.asarray(q_xyzw, dtype=float)
    n = float(np.linalg.norm(q))
    if not (math.isfinite(n) and abs(n - 1.0) <= QUATERNION_NORM_TOL):
        raise ValueError(f"not a unit quaternion (norm {n})")
    x, y, z, w = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w; w >= 0) of a rotation matrix (Shepperd's method)."""
    m = np.asarray(R, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
    out = np.asarray(q) / np.linalg.norm(q)
    return -out if out[3] < 0 else out


# -- frames ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrackerTransform:
    """Tracker-frame body pose -> tip in the robot base frame (see the module docstring).

    ``R_base_tracker``, ``t_base_tracker_mm``: base_from_tracker; ``R_body_tip``,
    ``t_body_tip_mm``: marker_to_tip (the tip in the body frame); ``mm_per_unit``: tracker scale.
    """

    R_base_tracker: np.ndarray
    t_base_tracker_mm: np.ndarray
    R_body_tip: np.ndarray
    t_body_tip_mm: np.ndarray
    mm_per_unit: float

    @classmethod
    def identity(cls, mm_per_unit: float = 1.0) -> TrackerTransform:
        """No alignment, tip at the body origin."""
        return cls(np.eye(3), np.zeros(3), np.eye(3), np.zeros(3), mm_per_unit)

    @classmethod
    def from_transforms(
        cls,
        base_from_tracker: RigidTransformConfig,
        marker_to_tip: RigidTransformConfig,
        mm_per_unit: float,
    ) -> TrackerTransform:
        """From the two config transforms (rotation vectors in rad, translations in mm)."""
        return cls(
            rotation_from_rotvec(base_from_tracker.rotvec_rad),
            np.asarray(base_from_tracker.translation_mm, dtype=float),
            rotation_from_rotvec(marker_to_tip.rotvec_rad),
            np.asarray(marker_to_tip.translation_mm, dtype=float),
            float(mm_per_unit),
        )

    @classmethod
    def from_config(cls, cfg: TrackerConfig) -> TrackerTransform:
        """From a tracker config section."""
        return cls.from_transforms(cfg.base_from_tracker, cfg.marker_to_tip, cfg.mm_per_unit)

    def tip_in_base(
        self, position_units: np.ndarray | tuple[float, ...], R_tracker_body: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(tip position in the base frame (mm), R_base_tip) for a body pose in tracker units."""
        p_tracker_mm = self.mm_per_unit * np.asarray(position_units, dtype=float)
        p_tracker_mm = p_tracker_mm + R_tracker_body @ self.t_body_tip_mm
        p_base = self.R_base_tracker @ p_tracker_mm + self.t_base_tracker_mm
        return p_base, self.R_base_tracker @ R_tracker_body @ self.R_body_tip

    def body_in_tracker(
        self, p_tip_base_mm: np.ndarray, R_base_tip: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`tip_in_base`: (body position in tracker units, R_tracker_body)."""
        R_tb = self.R_base_tracker.T @ np.asarray(R_base_tip, dtype=float) @ self.R_body_tip.T
        p_tracker_mm = self.R_base_tracker.T @ (
            np.asarray(p_tip_base_mm, dtype=float) - self.t_base_tracker_mm
        )
        return (p_tracker_mm - R_tb @ self.t_body_tip_mm) / self.mm_per_unit, R_tb


# -- samples --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TipMeasurement:
    """What a tracker reader publishes: the tip in the base frame and where it came from.

    ``position_mm``: tip, base frame (mm). ``rotation``: R_base_tip, or None when the source
    has no orientation. ``frame``: the tracker's frame number (line streams: lines so far).
    ``tracker_time_s``: the sender's timestamp (s, its own clock). ``latency_s``: what the
    sender reported as its own delay from exposure to transmission (0 when unknown).
    """

    position_mm: np.ndarray
    rotation: np.ndarray | None
    frame: int
    tracker_time_s: float
    latency_s: float


@dataclass(frozen=True, slots=True)
class TipSample:
    """The loop's view of the tip: newest measurement, its time and age, and its health.

    ``position_mm``: tip in the robot base frame (mm), NaN before the first sample;
    ``rotation``: R_base_tip or None. ``t_s``: acquisition time on the reader's clock
    (time.monotonic: receipt minus the sender's reported latency). ``age_s``: now - t_s (inf
    before the first sample). ``stale``: older than ``stale_after_s``, none yet, or the tracker is
    lost. ``occluded``: the newest frame had no valid pose of the body (it is not published, so
    the previous pose ages). ``frame``, ``tracker_time_s``: from the tracker. ``seq``: count of
    published samples (tells a reader whether this one is new).
    """

    position_mm: np.ndarray
    rotation: np.ndarray | None
    t_s: float
    age_s: float
    stale: bool
    occluded: bool
    frame: int
    tracker_time_s: float
    seq: int


@dataclass
class TrackerStats:
    """Counters of one tracker link since the reader was made.

    ``received``: datagrams (TCP: reads) taken in; ``samples``: tip samples published; ``bad``:
    undecodable datagrams or lines; ``occluded``: frames without a valid pose of the body;
    ``out_of_order``: reordered or repeated frames dropped; ``foreign``: datagrams from another
    host; ``other_messages``: NatNet messages other than frames and server info;
    ``discarded_bytes``: bytes thrown away with bad data.
    """

    received: int = 0
    samples: int = 0
    bad: int = 0
    occluded: int = 0
    out_of_order: int = 0
    foreign: int = 0
    other_messages: int = 0
    discarded_bytes: int = 0


_NAN3 = np.full(3, np.nan)
_NAN3.setflags(write=False)


class TipTracker(PollingReader):
    """Shared part of the tracker readers: transform, latest value, stats, lost detection.

    ``transform``: tracker -> base. ``stale_after_s`` (s): age beyond which a sample is stale.
    ``lost_after_s`` (s): silence after which :attr:`failure` says the tracker is lost (cleared
    by the next measurement; the thread keeps running). ``clock``: seconds, default
    time.monotonic (tests inject one).
    """

    def __init__(
        self,
        transform: TrackerTransform,
        *,
        port_name: str,
        stale_after_s: float = 0.1,
        lost_after_s: float = 1.0,
        clock: Clock = time.monotonic,
    ) -> None:
        super().__init__()
        self.transform = transform
        self.port_name = port_name
        self.clock = clock
        self.lost_after_s = float(lost_after_s)
        self.stats = TrackerStats()
        self.traffic = TrafficLog()
        self.values: LatestValue[TipMeasurement] = LatestValue(stale_after_s, clock)
        self.occluded = False
        self._last_rx_s: float | None = None  # last time the source showed life
        self._lost = False
        #: Why the last bad datagram or line was rejected (for logs).
        self.last_error = ""

    # -- what the loop calls ------------------------------------------------------------------

    def latest(self, now_s: float | None = None) -> TipSample:
        """Newest tip sample aged at ``now_s`` (s; default: the clock now). Never blocks."""
        got = self.values.latest(now_s)
        m = got.value
        if m is None:
            return TipSample(_NAN3, None, math.nan, math.inf, True, self.occluded, 0, math.nan, 0)
        stale = got.stale or self._lost or (self.failure is not None)
        return TipSample(
            m.position_mm,
            m.rotation,
            got.t_s,
            got.age_s,
            stale,
            self.occluded,
            m.frame,
            m.tracker_time_s,
            got.seq,
        )

    def position_and_age(self, now_s: float | None = None) -> tuple[np.ndarray, float]:
        """(tip in the base frame (mm), age (s)): NaNs and inf before the first sample."""
        s = self.latest(now_s)
        return s.position_mm.copy(), s.age_s

    # -- for subclasses ---------------------------------------------------------------------

    def _alive(self, t_rx: float) -> None:
        """The source showed life at ``t_rx``: clear a 'lost' failure."""
        self._last_rx_s = t_rx
        if self._lost:
            self._lost = False
            self.failure = None

    def _publish(
        self,
        position_units: np.ndarray | tuple[float, ...],
        R_tracker_body: np.ndarray,
        *,
        has_rotation: bool,
        frame: int,
        tracker_time_s: float,
        latency_s: float,
        t_rx: float,
    ) -> None:
        p, R = self.transform.tip_in_base(position_units, R_tracker_body)
        p.setflags(write=False)
        R.setflags(write=False)
        m = TipMeasurement(p, R if has_rotation else None, frame, tracker_time_s, latency_s)
        self.values.publish(m, t_rx - latency_s)
        self.occluded = False
        self.stats.samples += 1

    def _check_lost(self, now: float) -> bool:
        """Flag the tracker lost after ``lost_after_s`` of silence; True while lost."""
        last = self._last_rx_s
        if last is None or now - last <= self.lost_after_s:
            return self._lost
        if not self._lost:
            self._lost = True
            self.values.invalidate()
            self.failure = SensorError(
                self.port_name,
                f"tracker lost: nothing received for {now - last:.2f} s "
                f"(limit {self.lost_after_s} s); stopped streaming or unreachable",
            )
        return True

    def _bad(self, data: bytes, why: str) -> None:
        self.stats.bad += 1
        self.stats.discarded_bytes += len(data)
        self.traffic.add("rx", data[:64])
        self.last_error = why


# -- NatNet ---------------------------------------------------------------------------------


class NatNetTracker(TipTracker):
    """NatNet client for one rigid body on an injected UDP socket.

    ``sock``: a bound UDP socket (made non-blocking here; owned: closed by :meth:`close`).
    ``server``: (host, command port) of the NatNet server. ``rigid_body_id``: the body to track.
    ``unicast``: send keep-alives so a unicast server keeps streaming to this socket (False when
    the socket has joined the multicast group). See :class:`TipTracker` for the other arguments.

    Frames are accepted only from the server's address. The stream version comes from the
    server's NAT_SERVERINFO (:meth:`connect`); frames before it are dropped.
    """

    def __init__(
        self,
        sock: socket.socket,
        server: tuple[str, int],
        transform: TrackerTransform,
        rigid_body_id: int,
        *,
        unicast: bool = True,
        stale_after_s: float = 0.1,
        lost_after_s: float = 1.0,
        clock: Clock = time.monotonic,
    ) -> None:
        host, command_port = server
        super().__init__(
            transform,
            port_name=f"natnet://{host}:{command_port}",
            stale_after_s=stale_after_s,
            lost_after_s=lost_after_s,
            clock=clock,
        )
        self.sock = sock
        try:
            self._server = (socket.gethostbyname(host), int(command_port))
            sock.setblocking(False)
        except OSError as exc:
            raise SensorError(self.port_name, f"cannot use socket/host: {exc}") from exc
        self.rigid_body_id = int(rigid_body_id)
        self.unicast = unicast
        self.server_info: ServerInfo | None = None
        self.version: NatNetVersion | None = None
        self._last_frame: int | None = None
        self._last_keepalive_s = -math.inf
        self._last_connect_s = -math.inf

    def send_connect(self) -> None:
        """Send NAT_CONNECT to the server's command port."""
        self._send(pack_connect())
        self._last_connect_s = time.monotonic()

    def connect(self, timeout_s: float = 2.0) -> ServerInfo:
        """Send NAT_CONNECT and wait for NAT_SERVERINFO (blocking: start-up only, not the loop).

        Raises :class:`SensorError` naming the server when no answer comes within ``timeout_s``
        (s) or the server streams an unsupported NatNet version.
        """
        self.send_connect()
        deadline = time.monotonic() + timeout_s
        while self.server_info is None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise SensorError(
                    self.port_name,
                    f"no NAT_SERVERINFO within {timeout_s} s (is the server streaming, in "
                    f"{'unicast' if self.unicast else 'multicast'} mode, on this port?)",
                )
            self._receive(min(left, RECV_POLL_S))
            if self.failure is not None:
                raise self.failure
        return self.server_info

    def poll(self) -> None:
        """Keep-alive / reconnect as due, then take in what arrived (waiting <= RECV_POLL_S)."""
        now_wall = time.monotonic()
        lost = self._check_lost(self.clock())
        if (self.server_info is None or lost) and (
            now_wall - self._last_connect_s >= RECONNECT_PERIOD_S
        ):
            self.send_connect()
        if self.unicast and now_wall - self._last_keepalive_s >= KEEPALIVE_PERIOD_S:
            self._send(pack_keepalive())
            self._last_keepalive_s = now_wall
        self._receive(RECV_POLL_S)

    def handle_datagram(
        self, data: bytes, source: tuple[str, int] | None = None, t_rx: float | None = None
    ) -> None:
        """Decode one datagram received from ``source`` at ``t_rx`` (s, reader clock).

        Publishes a tip sample when it is a frame with a valid pose of the body; counts and
        skips everything else. Never raises for bad data.
        """
        t = self.clock() if t_rx is None else t_rx
        self.stats.received += 1
        if source is not None and source[0] != self._server[0]:
            self.stats.foreign += 1
            self.stats.discarded_bytes += len(data)
            return
        try:
            message_id, payload = split_message(data)
        except NatNetDecodeError as exc:
            self._bad(data, str(exc))
            return
        if message_id == MessageId.NAT_FRAMEOFDATA:
            self._frame(data, payload, t)
        elif message_id == MessageId.NAT_SERVERINFO:
            self._server_info(data, payload)
        else:
            self.stats.other_messages += 1

    # -- internals ----------------------------------------------------------------------------

    def _server_info(self, data: bytes, payload: bytes) -> None:
        try:
            info = parse_server_info(payload)
        except NatNetDecodeError as exc:
            self._bad(data, str(exc))
            return
        try:
            check_version(info.natnet_version)
        except ValueError as exc:
            self.failure = SensorError(self.port_name, f"{info.application}: {exc}")
            return
        self.server_info = info
        self.version = info.natnet_version
        if self._last_rx_s is None:  # frames should follow from now on
            self._last_rx_s = self.clock()

    def _frame(self, data: bytes, payload: bytes, t_rx: float) -> None:
        if self.version is None:
            self.stats.other_messages += 1  # a frame before the server info: cannot be read
            return
        try:
            frame = parse_frame_of_data(payload, self.version)
        except NatNetDecodeError as exc:
            self._bad(data, str(exc))
            return
        last = self._last_frame
        if last is not None and 0 <= last - frame.frame_number < REORDER_WINDOW_FRAMES:
            self.stats.out_of_order += 1
            return
        self._last_frame = frame.frame_number
        self._alive(t_rx)
        body = frame.rigid_body(self.rigid_body_id)
        if body is None or not body.tracking_valid:
            self._occluded()
            return
        try:
            R = rotation_from_quaternion(body.orientation_xyzw)
        except ValueError:
            self._occluded()
            return
        if not all(math.isfinite(v) for v in body.position):
            self._occluded()
            return
        latency = frame.server_latency_s(self.server_info.clock_hz if self.server_info else None)
        self._publish(
            body.position,
            R,
            has_rotation=True,
            frame=frame.frame_number,
            tracker_time_s=frame.timestamp_s,
            latency_s=latency if latency is not None and latency < 1.0 else 0.0,
            t_rx=t_rx,
        )

    def _occluded(self) -> None:
        self.occluded = True
        self.stats.occluded += 1

    def _send(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self._server)
        except OSError as exc:
            raise SensorError(self.port_name, f"cannot send to the server: {exc}") from exc

    def _receive(self, wait_s: float) -> None:
        try:
            ready, _, _ = select.select([self.sock], [], [], wait_s)
        except (OSError, ValueError) as exc:
            raise SensorError(self.port_name, f"socket failed: {exc}") from exc
        for _ in range(MAX_DATAGRAMS_PER_POLL if ready else 0):
            try:
                data, source = self.sock.recvfrom(RECV_BUFFER_BYTES)
            except BlockingIOError:
                return
            except OSError as exc:
                raise SensorError(self.port_name, f"socket failed: {exc}") from exc
            self.handle_datagram(data, source, self.clock())

    def _close_transport(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()


# -- line stream ----------------------------------------------------------------------------

_NUMBER = rb"\s*([+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*"
_LINE = re.compile(_NUMBER + (rb"," + _NUMBER) * 3 + rb"(?:" + (rb"," + _NUMBER) * 4 + rb")?")


@dataclass(frozen=True, slots=True)
class StreamPoint:
    """One line of the line stream: sender time (s), position (tracker units), orientation."""

    t_s: float
    position: tuple[float, float, float]
    orientation_xyzw: tuple[float, float, float, float] | None = None


def parse_stream_line(line: bytes) -> StreamPoint | None:
    """A line (without its line end) as a :class:`StreamPoint`, or None if it is not valid.

    Comments and empty lines are not valid points either: callers skip them before.
    """
    if len(line) > MAX_LINE_BYTES:
        return None
    m = _LINE.fullmatch(line)
    if m is None:
        return None
    values = [float(g) for g in m.groups() if g is not None]
    if not all(math.isfinite(v) for v in values):
        return None
    t, x, y, z = values[:4]
    if len(values) == 4:
        return StreamPoint(t, (x, y, z))
    q = values[4:]
    if abs(math.sqrt(sum(c * c for c in q)) - 1.0) > QUATERNION_NORM_TOL:
        return None
    return StreamPoint(t, (x, y, z), (q[0], q[1], q[2], q[3]))


def format_stream_line(
    t_s: float,
    position: tuple[float, ...] | np.ndarray,
    orientation_xyzw: tuple[float, ...] | np.ndarray | None = None,
) -> bytes:
    """The line for one measurement, ``\\n`` included (positions with 4 decimals)."""
    fields = [f"{t_s:.6f}"] + [f"{float(v):.4f}" for v in position]
    if orientation_xyzw is not None:
        fields += [f"{float(v):.7f}" for v in orientation_xyzw]
    return (",".join(fields) + "\n").encode("ascii")


class LineStreamTracker(TipTracker):
    """Reads the line stream (module docstring) from an injected socket.

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


# -- construction from config ---------------------------------------------------------------


def local_bind_address(cfg: TrackerConfig) -> str:
    """Local address to bind: ``cfg.local_address``, else 127.0.0.1 for a loopback server and
    all interfaces ("") otherwise."""
    if cfg.local_address is not None:
        return cfg.local_address
    try:
        ip = ipaddress.ip_address(socket.gethostbyname(cfg.host))
    except (OSError, ValueError):
        return ""
    return "127.0.0.1" if ip.is_loopback else ""


def open_tracker(
    cfg: TrackerConfig, *, clock: Clock = time.monotonic, start: bool = True
) -> NatNetTracker | LineStreamTracker:
    """Make the reader ``cfg.kind`` asks for, connect it and (``start``) start its thread.

    NatNet waits up to ``cfg.connect_timeout_s`` for the server's answer. Raises
    :class:`SensorError` naming the address when the socket cannot be made or nobody answers.
    """
    transform = TrackerTransform.from_config(cfg)
    stale, lost = cfg.stale_after_s, cfg.lost_after_s
    reader: NatNetTracker | LineStreamTracker
    if cfg.kind == "natnet":
        sock = _natnet_socket(cfg)
        reader = NatNetTracker(
            sock,
            (cfg.host, cfg.command_port),
            transform,
            cfg.rigid_body_id,
            unicast=cfg.multicast_group is None,
            stale_after_s=stale,
            lost_after_s=lost,
            clock=clock,
        )
        try:
            reader.connect(cfg.connect_timeout_s)
        except BaseException:
            reader.close()
            raise
    elif cfg.kind == "udp_stream":
        name = f"udp://{cfg.host}:{cfg.port}"
        sock = _socket(name, socket.SOCK_DGRAM)
        _bind(sock, name, (cfg.host, cfg.port))
        reader = LineStreamTracker(
            sock,
            transform,
            transport="udp",
            port_name=name,
            stale_after_s=stale,
            lost_after_s=lost,
            clock=clock,
        )
    else:
        name = f"tcp://{cfg.host}:{cfg.port}"
        try:
            sock = socket.create_connection(
                (cfg.host, cfg.port),
                timeout=cfg.connect_timeout_s,
                source_address=(local_bind_address(cfg), 0),
            )
        except OSError as exc:
            raise SensorError(name, f"cannot connect: {exc}") from exc
        reader = LineStreamTracker(
            sock,
            transform,
            transport="tcp",
            port_name=name,
            stale_after_s=stale,
            lost_after_s=lost,
            clock=clock,
        )
    return reader.start() if start else reader


def _socket(name: str, kind: int) -> socket.socket:
    try:
        return socket.socket(socket.AF_INET, kind)
    except OSError as exc:
        raise SensorError(name, f"cannot create socket: {exc}") from exc


def _bind(sock: socket.socket, name: str, address: tuple[str, int]) -> None:
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise SensorError(name, f"cannot bind {address[0] or '*'}:{address[1]}: {exc}") from exc


def _natnet_socket(cfg: TrackerConfig) -> socket.socket:
    """Unicast: a UDP socket on an ephemeral port. Multicast: bound to the data port and joined
    to ``cfg.multicast_group`` on the local interface (never exercised by the tests)."""
    name = f"natnet://{cfg.host}:{cfg.command_port}"
    sock = _socket(name, socket.SOCK_DGRAM)
    local = local_bind_address(cfg)
    if cfg.multicast_group is None:
        _bind(sock, name, (local, 0))
        return sock
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        _bind(sock, name, ("", cfg.port))
        membership = socket.inet_aton(cfg.multicast_group) + socket.inet_aton(local or "0.0.0.0")
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
    except OSError as exc:
        sock.close()
        raise SensorError(name, f"cannot join {cfg.multicast_group}: {exc}") from exc
    return sock
