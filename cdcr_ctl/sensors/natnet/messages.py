"""NatNet messages (pure bytes): header, ids, versions, the packet dataclasses, server info.

Everything is little endian.

Message (one UDP datagram)::

    u16 message id, u16 payload size (bytes), payload

``NAT_CONNECT`` (0), client -> server command port: in the SDK's layout, ``"Ping"`` NUL-padded to
264 bytes, a 0 byte, the requested NatNet version (4 x u8), a 0 byte, plus the trailing NUL the SDK
appends (271 bytes). Servers answer any payload with ``NAT_SERVERINFO``.

``NAT_SERVERINFO`` (1)::

    char application name[256] (NUL-terminated), u8 application version[4],
    u8 NatNet version[4]; NatNet >= 3.0 servers add: u64 high-resolution clock (ticks/s),
    u16 data port, u8 is-multicast, u8 multicast group address[4]
"""

from __future__ import annotations

import socket
import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple


class MessageId(IntEnum):
    """NatNet message ids (u16 at the start of every datagram)."""

    NAT_CONNECT = 0
    NAT_SERVERINFO = 1
    NAT_REQUEST = 2
    NAT_RESPONSE = 3
    NAT_REQUEST_MODELDEF = 4
    NAT_MODELDEF = 5
    NAT_REQUEST_FRAMEOFDATA = 6
    NAT_FRAMEOFDATA = 7
    NAT_MESSAGESTRING = 8
    NAT_DISCONNECT = 9
    NAT_KEEPALIVE = 10
    NAT_UNRECOGNIZED_REQUEST = 100


class NatNetVersion(NamedTuple):
    """A NatNet stream version; compares as a tuple."""

    major: int
    minor: int
    build: int = 0
    revision: int = 0

    def __str__(self) -> str:
        return f"{self.major}.{self.minor}.{self.build}.{self.revision}"


#: Oldest stream version this module reads.
MIN_VERSION = NatNetVersion(3, 0)
#: The version this module writes by default and asks for in NAT_CONNECT.
DEFAULT_VERSION = NatNetVersion(4, 1)

#: Largest payload a NatNet header can announce (its size field is a u16).
MAX_PAYLOAD_BYTES = 0xFFFF

#: Length of the fixed, NUL-padded application-name field of NAT_SERVERINFO.
SERVER_NAME_BYTES = 256

HEADER = struct.Struct("<HH")
_I32 = struct.Struct("<i")
_U32 = struct.Struct("<I")
_I16 = struct.Struct("<h")
_F32 = struct.Struct("<f")
_VEC3 = struct.Struct("<fff")
_RIGID_BODY = struct.Struct("<i8fh")  # id, x y z, qx qy qz qw, error, params (38 bytes)
_ASSET_MARKER = struct.Struct("<i4fhf")  # id, x y z, size, params, residual (26 bytes)
_LABELED_MARKER = struct.Struct("<i4fhf")
_SUFFIX_3 = struct.Struct("<IIdQQQ")
_SUFFIX_4 = struct.Struct("<IIdQQQiI")
_SERVER_INFO_EXT = struct.Struct("<QHB4s")


class NatNetDecodeError(ValueError):
    """A datagram is not a well-formed NatNet message; ``offset`` is where reading stopped."""

    def __init__(self, message: str, offset: int = 0) -> None:
        self.offset = offset
        super().__init__(f"{message} (at byte {offset})")


@dataclass(frozen=True, slots=True)
class ServerInfo:
    """A server's answer to NAT_CONNECT.

    ``clock_hz``: ticks per second of the server's high-resolution clock (the unit of the frame
    suffix stamps); ``data_port``/``multicast``/``multicast_group``: where it streams. The last
    four are None when the server did not send them (NatNet < 3.0 layout).
    """

    application: str
    application_version: tuple[int, int, int, int]
    natnet_version: NatNetVersion
    clock_hz: int | None = None
    data_port: int | None = None
    multicast: bool | None = None
    multicast_group: str | None = None


@dataclass(frozen=True, slots=True)
class RigidBodyPose:
    """One rigid body in one frame, in the tracker's frame and units.

    ``position``: x, y, z (tracker units; Motive: m). ``orientation_xyzw``: unit quaternion
    (scalar last) rotating body-frame vectors into the tracker frame. ``mean_error``: mean marker
    residual (tracker units). ``tracking_valid``: False when the server lost the body (the pose is
    then the last known one or zeros: do not use it).
    """

    id: int
    position: tuple[float, float, float]
    orientation_xyzw: tuple[float, float, float, float]
    mean_error: float = 0.0
    tracking_valid: bool = True


@dataclass(frozen=True, slots=True)
class MarkerSet:
    """A named set of marker positions (tracker units)."""

    name: str
    positions: tuple[tuple[float, float, float], ...] = ()


@dataclass(frozen=True, slots=True)
class LabeledMarker:
    """A labeled marker: ``id`` (model id << 16 | marker id), position, size, params, residual."""

    id: int
    position: tuple[float, float, float]
    size: float = 0.0
    params: int = 0
    residual: float = 0.0


@dataclass(frozen=True, slots=True)
class FrameOfData:
    """The parts of a NAT_FRAMEOFDATA this controller uses (everything else is checked, skipped).

    ``timestamp_s``: server time of the frame (s since the server started). ``stamp_*``: the
    server's high-resolution clock (ticks; see :attr:`ServerInfo.clock_hz`) at camera
    mid-exposure, at data reception and at transmission: ``(transmit - mid_exposure) / clock_hz``
    is the server's own latency. ``params``: suffix flags (bit 0 recording, bit 1 models changed).
    """

    frame_number: int
    rigid_bodies: tuple[RigidBodyPose, ...] = ()
    timestamp_s: float = 0.0
    stamp_mid_exposure: int = 0
    stamp_data_received: int = 0
    stamp_transmit: int = 0
    params: int = 0
    marker_sets: tuple[MarkerSet, ...] = ()
    labeled_markers: tuple[LabeledMarker, ...] = ()
    timecode: int = 0
    timecode_sub: int = 0
    skipped: dict[str, int] = field(default_factory=dict, compare=False)

    def rigid_body(self, body_id: int) -> RigidBodyPose | None:
        """The rigid body with ``body_id``, or None when the frame does not contain it."""
        for body in self.rigid_bodies:
            if body.id == body_id:
                return body
        return None

    def server_latency_s(self, clock_hz: int | None) -> float | None:
        """Seconds from camera mid-exposure to transmission by the server, or None if unknown."""
        return server_latency_s(self.stamp_mid_exposure, self.stamp_transmit, clock_hz)


def server_latency_s(mid_exposure: int, transmit: int, clock_hz: int | None) -> float | None:
    """Seconds from the camera mid-exposure stamp to the transmit stamp (ticks of a ``clock_hz``
    clock), or None when unknown (no clock rate, no mid-exposure stamp, stamps out of order)."""
    if not clock_hz or transmit < mid_exposure or mid_exposure == 0:
        return None
    return (transmit - mid_exposure) / clock_hz


# -- messages -------------------------------------------------------------------------------


def pack_message(message_id: int, payload: bytes = b"") -> bytes:
    """Header (u16 id, u16 size) + ``payload``; ValueError when the payload is over 65535 bytes."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ValueError(f"NatNet payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    return HEADER.pack(int(message_id), len(payload)) + payload


def split_message(datagram: bytes) -> tuple[int, bytes]:
    """(message id, payload) of one datagram; checks that the header's size matches."""
    if len(datagram) < HEADER.size:
        raise NatNetDecodeError(f"datagram of {len(datagram)} bytes has no NatNet header")
    message_id, size = HEADER.unpack_from(datagram)
    if size != len(datagram) - HEADER.size:
        raise NatNetDecodeError(
            f"header announces {size} payload bytes, datagram carries {len(datagram) - 4}", 2
        )
    return message_id, bytes(datagram[HEADER.size :])


def pack_connect(version: NatNetVersion = DEFAULT_VERSION) -> bytes:
    """NAT_CONNECT in the NatNet SDK's layout, asking for stream ``version``."""
    body = bytearray(270)
    body[0:4] = b"Ping"
    body[265:269] = bytes(version)
    return pack_message(MessageId.NAT_CONNECT, bytes(body) + b"\0")


def pack_keepalive() -> bytes:
    """NAT_KEEPALIVE (empty payload)."""
    return pack_message(MessageId.NAT_KEEPALIVE)


def pack_server_info(info: ServerInfo) -> bytes:
    """NAT_SERVERINFO for ``info``; the NatNet >= 3.0 tail is written when ``clock_hz`` is set."""
    name = info.application.encode("utf-8")[: SERVER_NAME_BYTES - 1]
    payload = name.ljust(SERVER_NAME_BYTES, b"\0")
    payload += bytes(info.application_version) + bytes(info.natnet_version)
    if info.clock_hz is not None:
        group = socket.inet_aton(info.multicast_group or "0.0.0.0")
        payload += _SERVER_INFO_EXT.pack(
            info.clock_hz, info.data_port or 0, int(bool(info.multicast)), group
        )
    return pack_message(MessageId.NAT_SERVERINFO, payload)


def parse_server_info(payload: bytes) -> ServerInfo:
    """Decode a NAT_SERVERINFO payload (without the 4-byte header)."""
    need = SERVER_NAME_BYTES + 8
    if len(payload) < need:
        raise NatNetDecodeError(f"server info needs {need} bytes, got {len(payload)}")
    name = payload[:SERVER_NAME_BYTES].split(b"\0", 1)[0].decode("utf-8", errors="replace")
    a0, a1, a2, a3 = payload[SERVER_NAME_BYTES : SERVER_NAME_BYTES + 4]
    nn = NatNetVersion(*payload[SERVER_NAME_BYTES + 4 : need])
    if len(payload) < need + _SERVER_INFO_EXT.size:
        return ServerInfo(name, (a0, a1, a2, a3), nn)
    clock_hz, data_port, multicast, group = _SERVER_INFO_EXT.unpack_from(payload, need)
    return ServerInfo(
        name, (a0, a1, a2, a3), nn, clock_hz, data_port, bool(multicast), socket.inet_ntoa(group)
    )
