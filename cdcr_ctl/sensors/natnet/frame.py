"""NatNet frame-of-data packets (pure bytes): parse and pack, versions 3.0 to 4.1.

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
import struct

from cdcr_ctl.sensors.natnet.messages import (
    _ASSET_MARKER,
    _I16,
    _I32,
    _LABELED_MARKER,
    _RIGID_BODY,
    _SUFFIX_3,
    _SUFFIX_4,
    _U32,
    _VEC3,
    DEFAULT_VERSION,
    MIN_VERSION,
    FrameOfData,
    LabeledMarker,
    MarkerSet,
    MessageId,
    NatNetDecodeError,
    NatNetVersion,
    RigidBodyPose,
    pack_message,
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
    """Bounds-checked little-endian reader over one payload (the common reads written out on
    locals: this runs for every field of every frame)."""

    __slots__ = ("data", "end", "pos")

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0
        self.end = len(data)

    def left(self) -> int:
        return self.end - self.pos

    def take(self, st: struct.Struct) -> tuple:
        pos, size = self.pos, st.size
        if self.end - pos < size:
            raise NatNetDecodeError(f"frame cut short: need {size} bytes", pos)
        self.pos = pos + size
        return st.unpack_from(self.data, pos)

    def i32(self) -> int:
        pos = self.pos
        if self.end - pos < 4:
            raise NatNetDecodeError("frame cut short: need 4 bytes", pos)
        self.pos = pos + 4
        return _I32.unpack_from(self.data, pos)[0]

    def skip(self, n: int) -> None:
        if n < 0 or self.end - self.pos < n:
            raise NatNetDecodeError(f"frame cut short: need {n} bytes", self.pos)
        self.pos += n

    def count(self, what: str, min_item_bytes: int, sized: bool) -> int:
        """A list count (and the 4.1 byte size after it), checked against the bytes left."""
        n = self.i32()
        if n < 0:
            raise NatNetDecodeError(f"negative {what} count {n}", self.pos - 4)
        if sized:
            nbytes = self.take(_U32)[0]
            if nbytes > self.end - self.pos:
                raise NatNetDecodeError(f"{what} list size {nbytes} exceeds the frame", self.pos)
        if n * min_item_bytes > self.end - self.pos:
            raise NatNetDecodeError(
                f"{n} {what} cannot fit in {self.end - self.pos} bytes", self.pos
            )
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
