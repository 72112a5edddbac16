"""NatNet protocol: byte layouts derived by hand from the format, round trips in every supported
version, strict rejection of damaged datagrams, and property tests on random bytes."""

from __future__ import annotations

import contextlib
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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
    pack_connect,
    pack_frame_of_data,
    pack_keepalive,
    pack_message,
    pack_server_info,
    parse_frame_of_data,
    parse_server_info,
    split_message,
)

VERSIONS = [NatNetVersion(3, 0), NatNetVersion(3, 1), NatNetVersion(4, 0), NatNetVersion(4, 1)]

BODY = RigidBodyPose(7, (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0), 0.5, True)


def one_body_frame(**kw) -> FrameOfData:
    return FrameOfData(frame_number=1234, rigid_bodies=(BODY,), timestamp_s=2.5, **kw)


# -- layouts derived from the format ---------------------------------------------------------


def test_header_and_keepalive_bytes() -> None:
    assert pack_keepalive() == b"\x0a\x00\x00\x00"
    assert pack_message(MessageId.NAT_REQUEST, b"abc") == b"\x02\x00\x03\x00abc"
    with pytest.raises(ValueError, match="65535"):
        pack_message(7, bytes(65536))


def test_connect_uses_the_sdk_layout() -> None:
    data = pack_connect(NatNetVersion(4, 1, 0, 0))
    assert data[:4] == b"\x00\x00\x0f\x01"  # id 0, 271 payload bytes
    assert len(data) == 4 + 271
    assert data[4:8] == b"Ping"
    assert data[4 + 265 : 4 + 269] == b"\x04\x01\x00\x00"
    assert data[-1] == 0


def test_server_info_layout_and_round_trip() -> None:
    info = ServerInfo(
        "Motive", (3, 1, 2, 0), NatNetVersion(4, 1), 10_000_000, 1511, False, "0.0.0.0"
    )
    data = pack_server_info(info)
    assert data[:2] == b"\x01\x00"
    payload = data[4:]
    assert len(payload) == 256 + 4 + 4 + 8 + 2 + 1 + 4
    assert payload[:7] == b"Motive\x00"
    assert payload[256:264] == bytes([3, 1, 2, 0, 4, 1, 0, 0])
    assert struct.unpack_from("<QH", payload, 264) == (10_000_000, 1511)
    assert parse_server_info(payload) == info
    # An old server sends only the first 264 bytes.
    old = parse_server_info(payload[:264])
    assert old.natnet_version == NatNetVersion(4, 1) and old.clock_hz is None
    with pytest.raises(NatNetDecodeError):
        parse_server_info(payload[:263])


def test_frame_sizes_by_hand() -> None:
    # 3.0: header 4, frame number 4, seven list counts 7 * 4, one rigid body
    # (i32 + 8 * f32 + i16 = 38), suffix (2 * u32 + f64 + 3 * u64 = 40), params 2, end tag 4.
    size_30 = 4 + 4 + 7 * 4 + 38 + 40 + 2 + 4
    assert len(pack_frame_of_data(one_body_frame(), NatNetVersion(3, 0))) == size_30
    # 4.0 adds the precision timestamp (i32 + u32) to the suffix.
    assert len(pack_frame_of_data(one_body_frame(), NatNetVersion(4, 0))) == size_30 + 8
    # 4.1 adds a u32 byte size after every count, and the asset list (count + size).
    assert len(pack_frame_of_data(one_body_frame(), NatNetVersion(4, 1))) == size_30 + 8 + 36


def test_rigid_body_bytes_at_their_offset_in_30() -> None:
    data = pack_frame_of_data(one_body_frame(), NatNetVersion(3, 0))
    assert struct.unpack_from("<HH", data) == (7, len(data) - 4)
    assert struct.unpack_from("<i", data, 4) == (1234,)
    assert struct.unpack_from("<ii", data, 8) == (0, 0)  # no marker sets, no other markers
    assert struct.unpack_from("<i", data, 16) == (1,)  # one rigid body
    body = struct.unpack_from("<i3f4ffh", data, 20)
    assert body == (7, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0, 0.5, 1)


def test_rigid_body_bytes_at_their_offset_in_41() -> None:
    data = pack_frame_of_data(one_body_frame(), NatNetVersion(4, 1))
    # frame number, marker sets (count 0, size 0), other markers (0, 0), rigid bodies (1, 38)
    assert struct.unpack_from("<iIIIIiI", data, 4)[1:] == (0, 0, 0, 0, 1, 38)
    assert struct.unpack_from("<i3f4ffh", data, 32)[0] == 7


def test_parse_frame_written_by_hand() -> None:
    """A 3.1 frame assembled field by field here, independent of the packer."""
    payload = b"".join(
        [
            struct.pack("<i", 99),  # frame number
            struct.pack("<i", 1) + b"all\0" + struct.pack("<i", 1) + struct.pack("<3f", 1, 2, 3),
            struct.pack("<i", 0),  # other markers
            struct.pack("<i", 2),
            struct.pack("<i3f4ffh", 1, 0.25, 0.5, 1.0, 0.0, 0.0, 0.0, 1.0, 0.001, 1),
            struct.pack("<i3f4ffh", 2, 9.0, 9.0, 9.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0),
            struct.pack("<i", 1),  # one skeleton with one body: checked and skipped
            struct.pack("<ii", 5, 1),
            struct.pack("<i3f4ffh", 3, 0, 0, 0, 0, 0, 0, 1, 0, 1),
            struct.pack("<i", 1) + struct.pack("<i4fhf", 65537, 1, 1, 1, 0.01, 4, 0.0),
            struct.pack("<i", 1) + struct.pack("<iii", 1, 1, 2) + struct.pack("<2f", 5, 6),
            struct.pack("<i", 0),  # devices
            struct.pack("<IIdQQQ", 0, 0, 3.25, 100, 200, 300),
            struct.pack("<h", 0),
        ]
    )
    frame = parse_frame_of_data(payload, NatNetVersion(3, 1))
    assert frame.frame_number == 99
    assert frame.rigid_body(1) == RigidBodyPose(
        1, (0.25, 0.5, 1.0), (0, 0, 0, 1.0), frame.rigid_body(1).mean_error, True
    )
    assert frame.rigid_body(2).tracking_valid is False
    assert frame.rigid_body(3) is None  # skeleton bodies are not top-level rigid bodies
    assert frame.marker_sets == (MarkerSet("all", ((1.0, 2.0, 3.0),)),)
    assert frame.labeled_markers[0].id == 65537
    assert frame.skipped == {"skeletons": 1, "force_plates": 1, "devices": 0}
    assert (frame.timestamp_s, frame.stamp_mid_exposure, frame.stamp_transmit) == (3.25, 100, 300)
    assert frame.server_latency_s(100) == 2.0
    # With the end-of-data tag it is just as good; with anything more it is not.
    assert parse_frame_of_data(payload + bytes(4), NatNetVersion(3, 1)) == frame
    with pytest.raises(NatNetDecodeError, match="unexpected bytes"):
        parse_frame_of_data(payload + bytes(5), NatNetVersion(3, 1))


@pytest.mark.parametrize("version", VERSIONS, ids=str)
def test_round_trip_every_version(version: NatNetVersion) -> None:
    frame = FrameOfData(
        frame_number=42,
        rigid_bodies=(BODY, RigidBodyPose(2, (0.5, 0.25, 0.125), (0.0, 0.0, 0.5, 0.5), 0, False)),
        timestamp_s=12.5,
        stamp_mid_exposure=10,
        stamp_data_received=20,
        stamp_transmit=30,
        params=3,
        marker_sets=(MarkerSet("tip", ((1.0, 2.0, 3.0), (4.0, 5.0, 6.0))), MarkerSet("empty")),
        labeled_markers=(LabeledMarker(65537, (1.0, 1.0, 1.0), 0.5, 0xFFFF, 0.25),),
    )
    message_id, payload = split_message(pack_frame_of_data(frame, version))
    assert message_id == MessageId.NAT_FRAMEOFDATA
    assert parse_frame_of_data(payload, version) == frame


def test_versions_before_3_are_refused() -> None:
    with pytest.raises(ValueError, match="not supported"):
        pack_frame_of_data(one_body_frame(), NatNetVersion(2, 10))
    payload = split_message(pack_frame_of_data(one_body_frame(), NatNetVersion(3, 0)))[1]
    with pytest.raises(NatNetDecodeError, match="not supported"):
        parse_frame_of_data(payload, NatNetVersion(2, 9))


# -- damage ---------------------------------------------------------------------------------


def test_header_size_must_match_the_datagram() -> None:
    data = pack_frame_of_data(one_body_frame())
    with pytest.raises(NatNetDecodeError, match="announces"):
        split_message(data[:-1])
    with pytest.raises(NatNetDecodeError, match="announces"):
        split_message(data + b"\0")
    with pytest.raises(NatNetDecodeError, match="no NatNet header"):
        split_message(b"\x07\x00")


@pytest.mark.parametrize("version", VERSIONS, ids=str)
def test_every_truncation_is_rejected(version: NatNetVersion) -> None:
    payload = split_message(pack_frame_of_data(one_body_frame(), version))[1]
    payload = payload[:-4]  # without the optional end tag, every shorter prefix is incomplete
    for n in range(len(payload)):
        with pytest.raises(NatNetDecodeError):
            parse_frame_of_data(payload[:n], version)


def test_absurd_counts_are_rejected_before_reading() -> None:
    payload = bytearray(split_message(pack_frame_of_data(one_body_frame(), NatNetVersion(3, 0)))[1])
    struct.pack_into("<i", payload, 12, 10_000_000)  # rigid body count
    with pytest.raises(NatNetDecodeError, match="cannot fit"):
        parse_frame_of_data(bytes(payload), NatNetVersion(3, 0))
    struct.pack_into("<i", payload, 12, -1)
    with pytest.raises(NatNetDecodeError, match="negative"):
        parse_frame_of_data(bytes(payload), NatNetVersion(3, 0))


# -- properties -----------------------------------------------------------------------------

f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(f32, f32, f32)
bodies = st.builds(
    RigidBodyPose,
    st.integers(-(2**31), 2**31 - 1),
    vec3,
    st.tuples(f32, f32, f32, f32),
    f32,
    st.booleans(),
)
frames = st.builds(
    FrameOfData,
    frame_number=st.integers(-(2**31), 2**31 - 1),
    rigid_bodies=st.lists(bodies, max_size=5).map(tuple),
    timestamp_s=st.floats(0, 1e6),
    stamp_mid_exposure=st.integers(0, 2**64 - 1),
    stamp_data_received=st.integers(0, 2**64 - 1),
    stamp_transmit=st.integers(0, 2**64 - 1),
    params=st.integers(0, 0xFFFF),
    marker_sets=st.lists(
        st.builds(MarkerSet, st.text("abcxyz_", max_size=8), st.lists(vec3, max_size=3).map(tuple)),
        max_size=2,
    ).map(tuple),
)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(frames, st.sampled_from(VERSIONS))
def test_property_pack_parse_round_trip(frame: FrameOfData, version: NatNetVersion) -> None:
    assert (
        parse_frame_of_data(split_message(pack_frame_of_data(frame, version))[1], version) == frame
    )


@settings(max_examples=500, deadline=None, derandomize=True)
@given(st.binary(max_size=400), st.sampled_from(VERSIONS))
def test_property_random_bytes_only_raise_decode_errors(
    data: bytes, version: NatNetVersion
) -> None:
    with contextlib.suppress(NatNetDecodeError):
        split_message(data)
    with contextlib.suppress(NatNetDecodeError):
        parse_frame_of_data(data, version)
    with contextlib.suppress(NatNetDecodeError):
        parse_server_info(data)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.binary(min_size=1, max_size=60), st.sampled_from(VERSIONS), st.data())
def test_property_random_bytes_spliced_into_a_frame(
    junk: bytes, version: NatNetVersion, data: st.DataObject
) -> None:
    """Random bytes overwriting part of a valid frame: a decode error or a frame, never a crash."""
    payload = bytearray(split_message(pack_frame_of_data(one_body_frame(), version))[1])
    at = data.draw(st.integers(0, len(payload) - 1))
    payload[at : at + len(junk)] = junk
    with contextlib.suppress(NatNetDecodeError):
        parse_frame_of_data(bytes(payload), version)


def test_default_version_is_41() -> None:
    assert DEFAULT_VERSION == NatNetVersion(4, 1)
