"""The one-rigid-body frame in one struct (``natnet.single``) against the general packer and
decoder, bytes for bytes and floats bit for bit, in every stream version; the simulated server's
``make_datagram`` against ``pack_frame_of_data(make_frame(...))``."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.sensors.natnet import (
    FrameOfData,
    NatNetVersion,
    RigidBodyPose,
    pack_frame_of_data,
    parse_frame_of_data,
)
from cdcr_ctl.sensors.natnet.single import (
    SingleBodyFrame,
    pack_single_body_frame,
    read_single_body_frame,
)
from cdcr_ctl.sim.tracker import SimNatNetServer

VERSIONS = [NatNetVersion(3, 0), NatNetVersion(3, 1), NatNetVersion(4, 0), NatNetVersion(4, 1)]
VERSIONS.append(NatNetVersion(4, 2))

f32 = st.floats(width=32, allow_nan=False)
u64 = st.integers(0, 2**63)


def _general(one: SingleBodyFrame) -> FrameOfData:
    body = RigidBodyPose(
        one.body_id,
        (one.x, one.y, one.z),
        (one.qx, one.qy, one.qz, one.qw),
        one.mean_error,
        bool(one.body_params & 1),
    )
    return FrameOfData(
        one.frame_number,
        (body,),
        one.timestamp_s,
        one.stamp_mid_exposure,
        one.stamp_data_received,
        one.stamp_transmit,
        one.params,
        timecode=one.timecode,
        timecode_sub=one.timecode_sub,
    )


def _bits(v: float) -> bytes:
    return struct.pack("<d", v)


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from(VERSIONS),
    st.integers(-(2**31), 2**31 - 1),
    st.integers(-(2**31), 2**31 - 1),
    st.tuples(*[f32] * 8),
    st.sampled_from([0, 1]),
    st.tuples(st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1)),
    st.floats(allow_nan=False, allow_infinity=False, min_value=-1e9, max_value=1e12),
    st.tuples(u64, u64, u64),
    st.integers(0, 0xFFFF),
)
def test_single_body_frame_packs_and_reads_as_the_general_code(
    version, number, body_id, floats, valid, timecode, t, stamps, params
):
    one = SingleBodyFrame(number, body_id, *floats, valid, *timecode, t, *stamps, params)
    general = _general(one)
    data = pack_single_body_frame(version, one)
    assert data == pack_frame_of_data(general, version)
    untagged = struct.pack("<HH", 7, len(data) - 8) + data[4:-4]
    for datagram in (data, untagged):  # with and without the end-of-data tag
        got = read_single_body_frame(datagram, version)
        assert got is not None
        ref = parse_frame_of_data(datagram[4:], version)
        b = ref.rigid_bodies[0]
        assert got.frame_number == ref.frame_number and got.body_id == b.id
        want = [*b.position, *b.orientation_xyzw, b.mean_error, ref.timestamp_s]
        have = [got.x, got.y, got.z, got.qx, got.qy, got.qz, got.qw, got.mean_error]
        assert [_bits(v) for v in [*have, got.timestamp_s]] == [_bits(v) for v in want]
        assert bool(got.body_params & 1) == b.tracking_valid
        assert (got.timecode, got.timecode_sub, got.params) == (
            ref.timecode,
            ref.timecode_sub,
            ref.params,
        )
        assert (got.stamp_mid_exposure, got.stamp_data_received, got.stamp_transmit) == (
            ref.stamp_mid_exposure,
            ref.stamp_data_received,
            ref.stamp_transmit,
        )


@pytest.mark.parametrize("version", VERSIONS)
def test_other_layouts_go_to_the_general_decoder(version) -> None:
    body = RigidBodyPose(1, (0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0))
    for frame in (
        FrameOfData(5),  # no body
        FrameOfData(5, (body, body)),  # two
    ):
        assert read_single_body_frame(pack_frame_of_data(frame, version), version) is None
    one = pack_frame_of_data(FrameOfData(5, (body,), timestamp_s=1.5), version)
    assert read_single_body_frame(one, version) is not None
    assert read_single_body_frame(one + b"\0", version) is None  # length
    assert read_single_body_frame(b"\x08\x00" + one[2:], version) is None  # message id
    assert read_single_body_frame(one[:2] + b"\x00\x00" + one[4:], version) is None  # size
    other = NatNetVersion(3, 0) if version >= (4, 0) else NatNetVersion(4, 1)
    assert read_single_body_frame(one, other) is None  # another version's layout
    assert read_single_body_frame(one, NatNetVersion(2, 10)) is None
    nan = pack_frame_of_data(FrameOfData(5, (body,), timestamp_s=math.nan), version)
    assert read_single_body_frame(nan, version) is None  # the general decoder raises


def test_a_nonzero_size_of_an_empty_list_goes_to_the_general_decoder() -> None:
    v = NatNetVersion(4, 1)
    body = RigidBodyPose(1, (0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0))
    data = bytearray(pack_frame_of_data(FrameOfData(5, (body,)), v))
    data[12:16] = (0).to_bytes(4, "little")  # marker sets' byte size: still 0
    assert read_single_body_frame(bytes(data), v) is not None
    data[12:16] = (4).to_bytes(4, "little")  # a size the general decoder accepts, not ours
    assert read_single_body_frame(bytes(data), v) is None
    parse_frame_of_data(bytes(data[4:]), v)


def _server(**kw) -> SimNatNetServer:
    poses = iter(range(10**6))

    def truth():
        k = next(poses)
        a = 0.01 * k + 0.3
        c, s = math.cos(a), math.sin(a)
        R = np.array([[c, -s * 0.1, s], [s * 0.1, 1.0 - 1e-3 * k, 0.02], [-s, -0.02, c]])
        if k % 7 == 3:
            R[0, 1] = 0.0  # a zero entry: the general arithmetic
        return R, np.array([10.0 + k, -3.5 * k + 0.25, 90.0 - 0.5 * k])

    return SimNatNetServer(truth, noise_mm=0.05, seed=3, **kw)


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("kw", [{}, {"dropout": 0.3}, {"include_markers": True}])
def test_make_datagram_is_pack_of_make_frame(version, kw) -> None:
    a, b = _server(version=version, **kw), _server(version=version, **kw)
    a._t0 = b._t0 = 0.0  # frame timestamps from one origin (as in lock-step)
    try:
        for k in range(40):
            now = 0.01 * k
            a.occlude(k % 11 == 5)
            b.occlude(k % 11 == 5)
            want = pack_frame_of_data(b.make_frame(now, transmit_s=now + 0.004), version)
            assert a.make_datagram(now, transmit_s=now + 0.004) == want
        assert a.rng.random() == b.rng.random()  # the noise stream drew alike
    finally:
        a.close()
        b.close()
