"""Simulated tip trackers on loopback: a NatNet server (Motive stand-in) and a line-stream sender.

Both sample a *truth* callable at their frame rate, add noise, latency and occlusion dropouts,
and serve the result on 127.0.0.1 only (a non-loopback address is refused: the simulator never
sends to a real interface, and never multicasts).

The truth callable takes no argument and returns the pose now, either as ``(R, p_mm)`` (a 3x3
rotation and a position in mm) or as a bare position ``p_mm`` (rotation = identity):

- ``truth_frame="base"``: the TIP pose in the robot base frame (what the robot model computes);
  the simulator inverts the tracker transform (``transform``: the *true* alignment, which may
  differ from the controller's config to simulate a calibration error) to get the rigid body's
  pose in the tracker frame;
- ``truth_frame="tracker"``: the rigid BODY pose in the tracker frame (mm).

Fault hooks: :meth:`pause` (stop serving: no frames, no answers), :meth:`resume`,
:meth:`occlude` (force the body lost), :meth:`inject` (send raw bytes, e.g. garbage), and for
TCP :meth:`SimLineStreamServer.hang_up` (close the connection).
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import ipaddress
import logging
import math
import select
import socket
import threading
import time
from collections.abc import Callable
from typing import Any, Literal, Self

import numpy as np

from cdcr_ctl.config.tracking import RigidTransformConfig, TrackerConfig
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
from cdcr_ctl.sensors.tracker import (
    TrackerTransform,
    format_stream_line,
    quaternion_from_rotation,
    rotation_from_rotvec,
)
from cdcr_ctl.sim.simconfig import SimConfig

log = logging.getLogger(__name__)

Pose = tuple[np.ndarray, np.ndarray]
Truth = Callable[[], Pose | np.ndarray]

#: Ticks per second of the simulated server's high-resolution clock (Motive's is QPC-based).
SIM_CLOCK_HZ = 10_000_000
#: A unicast client that sent neither NAT_CONNECT nor a keep-alive for this long is dropped (s).
SUBSCRIBER_TIMEOUT_S = 5.0
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


class TruthSampler:
    """Turns the truth callable into a noisy rigid-body pose in tracker frame and units.

    ``noise_mm``: standard deviation of isotropic Gaussian position noise (mm). ``rng``: numpy
    Generator (seeded by the caller for repeatable runs).
    """

    def __init__(
        self,
        truth: Truth,
        transform: TrackerTransform,
        truth_frame: Literal["base", "tracker"],
        noise_mm: float,
        rng: np.random.Generator,
    ) -> None:
        if truth_frame not in ("base", "tracker"):
            raise ValueError(f"truth_frame must be 'base' or 'tracker', not {truth_frame!r}")
        self.truth = truth
        self.transform = transform
        self.truth_frame = truth_frame
        self.noise_mm = float(noise_mm)
        self.rng = rng

    def sample(self) -> tuple[np.ndarray, np.ndarray]:
        """(body position in tracker units, R_tracker_body) now."""
        got = self.truth()
        if isinstance(got, tuple):
            R, p_mm = np.asarray(got[0], dtype=float), np.asarray(got[1], dtype=float)
        else:
            R, p_mm = np.eye(3), np.asarray(got, dtype=float)
        if self.truth_frame == "base":
            p_units, R_tb = self.transform.body_in_tracker(p_mm, R)
        else:
            p_units, R_tb = p_mm / self.transform.mm_per_unit, R
        if self.noise_mm > 0:
            p_units = p_units + self.rng.normal(0.0, self.noise_mm, 3) / self.transform.mm_per_unit
        return p_units, R_tb


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

    def make_frame(self, now: float) -> FrameOfData:
        """Sample the truth and build the frame for time ``now`` (s, monotonic)."""
        self.frame_number += 1
        occluded = self._occluded or (self.dropout > 0 and self.rng.random() < self.dropout)
        bodies: list[RigidBodyPose] = []
        if occluded and self.dropout_mode == "invalid":
            bodies.append(
                RigidBodyPose(self.rigid_body_id, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), 0.0, False)
            )
        elif not occluded:
            try:
                p, R = self.sampler.sample()
            except Exception:
                self.truth_errors += 1
                log.exception("sim natnet: truth callable failed")
                p, R = None, None
            if p is not None and R is not None:
                q = quaternion_from_rotation(R)
                bodies.append(
                    RigidBodyPose(
                        self.rigid_body_id,
                        (float(p[0]), float(p[1]), float(p[2])),
                        (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                        0.0002,
                        True,
                    )
                )
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
        ticks = int(now * SIM_CLOCK_HZ)
        return FrameOfData(
            frame_number=self.frame_number,
            rigid_bodies=tuple(bodies),
            timestamp_s=now - self._t0,
            stamp_mid_exposure=ticks,
            stamp_data_received=ticks,
            stamp_transmit=ticks,
            marker_sets=markers,
            labeled_markers=labeled,
        )

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


class SimLineStreamServer(_ServerThread):
    """Sends the line stream (see :mod:`cdcr_ctl.sensors.tracker`) on loopback.

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


def true_transform(
    tracker: TrackerConfig, offset: RigidTransformConfig | None = None
) -> TrackerTransform:
    """The world's tracker alignment: the controller's ``base_from_tracker`` followed by
    ``offset`` (a rigid error applied in the base frame: ``p_true = R_o p_cfg + t_o``)."""
    cfg = TrackerTransform.from_config(tracker)
    if offset is None:
        return cfg
    R_o = rotation_from_rotvec(offset.rotvec_rad)
    t_o = np.asarray(offset.translation_mm, dtype=float)
    return TrackerTransform(
        R_o @ cfg.R_base_tracker,
        R_o @ cfg.t_base_tracker_mm + t_o,
        cfg.R_body_tip,
        cfg.t_body_tip_mm,
        cfg.mm_per_unit,
    )


def sim_tracker_from_config(
    truth: Truth, tracker: TrackerConfig, sim: SimConfig
) -> SimNatNetServer | SimLineStreamServer:
    """The simulated tracker the controller's ``tracker`` section expects, with the simulator's
    rate, latency, dropout (``sim.tracker``), noise (``sim.noise.tracker_mm``), frame offset
    (``sim.effects.tracker_offset``) and seed. ``truth`` returns the tip pose in the base frame.

    NatNet: serves on ``tracker.host``:``tracker.command_port``; UDP stream: sends to
    ``tracker.host``:``tracker.port``; TCP stream: listens there. Not started.
    """
    transform = true_transform(tracker, sim.effects.tracker_offset)
    common: dict[str, Any] = {
        "transform": transform,
        "truth_frame": "base",
        "rate_hz": sim.tracker.rate_hz,
        "latency_s": sim.tracker.latency_s,
        "noise_mm": sim.noise.tracker_mm,
        "dropout": sim.tracker.dropout,
        "seed": sim.seed,
    }
    if tracker.kind == "natnet":
        return SimNatNetServer(
            truth,
            host=tracker.host,
            command_port=tracker.command_port,
            rigid_body_id=tracker.rigid_body_id,
            **common,
        )
    if tracker.kind == "udp_stream":
        return SimLineStreamServer(
            truth,
            transport="udp",
            target=(require_loopback(tracker.host), tracker.port),
            with_orientation=True,
            **common,
        )
    return SimLineStreamServer(
        truth,
        transport="tcp",
        host=tracker.host,
        port=tracker.port,
        with_orientation=True,
        **common,
    )


def main(argv: list[str] | None = None) -> int:
    """``python -m cdcr_ctl.sim.tracker``: serve a tip moving on a circle (base frame, mm).

    Prints ``command_port data_port`` on one line once serving, then runs until interrupted.
    """
    ap = argparse.ArgumentParser(prog="python -m cdcr_ctl.sim.tracker", description=main.__doc__)
    ap.add_argument("--command-port", type=int, default=0)
    ap.add_argument("--data-port", type=int, default=0)
    ap.add_argument("--rate-hz", type=float, default=120.0)
    ap.add_argument("--latency-s", type=float, default=0.0)
    ap.add_argument("--noise-mm", type=float, default=0.0)
    ap.add_argument("--dropout", type=float, default=0.0)
    ap.add_argument("--radius-mm", type=float, default=20.0)
    ap.add_argument("--duration-s", type=float, default=math.inf)
    args = ap.parse_args(argv)
    t0 = time.monotonic()

    def truth() -> np.ndarray:
        t = time.monotonic() - t0
        return np.array([args.radius_mm * math.cos(t), args.radius_mm * math.sin(t), 150.0])

    server = SimNatNetServer(
        truth,
        command_port=args.command_port,
        data_port=args.data_port,
        rate_hz=args.rate_hz,
        latency_s=args.latency_s,
        noise_mm=args.noise_mm,
        dropout=args.dropout,
    )
    with server:
        print(server.command_address[1], server.data_address[1], flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            threading.Event().wait(args.duration_s if math.isfinite(args.duration_s) else None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
