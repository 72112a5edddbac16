"""Tracker readers from config: sockets made and bound, :func:`open_tracker` picks the reader."""

from __future__ import annotations

import ipaddress
import socket
import time

from cdcr_ctl.config.tracking import TrackerConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.sample import Clock
from cdcr_ctl.sensors.tracker.frames import TrackerTransform
from cdcr_ctl.sensors.tracker.natnet_client import NatNetTracker
from cdcr_ctl.sensors.tracker.stream_client import LineStreamTracker

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
