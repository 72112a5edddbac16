"""Open the CAN bus a rig config names, with python-can (the transport is chosen here only).

``virtual`` (one process: tests, the in-process simulator), ``slcan`` (USB-CAN adapters speaking
the Lawicel ASCII protocol, and the simulated rig's pseudo-terminal), ``socketcan`` (``can0`` on a
Linux rig PC; the interface must be up with the right bit rate, e.g. by systemd-networkd), and any
other interface python-can knows (``pcan``, ``kvaser``, ``udp_multicast`` inside a
loopback-only network namespace, ...).
"""

from __future__ import annotations

import can

from cdcr_ctl.config.drives import CanBusConfig
from cdcr_ctl.errors import CommError


def open_bus(cfg: CanBusConfig) -> can.BusABC:
    """A python-can bus for ``cfg``; :class:`CommError` naming interface and channel on failure."""
    kwargs: dict[str, object] = {}
    if cfg.interface == "slcan":
        kwargs["bitrate"] = cfg.bitrate
        kwargs["sleep_after_open"] = 0.2
    elif cfg.interface == "virtual":
        kwargs["receive_own_messages"] = False
    elif cfg.interface == "socketcan":
        pass  # bit rate is set when the interface is brought up (ip link set can0 type can ...)
    else:
        kwargs["bitrate"] = cfg.bitrate
    try:
        return can.Bus(interface=cfg.interface, channel=cfg.channel, **kwargs)
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise CommError(f"CAN {cfg.interface}:{cfg.channel}: cannot open ({exc})") from exc


def socketcan_available(channel: str = "can0") -> tuple[bool, str]:
    """Whether this kernel offers SocketCAN and ``channel`` exists (reason text when not)."""
    import socket

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
