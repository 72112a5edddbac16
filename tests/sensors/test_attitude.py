"""WitMotion attitude sensors: frames by hand, Euler convention against scipy, the decoder on
recorded streams with garbage, split and corrupted frames, the reader on a pty (disconnect
included), against the simulated sensor, and property tests on the decoder."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from cdcr_ctl.config.loadcells import SerialPortConfig
from cdcr_ctl.config.tracking import AttitudeSensorsConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.attitude import (
    FRAME_BYTES,
    WitAcceleration,
    WitAngle,
    WitAngularRate,
    WitMotionDecoder,
    WitMotionSensor,
    WitOther,
    WitQuaternion,
    checksum,
    decode_frame,
    open_attitude_sensors,
    pack_acceleration,
    pack_angle,
    pack_angular_rate,
    pack_frame,
    pack_quaternion,
    rotation_from_rpy,
    rpy_from_rotation,
)
from cdcr_ctl.sim.attitude import SimWitMotion

WAIT_S = 5.0


def wait_until(pred: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


# -- frames by hand -------------------------------------------------------------------------


def test_angle_frame_by_hand() -> None:
    # roll 90° -> 16384 = 0x4000, pitch -45° -> -8192 = 0xE000, yaw 0, aux 0x1234;
    # checksum 0x55+0x53+0x40+0xE0+0x34+0x12 = 0x20E -> 0x0E.
    frame = pack_angle(90.0, -45.0, 0.0, 0x1234)
    assert frame == bytes.fromhex("55 53 00 40 00 e0 00 00 34 12 0e")
    assert decode_frame(frame) == WitAngle(90.0, -45.0, 0.0, 0x1234)


def test_other_frames_by_hand() -> None:
    # 1 g on z: 2048 = 0x0800; 25.00 °C -> 2500 = 0x09C4.
    acc = pack_acceleration((0.0, 0.0, 1.0), 25.0)
    assert acc[:10] == bytes.fromhex("55 51 00 00 00 00 00 08 c4 09")
    assert acc[10] == (0x55 + 0x51 + 0x08 + 0xC4 + 0x09) & 0xFF
    assert decode_frame(acc) == WitAcceleration(0.0, 0.0, 1.0, 25.0)
    # -2000 °/s clamps nothing: -32768 = 0x8000.
    rate = pack_angular_rate((-2000.0, 0.0, 1000.0))
    assert rate[2:8] == bytes.fromhex("00 80 00 00 00 40")
    assert decode_frame(rate) == WitAngularRate(-2000.0, 0.0, 1000.0, 0)
    quat = pack_quaternion((1.0, 0.0, 0.0, -0.5))  # +1 clamps to 32767
    assert quat[2:10] == bytes.fromhex("ff 7f 00 00 00 00 00 c0")
    assert decode_frame(quat) == WitQuaternion(32767 / 32768, 0.0, 0.0, -0.5)
    assert decode_frame(pack_frame(0x54, (1, 2, 3, 4))) == WitOther(
        0x54, bytes.fromhex("01 00 02 00 03 00 04 00")
    )


def test_angles_wrap_and_clamp() -> None:
    assert decode_frame(pack_angle(180.0, 0.0, 270.0)) == WitAngle(-180.0, 0.0, -90.0, 0)
    assert decode_frame(pack_angle(179.999, 0.0, -180.0)) == WitAngle(
        179.99450683593750, 0.0, -180.0, 0
    )


def test_checksum_is_low_byte_of_sum() -> None:
    assert checksum(bytes(range(10))) == 45
    assert checksum(b"\xff" * 10) == (255 * 10) & 0xFF


# -- orientation ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("roll", "pitch", "yaw"), [(0, 0, 0), (0.3, -0.2, 1.0), (-2.5, 1.2, -3.0), (1.0, 0.0, 0.0)]
)
def test_rpy_is_zyx_like_scipy(roll: float, pitch: float, yaw: float) -> None:
    R = rotation_from_rpy(roll, pitch, yaw)
    np.testing.assert_allclose(
        R, Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix(), atol=1e-12
    )
    np.testing.assert_allclose(rpy_from_rotation(R), (roll, pitch, yaw), atol=1e-12)


def test_rpy_at_gimbal_lock() -> None:
    R = rotation_from_rpy(0.4, math.pi / 2, 1.0)
    roll, pitch, yaw = rpy_from_rotation(R)
    assert roll == 0.0 and pitch == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(rotation_from_rpy(roll, pitch, yaw), R, atol=1e-9)


def test_gravity_points_up_in_a_level_sensor() -> None:
    sim = SimWitMotion(lambda: np.eye(3), packets=("acceleration",))
    try:
        tilted = rotation_from_rpy(0.0, math.radians(30), 0.0)
        (acc,) = WitMotionDecoder().feed(sim.frames_for(tilted, 0.0))
        # Pitched +30° about y: the sensor sees "up" at -sin(30°) on x, cos(30°) on z.
        assert acc.x_g == pytest.approx(-0.5, abs=1e-3)
        assert acc.z_g == pytest.approx(math.cos(math.radians(30)), abs=1e-3)
    finally:
        sim.close()


def test_simulated_angular_rate_from_successive_orientations() -> None:
    sim = SimWitMotion(lambda: np.eye(3), packets=("angular_rate",))
    try:
        w = math.radians(90.0)  # 90 °/s about z
        dec = WitMotionDecoder()
        dec.feed(sim.frames_for(rotation_from_rpy(0, 0, 0), 10.0))
        (rate,) = dec.feed(sim.frames_for(rotation_from_rpy(0, 0, w * 0.01), 10.01))
        assert (rate.x_dps, rate.y_dps) == (0.0, 0.0)
        assert rate.z_dps == pytest.approx(90.0, abs=0.1)
    finally:
        sim.close()


# -- decoder on recorded streams ------------------------------------------------------------

A1 = pack_angle(10.0, 20.0, 30.0)
A2 = pack_angle(-10.0, 5.0, 0.0)
Q1 = pack_quaternion((1.0, 0.0, 0.0, 0.0))
BAD = A1[:10] + bytes([(A1[10] + 1) & 0xFF])  # checksum off by one

RECORDED = (
    b"\x00\x13\xff"  # noise before anything
    + b"\x55"  # a lone header byte
    + b"\x55\x00"  # header then an invalid type
    + A1
    + BAD
    + b"\x55\x53\x01"  # a frame cut off by a reconnect...
    + Q1  # ... then good frames resume
    + A2
    + pack_frame(0x54, (1, 2, 3, 4))
)
EXPECTED = [
    decode_frame(A1),
    decode_frame(Q1),
    decode_frame(A2),
    WitOther(0x54, pack_frame(0x54, (1, 2, 3, 4))[2:10]),
]


@pytest.mark.parametrize("chunk", [1, 2, 5, 11, 13, len(RECORDED)])
def test_recorded_stream_with_faults_in_any_chunks(chunk: int) -> None:
    dec = WitMotionDecoder()
    got = []
    for i in range(0, len(RECORDED), chunk):
        got += dec.feed(RECORDED[i : i + chunk])
    assert got == EXPECTED
    assert dec.stats.frames_ok == 4
    # "55 55 00 ..." reads as a port-status frame (type 0x55) with a wrong checksum; then the
    # bad frame; then the cut-off frame read together with the 8 bytes after it.
    assert dec.stats.bad_frames == 3
    assert dec.stats.discarded_bytes == len(RECORDED) - 4 * FRAME_BYTES


def test_header_inside_data_does_not_hide_the_next_frame() -> None:
    # Data bytes 0x55 0x53 inside a bad frame look like a header: resync must still find A2.
    tricky = bytes([0x55, 0x53, 0x55, 0x53, 0, 0, 0, 0, 0, 0, 0]) + A2
    assert WitMotionDecoder().feed(tricky) == [decode_frame(A2)]


# -- reader on a pty ------------------------------------------------------------------------


def test_reader_on_pty_then_disconnect(pty_pair, open_serial) -> None:
    sensor = WitMotionSensor(open_serial(pty_pair.path), index=2, stale_after_s=5.0)
    with sensor:
        assert sensor.latest().seq == 0 and sensor.latest().stale
        pty_pair.write(RECORDED)
        assert wait_until(lambda: sensor.latest().seq == 2)
        s = sensor.latest()
        assert (s.index, s.port) == (2, pty_pair.path)
        assert math.degrees(s.roll_rad) == pytest.approx(-10.0, abs=0.01)
        assert math.degrees(s.pitch_rad) == pytest.approx(5.0, abs=0.01)
        assert s.quaternion_wxyz == (32767 / 32768, 0.0, 0.0, 0.0)
        assert not s.stale
        assert sensor.stats.bad_frames == 3
        pty_pair.write(A1[:6])  # half a frame, then the cable is pulled
        pty_pair.close_master()
        assert wait_until(lambda: sensor.failure is not None)
        assert isinstance(sensor.failure, SensorError)
        assert sensor.failure.port == pty_pair.path
        assert wait_until(lambda: not sensor.running)  # the thread ends just after reporting
        assert sensor.latest().stale and sensor.latest().seq == 2


# -- reader against the simulated sensor ----------------------------------------------------


def test_group_from_config_against_two_simulated_sensors() -> None:
    R0 = rotation_from_rpy(0.1, -0.2, 0.3)
    R1 = rotation_from_rpy(-0.4, 0.25, 2.0)
    sims = [
        SimWitMotion(lambda: R0, rate_hz=200.0).start(),
        SimWitMotion(
            lambda: R1, rate_hz=200.0, noise_deg=0.05, yaw_offset_deg=15.0, seed=2
        ).start(),
    ]
    try:
        cfg = AttitudeSensorsConfig(
            sensors=[SerialPortConfig(port=s.path, baudrate=9600) for s in sims],
            stale_after_s=5.0,
        )
        with open_attitude_sensors(cfg) as group:
            group.wait_for_samples(WAIT_S)
            assert wait_until(lambda: all(s.seq >= 5 for s in group.latest()))
            s0, s1 = group.latest()
            # int16 quantisation: 180/32768 ≈ 0.0055°
            np.testing.assert_allclose(s0.rotation(), R0, atol=2e-4)
            assert (s0.index, s1.index) == (0, 1)
            # Noisy with a magnetic yaw error: roll and pitch right, yaw off by ~15°.
            assert s1.roll_rad == pytest.approx(-0.4, abs=math.radians(0.5))
            assert s1.pitch_rad == pytest.approx(0.25, abs=math.radians(0.5))
            assert math.degrees(s1.yaw_rad - 2.0) == pytest.approx(15.0, abs=0.5)
            tilt = s1.rotation(use_yaw=False)
            assert rpy_from_rotation(tilt)[2] == 0.0
            # The quaternion frame carries the truth without the yaw error.
            w, x, y, z = s1.quaternion_wxyz
            np.testing.assert_allclose(Rotation.from_quat([x, y, z, w]).as_matrix(), R1, atol=2e-4)
            sims[1].hang_up()
            assert wait_until(lambda: group.failure is not None)
            assert group.failure.port == sims[1].path
            with pytest.raises(SensorError):
                group.raise_if_failed()
            assert not group.latest()[0].stale and group.latest()[1].stale
    finally:
        for s in sims:
            s.close()


def test_open_reports_the_port_that_fails() -> None:
    cfg = AttitudeSensorsConfig(sensors=[SerialPortConfig(port="/dev/nonexistent-wit")])
    with pytest.raises(SensorError) as err:
        open_attitude_sensors(cfg)
    assert err.value.port == "/dev/nonexistent-wit"


def test_simulated_sensor_garbage_and_pause(open_serial) -> None:
    with SimWitMotion(lambda: np.eye(3), rate_hz=200.0) as sim:
        sensor = WitMotionSensor(open_serial(sim.path), stale_after_s=0.05)
        with sensor:
            assert wait_until(lambda: sensor.latest().seq > 3)
            sim.inject(b"\x55\x53" + bytes(9) + b"\xaa\x55")  # bad checksum and junk
            assert wait_until(lambda: sensor.stats.bad_frames >= 1)
            sim.pause()
            assert wait_until(lambda: sensor.latest().stale)
            seq = sensor.latest().seq
            sim.resume()
            assert wait_until(lambda: sensor.latest().seq > seq and not sensor.latest().stale)
            assert sensor.failure is None


# -- properties -----------------------------------------------------------------------------


def valid_windows(data: bytes) -> list[bytes]:
    """Every 11-byte window that is a checksum-valid frame with a standard type byte."""
    return [
        data[i : i + FRAME_BYTES]
        for i in range(len(data) - FRAME_BYTES + 1)
        if data[i] == 0x55
        and 0x50 <= data[i + 1] <= 0x5F
        and checksum(data[i : i + 10]) == data[i + 10]
    ]


@settings(max_examples=500, deadline=None, derandomize=True)
@given(st.lists(st.binary(max_size=40), max_size=8))
def test_property_random_bytes_yield_only_checksum_valid_frames(chunks: list[bytes]) -> None:
    dec = WitMotionDecoder()
    got = [p for c in chunks for p in dec.feed(c)]
    allowed = [decode_frame(w) for w in valid_windows(b"".join(chunks))]
    assert all(p in allowed for p in got)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.binary(max_size=200).map(lambda b: b.replace(b"\x55", b"")))
def test_property_bytes_without_a_header_yield_nothing(data: bytes) -> None:
    dec = WitMotionDecoder()
    assert dec.feed(data) == []
    assert dec.stats.discarded_bytes == len(data)


int16_no_header = st.integers(-32768, 32767).filter(
    lambda v: 0x55 not in v.to_bytes(2, "little", signed=True)
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    st.lists(
        st.tuples(
            st.sampled_from([0x51, 0x52, 0x53, 0x59]),
            st.lists(int16_no_header, min_size=4, max_size=4),
        ),
        min_size=1,
        max_size=6,
    ),
    st.data(),
)
def test_property_one_corrupted_byte_loses_exactly_its_frame(frames, data) -> None:
    raw = [pack_frame(kind, values) for kind, values in frames]
    k = data.draw(st.integers(0, len(raw) - 1))
    at = data.draw(st.integers(1, FRAME_BYTES - 1))  # any byte but the header
    delta = data.draw(st.integers(1, 255))
    bad = bytearray(raw[k])
    bad[at] = (bad[at] + delta) & 0xFF
    stream = b"".join(raw[:k]) + bytes(bad) + b"".join(raw[k + 1 :])
    expected = [decode_frame(f) for i, f in enumerate(raw) if i != k]
    got = WitMotionDecoder().feed(stream)
    if 0x55 not in bad[1:]:
        # Nothing in the damaged frame looks like a header: exactly that frame is lost.
        assert got == expected
    else:
        # A 0x55 inside it (the damaged byte or its checksum) may start a false frame with its
        # neighbours that passes an 8-bit checksum by chance: all the decoder can promise then
        # is that it returns only checksum-valid frames.
        allowed = [decode_frame(w) for w in valid_windows(stream)]
        assert all(p in allowed for p in got)
