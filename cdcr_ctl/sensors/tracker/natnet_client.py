"""NatNet client for one rigid body on an injected UDP socket (the transport side of NatNet).

The bytes are :mod:`cdcr_ctl.sensors.natnet`'s; this module connects, keeps a unicast stream
alive, drops reordered frames and publishes the body's tip through :class:`TipTracker`.
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import time

from cdcr_ctl.errors import SensorError
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
from cdcr_ctl.sensors.natnet.messages import server_latency_s
from cdcr_ctl.sensors.sample import Clock
from cdcr_ctl.sensors.tracker.frames import TrackerTransform, rotation_from_quaternion
from cdcr_ctl.sensors.tracker.reader import (
    MAX_DATAGRAMS_PER_POLL,
    RECV_BUFFER_BYTES,
    RECV_POLL_S,
    REORDER_WINDOW_FRAMES,
    TipTracker,
)

#: How often a unicast NatNet client tells the server it is still there (s).
KEEPALIVE_PERIOD_S = 0.5
#: How often NAT_CONNECT is re-sent while no server info or no frames arrive (s).
RECONNECT_PERIOD_S = 1.0


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
        body = frame.rigid_body(self.rigid_body_id)
        pose = (
            (body.position, body.orientation_xyzw)
            if body is not None and body.tracking_valid
            else None
        )
        stamps = (frame.timestamp_s, frame.stamp_mid_exposure, frame.stamp_transmit)
        self._accept(frame.frame_number, pose, stamps, t_rx)

    def _accept(
        self,
        frame_number: int,
        pose: tuple[tuple[float, ...], tuple[float, ...]] | None,
        stamps: tuple[float, int, int],
        t_rx: float,
    ) -> None:
        """A decoded frame: ``pose`` = (position in tracker units, quaternion xyzw) of the body
        when the frame has it tracked, else None; ``stamps`` = (server timestamp s,
        mid-exposure ticks, transmit ticks); received at ``t_rx`` (s, reader clock)."""
        last = self._last_frame
        if last is not None and 0 <= last - frame_number < REORDER_WINDOW_FRAMES:
            self.stats.out_of_order += 1
            return
        self._last_frame = frame_number
        self._alive(t_rx)
        if pose is None:
            self._occluded()
            return
        position, orientation = pose
        try:
            R = rotation_from_quaternion(orientation)
        except ValueError:
            self._occluded()
            return
        x, y, z = position
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            self._occluded()
            return
        timestamp_s, mid, transmit = stamps
        info = self.server_info
        latency = server_latency_s(mid, transmit, info.clock_hz if info else None)
        self._publish(
            position,
            R,
            has_rotation=True,
            frame=frame_number,
            tracker_time_s=timestamp_s,
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
