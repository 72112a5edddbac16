"""Open the CAN bus a rig config names, with python-can (the transport is chosen here only).

``virtual`` (one process: tests, the in-process simulator), ``slcan`` (USB-CAN adapters speaking
the Lawicel ASCII protocol, and the simulated rig's pseudo-terminal; python-can sends the bit rate
as ``S0``-``S8``; frames go through :class:`~cdcr_ctl.drives.slcan.SlcanBus`, a line at a time),
``socketcan`` (``can0`` on a Linux rig PC; the interface must be up with the
right bit rate, e.g. ``ip link set can0 up type can bitrate 1000000`` or systemd-networkd), and
any other interface python-can knows (``pcan``, ``kvaser``, ``udp_multicast`` inside a
loopback-only network namespace, ...), which get ``bitrate`` as a keyword.
"""

from __future__ import annotations

import socket

import can

from cdcr_ctl import seriallink
from cdcr_ctl.config.drives import CanBusConfig
from cdcr_ctl.drives.slcan import SlcanBus
from cdcr_ctl.errors import CommError

#: Pause after opening an slcan serial port before the first command (s). Adapters that reset
#: on open (Arduino-style CDC) may need more; python-can's default is 2 s. A ``socket://`` link
#: (an adapter served over TCP) has no port that resets on open: no pause.
SLCAN_SLEEP_AFTER_OPEN_S = 0.2


def bus_kwargs(cfg: CanBusConfig) -> dict[str, object]:
    """The keyword arguments :func:`open_bus` gives ``can.Bus`` for ``cfg`` (pure)."""
    kwargs: dict[str, object] = {"interface": cfg.interface, "channel": cfg.channel}
    if cfg.interface == "slcan":
        kwargs["bitrate"] = cfg.bitrate
        tcp = cfg.channel.startswith("socket://")
        kwargs["sleep_after_open"] = 0.0 if tcp else SLCAN_SLEEP_AFTER_OPEN_S
    elif cfg.interface == "virtual":
        kwargs["receive_own_messages"] = False
    elif cfg.interface == "socketcan":
        pass  # the bit rate belongs to the network interface (ip link), not to the socket
    else:
        kwargs["bitrate"] = cfg.bitrate
    return kwargs


def open_bus(cfg: CanBusConfig) -> can.BusABC:
    """A python-can bus for ``cfg``; :class:`CommError` naming interface and channel on failure."""
    kwargs = bus_kwargs(cfg)
    try:
        if cfg.interface == "slcan":
            # python-can's slcan set-up, with a frame path that keeps up with a 1 kHz cycle.
            del kwargs["interface"]
            seriallink.register()
            return SlcanBus(**kwargs)
        return can.Bus(**kwargs)
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise CommError(f"CAN {cfg.interface}:{cfg.channel}: cannot open ({exc})") from exc


def socketcan_available(channel: str = "can0") -> tuple[bool, str]:
    """Whether this kernel offers SocketCAN and ``channel`` exists (reason text when not)."""
    if not hasattr(socket, "AF_CAN"):
        return False, "this Python has no AF_CAN"
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as exc:
        return False, f"the kernel has no SocketCAN ({exc.strerror})"
    try:
        s.bind((channel,))
    except OSError as exc:
        return False, f"no CAN interface {channel!r} ({exc.strerror})"
    finally:
        s.close()
    return True, ""
