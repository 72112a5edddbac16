"""OptiTrack NatNet stream protocol: messages, server info and frame-of-data packets (pure bytes).

Nothing here opens a socket: these functions turn bytes into dataclasses and back, so the
client (:mod:`cdcr_ctl.sensors.tracker`) and the simulated server (``cdcr_ctl.sim.tracker``) share
one definition of the format, and tests check it byte by byte.

Implemented: the binary NatNet stream **versions 3.0, 3.1, 4.0 and 4.1** (Motive 2.x-3.1), as
OptiTrack's NatNet SDK 4.1 sample clients (``PacketClient.cpp``, ``NatNetClient.py``) read it.
A server reporting a later 4.x version is read with the 4.1 layout; 2.x and earlier are rejected.
Everything is little endian; ``i32``/``u32``/``i16``/``u16``/``f32``/``f64``/``u64`` below.

Message (one UDP datagram)::

    u16 message id, u16 payload size (bytes), payload

``NAT_CONNECT`` (0), client -> server command port: in the SDK's layout, ``"Ping"`` NUL-padded to
264 bytes, a 0 byte, the requested NatNet version (4 x u8), a 0 byte, plus the trailing NUL the SDK
appends (271 bytes). Servers answer any payload with ``NAT_SERVERINFO``.

``NAT_SERVERINFO`` (1)::

    char application name[256] (NUL-terminated), u8 application version[4],
    u8 NatNet version[4]; NatNet >= 3.0 servers add: u64 high-resolution clock (ticks/s),
    u16 data port, u8 is-multicast, u8 multicast group address[4]

``NAT_KEEPALIVE`` (10): empty payload; a unicast client sends it so the server keeps streaming.

``NAT_FRAMEOFDATA`` (7); ``[n]`` marks the u32 byte size that NatNet >= 4.1 puts after each list
count (read, range-checked, not otherwise trusted)::

    i32 frame number
    marker sets:   i32 count [n]; each: name (NUL-terminated), i32 m, m x f32[3]
    other markers: i32 count [n]; each: f32[3]
    rigid bodies:  i32 count [n]; each: i32 id, f32[3] position (tracker units; Motive: m),
                   f32[4] orientation quaternion qx qy qz qw (body frame -> tracker frame),
                   f32 mean marker error, i16 params (bit 0: tracking valid)
    skeletons:     i32 count [n]; each: i32 id, i32 m, m x rigid body (as above)
    assets (>= 4.1 only): i32 count [n]; each: i32 id, i32 m, m x (i32 id, f32[3], f32[4],
                   f32 error, i16 params), i32 k, k x (i32 id, f32[3], f32 size, i16 params,
                   f32 residual)
    labeled markers: i32 count [n]; each: i32 id, f32[3], f32 size, i16 params, f32 residual
    force plates:  i32 count [n]; each: i32 id, i32 channels, per channel: i32 m, m x f32
    devices:       same layout as force plates
    suffix:        u32 timecode, u32 timecode sub, f64 timestamp (s since the server started),
                   u64 camera mid-exposure, u64 data received, u64 transmit stamps (ticks of the
                   high-resolution clock); NatNet >= 4.0: i32 precision timestamp (s),
                   u32 its fraction; then i16 params (bit 0 recording, bit 1 models changed)
    i32 end-of-data tag (0): optional when reading

NatNet has no checksum (UDP's covers the datagram). The decoder is strict instead: the header's
size must match the datagram, every count must fit the bytes left, and at most the 4-byte
end-of-data tag may follow the suffix. Anything else raises :class:`NatNetDecodeError`.
"""

from __future__ import annotations

import math
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
        if not clock_hz or self.stamp_transmit < self.stamp_mid_exposure:
            return None
        if self.stamp_mid_exposure == 0:
            return None
        return (self.stamp_transmit - self.stamp_mid_exposure) / clock_hz


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


# -- frame of data --------------------------------------------------------------------------


def _has_sizes(version: NatNetVersion) -> bool:
    return (version.major, version.minor) >= (4, 1)


def check_version(version: NatNetVersion) -> None:
    """ValueError unless this module reads ``version`` (3.0 or later)."""
    if (version.major, version.minor) < (MIN_VERSION.major, MIN_VERSION.minor):
        raise ValueError(
            f"NatNet {version.major}.{version.minor} is not supported (needs 3.0 or later: "
            "set the streaming version in Motive)"
        )


class _Reader:
    """Bounds-checked little-endian reader over one payload."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def left(self) -> int:
        return len(self.data) - self.pos

    def take(self, st: struct.Struct) -> tuple:
        if self.left() < st.size:
            raise NatNetDecodeError(f"frame cut short: need {st.size} bytes", self.pos)
        out = st.unpack_from(self.data, self.pos)
        self.pos += st.size
        return out

    def i32(self) -> int:
        return self.take(_I32)[0]

    def skip(self, n: int) -> None:
        if n < 0 or self.left() < n:
            raise NatNetDecodeError(f"frame cut short: need {n} bytes", self.pos)
        self.pos += n

    def count(self, what: str, min_item_bytes: int, sized: bool) -> int:
        """A list count (and the 4.1 byte size after it), checked against the bytes left."""
        n = self.i32()
        if n < 0:
            raise NatNetDecodeError(f"negative {what} count {n}", self.pos - 4)
        if sized:
            nbytes = self.take(_U32)[0]
            if nbytes > self.left():
                raise NatNetDecodeError(f"{what} list size {nbytes} exceeds the frame", self.pos)
        if n * min_item_bytes > self.left():
            raise NatNetDecodeError(f"{n} {what} cannot fit in {self.left()} bytes", self.pos)
        return n

    def cstring(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise NatNetDecodeError("unterminated name", self.pos)
        text = self.data[self.pos : end].decode("utf-8", errors="replace")
        self.pos = end + 1
        return text


def _vec3(v: tuple) -> tuple[float, float, float]:
    return (v[0], v[1], v[2])


def _read_rigid_body(r: _Reader) -> RigidBodyPose:
    rid, x, y, z, qx, qy, qz, qw, err, params = r.take(_RIGID_BODY)
    return RigidBodyPose(rid, (x, y, z), (qx, qy, qz, qw), err, bool(params & 0x01))


def _skip_channels(r: _Reader, what: str) -> None:
    channels = r.count(f"{what} channels", 4, False)
    for _ in range(channels):
        frames = r.count(f"{what} channel frames", 4, False)
        r.skip(4 * frames)


def parse_frame_of_data(payload: bytes, version: NatNetVersion) -> FrameOfData:
    """Decode a NAT_FRAMEOFDATA payload (without the header) sent in stream ``version``.

    Rigid bodies, marker sets, labeled markers and the suffix are returned; skeletons, assets,
    force plates and devices are checked and counted in ``skipped``. Raises
    :class:`NatNetDecodeError` on any inconsistency (see the module docstring).
    """
    try:
        check_version(version)
    except ValueError as exc:
        raise NatNetDecodeError(str(exc)) from None
    sized = _has_sizes(version)
    r = _Reader(bytes(payload))
    frame_number = r.i32()

    marker_sets = []
    for _ in range(r.count("marker sets", 5, sized)):
        name = r.cstring()
        n = r.count("markers", 12, False)
        positions = tuple(_vec3(r.take(_VEC3)) for _ in range(n))
        marker_sets.append(MarkerSet(name, positions))

    r.skip(12 * r.count("other markers", 12, sized))

    bodies = tuple(
        _read_rigid_body(r) for _ in range(r.count("rigid bodies", _RIGID_BODY.size, sized))
    )

    skipped = {"skeletons": r.count("skeletons", 8, sized)}
    for _ in range(skipped["skeletons"]):
        r.skip(4)
        r.skip(_RIGID_BODY.size * r.count("skeleton bodies", _RIGID_BODY.size, False))

    if sized:
        skipped["assets"] = r.count("assets", 12, True)
        for _ in range(skipped["assets"]):
            r.skip(4)
            r.skip(_RIGID_BODY.size * r.count("asset bodies", _RIGID_BODY.size, False))
            r.skip(_ASSET_MARKER.size * r.count("asset markers", _ASSET_MARKER.size, False))

    labeled = []
    for _ in range(r.count("labeled markers", _LABELED_MARKER.size, sized)):
        mid, x, y, z, size, params, residual = r.take(_LABELED_MARKER)
        labeled.append(LabeledMarker(mid, (x, y, z), size, params & 0xFFFF, residual))

    skipped["force_plates"] = r.count("force plates", 8, sized)
    for _ in range(skipped["force_plates"]):
        r.skip(4)
        _skip_channels(r, "force plate")
    skipped["devices"] = r.count("devices", 8, sized)
    for _ in range(skipped["devices"]):
        r.skip(4)
        _skip_channels(r, "device")

    suffix = _SUFFIX_4 if version.major >= 4 else _SUFFIX_3
    timecode, timecode_sub, timestamp, mid, received, transmit = r.take(suffix)[:6]
    params = r.take(_I16)[0]
    trailing = r.left()
    if trailing not in (0, 4):
        raise NatNetDecodeError(f"{trailing} unexpected bytes after the frame suffix", r.pos)
    if not math.isfinite(timestamp):
        raise NatNetDecodeError("non-finite frame timestamp", r.pos)
    return FrameOfData(
        frame_number=frame_number,
        rigid_bodies=bodies,
        timestamp_s=timestamp,
        stamp_mid_exposure=mid,
        stamp_data_received=received,
        stamp_transmit=transmit,
        params=params & 0xFFFF,
        marker_sets=tuple(marker_sets),
        labeled_markers=tuple(labeled),
        timecode=timecode,
        timecode_sub=timecode_sub,
        skipped=skipped,
    )


def _list(count: int, body: bytes, sized: bool) -> bytes:
    head = _I32.pack(count)
    if sized:
        head += _U32.pack(len(body))
    return head + body


def pack_frame_of_data(frame: FrameOfData, version: NatNetVersion = DEFAULT_VERSION) -> bytes:
    """The whole NAT_FRAMEOFDATA datagram (header included) for ``frame`` in stream ``version``.

    Writes marker sets, rigid bodies, labeled markers and the suffix; skeletons, assets, force
    plates and devices as empty lists; and the 4-byte end-of-data tag. ValueError for versions
    before 3.0 or a frame over 65535 bytes.
    """
    check_version(version)
    sized = _has_sizes(version)
    out = [_I32.pack(frame.frame_number)]
    sets = b"".join(
        m.name.encode("utf-8")
        + b"\0"
        + _I32.pack(len(m.positions))
        + b"".join(_VEC3.pack(*p) for p in m.positions)
        for m in frame.marker_sets
    )
    out.append(_list(len(frame.marker_sets), sets, sized))
    out.append(_list(0, b"", sized))  # other markers
    bodies = b"".join(
        _RIGID_BODY.pack(
            b.id, *b.position, *b.orientation_xyzw, b.mean_error, 1 if b.tracking_valid else 0
        )
        for b in frame.rigid_bodies
    )
    out.append(_list(len(frame.rigid_bodies), bodies, sized))
    out.append(_list(0, b"", sized))  # skeletons
    if sized:
        out.append(_list(0, b"", sized))  # assets
    labeled = b"".join(
        _LABELED_MARKER.pack(m.id, *m.position, m.size, _signed16(m.params), m.residual)
        for m in frame.labeled_markers
    )
    out.append(_list(len(frame.labeled_markers), labeled, sized))
    out.append(_list(0, b"", sized))  # force plates
    out.append(_list(0, b"", sized))  # devices
    stamps = (
        frame.timecode,
        frame.timecode_sub,
        frame.timestamp_s,
        frame.stamp_mid_exposure,
        frame.stamp_data_received,
        frame.stamp_transmit,
    )
    if version.major >= 4:
        out.append(_SUFFIX_4.pack(*stamps, *_precision_timestamp(frame.timestamp_s)))
    else:
        out.append(_SUFFIX_3.pack(*stamps))
    out.append(_I16.pack(_signed16(frame.params)))
    out.append(_I32.pack(0))  # end-of-data tag
    return pack_message(MessageId.NAT_FRAMEOFDATA, b"".join(out))


def _precision_timestamp(t_s: float) -> tuple[int, int]:
    """NatNet 4's precision timestamp: whole seconds (i32) and fraction (u32, 1/2**32 s)."""
    if not (math.isfinite(t_s) and 0 <= t_s < 2**31):
        return 0, 0
    seconds = math.floor(t_s)
    return seconds, min(int((t_s - seconds) * 2**32), 0xFFFFFFFF)


def _signed16(value: int) -> int:
    value &= 0xFFFF
    return value - 0x10000 if value >= 0x8000 else value
