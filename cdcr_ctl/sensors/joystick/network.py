"""Network joystick: ``struct input_event`` records of a remote device read from a TCP socket.

netevent-style tools and ``socat -u /dev/input/eventN TCP-LISTEN:PORT`` forward input devices
this way; the records are decoded by :mod:`cdcr_ctl.sensors.joystick.input_event`.
"""

from __future__ import annotations

import select
import socket
import time
from collections.abc import Iterator

from cdcr_ctl.config.tracking import JoystickConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.joystick.codes import Event
from cdcr_ctl.sensors.joystick.input_event import INPUT_EVENT_SIZE, InputEventParser
from cdcr_ctl.sensors.joystick.reader import Joystick, _config_ranges
from cdcr_ctl.sensors.sample import Clock

#: How long the TCP source waits for bytes before yielding an idle tick (s).
TCP_POLL_S = 0.02
#: TCP keep-alive of the network joystick: probes after this much silence (s), this often (s),
#: this many unanswered probes = the sender is gone. A joystick held still sends nothing, so
#: silence alone never means a disconnect; the kernel's probes tell a dead peer (cable pulled,
#: host down) from a quiet one within ~idle + interval * count seconds.
TCP_KEEPIDLE_S = 1
TCP_KEEPINTVL_S = 1
TCP_KEEPCNT = 3


def _tcp_events(
    sock: socket.socket, name: str, poll_s: float = TCP_POLL_S
) -> Iterator[Event | None]:
    """Event source over a connected socket: records -> events, ``None`` while idle.

    The peer closing the connection, a reset, keep-alive failure or a bad record raise
    :class:`SensorError` (the device is gone: a network joystick does not end normally).
    """
    parser = InputEventParser(name)
    while True:
        try:
            ready, _, _ = select.select([sock], [], [], poll_s)
            if not ready:
                yield None
                continue
            data = sock.recv(INPUT_EVENT_SIZE * 256)
        except (OSError, ValueError) as exc:  # ValueError: select on a closed socket
            raise SensorError(name, f"joystick disconnected: {exc}") from exc
        if not data:
            parser.eof()
            raise SensorError(
                name,
                f"joystick disconnected: the sender closed the connection at byte {parser.offset}",
            )
        for ev in parser.feed(data):
            yield ev.event
        parser.check()


def _keepalive(sock: socket.socket) -> None:
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for opt, value in (
        ("TCP_KEEPIDLE", TCP_KEEPIDLE_S),
        ("TCP_KEEPINTVL", TCP_KEEPINTVL_S),
        ("TCP_KEEPCNT", TCP_KEEPCNT),
    ):
        if hasattr(socket, opt):  # Linux
            sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, opt), value)


def open_tcp_joystick(
    cfg: JoystickConfig,
    *,
    clock: Clock = time.monotonic,
    start: bool = True,
    sock: socket.socket | None = None,
) -> Joystick:
    """Connect to the network joystick ``cfg.device`` (``tcp://HOST:PORT``) and start a reader.

    The sender streams ``struct input_event`` records (:data:`INPUT_EVENT`) of its device. There
    is no absinfo over the wire: the steering axes' raw range is ``cfg.axis_range`` (default
    signed 16 bit, :data:`DEFAULT_RANGE`) and the axes read 0 until their first event. ``sock``:
    an already connected socket (tests); else one is connected within ``cfg.connect_timeout_s``.
    Raises :class:`SensorError` naming the address when nobody answers there.
    """
    address = cfg.tcp_address
    if address is None:
        raise ValueError(f"not a network joystick: {cfg.device!r}")
    name = str(cfg.device)
    if sock is None:
        try:
            sock = socket.create_connection(address, timeout=cfg.connect_timeout_s)
        except OSError as exc:
            raise SensorError(name, f"cannot connect to the network joystick: {exc}") from exc
    try:
        sock.settimeout(None)
        sock.setblocking(True)
        _keepalive(sock)
        stick = Joystick(
            _tcp_events(sock, name),
            name=name,
            axis_x=cfg.axis_x,
            axis_y=cfg.axis_y,
            axis_ranges=_config_ranges(cfg),
            deadband=cfg.deadband,
            invert_x=cfg.invert_x,
            invert_y=cfg.invert_y,
            closer=sock.close,
            clock=clock,
        )
    except BaseException:
        sock.close()
        raise
    return stick.start() if start else stick
