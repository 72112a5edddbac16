"""Tip tracker: frame transforms against hand-derived values and scipy, the NatNet client against
recorded datagrams and the simulated server on loopback (occlusion, silence, disconnect), the line
stream over UDP and TCP, and property tests on both decoders.

Sockets bind to 127.0.0.1 on ephemeral ports only.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from cdcr_ctl.config.loader import validate_mapping
from cdcr_ctl.config.tracking import RigidTransformConfig, TrackerConfig
from cdcr_ctl.errors import ConfigError, SensorError
from cdcr_ctl.sensors.natnet import (
    FrameOfData,
    MessageId,
    NatNetVersion,
    RigidBodyPose,
    ServerInfo,
    pack_connect,
    pack_frame_of_data,
    pack_keepalive,
    pack_message,
    pack_server_info,
)
from cdcr_ctl.sensors.tracker import (
    LineStreamTracker,
    NatNetTracker,
    TrackerTransform,
    format_stream_line,
    open_tracker,
    parse_stream_line,
    quaternion_from_rotation,
    rotation_from_quaternion,
    rotation_from_rotvec,
)
from cdcr_ctl.sim.simconfig import SimConfig, TrackerSimConfig, TruthEffects
from cdcr_ctl.sim.tracker import (
    SimLineStreamServer,
    SimNatNetServer,
    require_loopback,
    sim_tracker_from_config,
)

LOCAL = "127.0.0.1"
SERVER = (LOCAL, 41510)  # a made-up address for the socket-free tests
WAIT_S = 5.0  # generous: only reached when something is broken


def wait_until(pred: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


def udp_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((LOCAL, 0))
    return s


@pytest.fixture
def sockets() -> Iterator[Callable[[], socket.socket]]:
    made: list[socket.socket] = []

    def make() -> socket.socket:
        s = udp_socket()
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


# -- rotations and frames --------------------------------------------------------------------


@pytest.mark.parametrize(
    "rotvec", [[0, 0, 0], [0.3, -0.2, 0.1], [0, 0, math.pi / 2], [1e-9, 0, 0], [2.0, 1.0, -2.0]]
)
def test_rotations_match_scipy(rotvec: list[float]) -> None:
    R = rotation_from_rotvec(rotvec)
    np.testing.assert_allclose(R, Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)
    q = quaternion_from_rotation(R)
    q_ref = Rotation.from_rotvec(rotvec).as_quat()  # x, y, z, w
    assert abs(abs(float(np.dot(q, q_ref))) - 1.0) < 1e-12
    np.testing.assert_allclose(rotation_from_quaternion(q), R, atol=1e-12)


def test_quaternion_must_be_unit() -> None:
    with pytest.raises(ValueError, match="unit quaternion"):
        rotation_from_quaternion((0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="unit quaternion"):
        rotation_from_quaternion((0.0, 0.0, 0.0, 1.01))
    with pytest.raises(ValueError, match="unit quaternion"):
        rotation_from_quaternion((math.nan, 0.0, 0.0, 1.0))


def hand_transform() -> TrackerTransform:
    """base_from_tracker: 90° about z then +10 mm x; tip 50 mm along the body's z; metres."""
    return TrackerTransform.from_transforms(
        RigidTransformConfig(rotvec_rad=[0, 0, math.pi / 2], translation_mm=[10, 0, 0]),
        RigidTransformConfig(translation_mm=[0, 0, 50]),
        1000.0,
    )


def test_tip_in_base_by_hand() -> None:
    # Body at (0.1, 0, 0) m, turned 90° about x: its z axis points along tracker -y, so the tip
    # is at (100, -50, 0) mm in the tracker frame; Rz(90°) maps that to (50, 100, 0); + (10, 0, 0).
    R_tb = rotation_from_rotvec([math.pi / 2, 0, 0])
    p, R = hand_transform().tip_in_base((0.1, 0.0, 0.0), R_tb)
    np.testing.assert_allclose(p, [60.0, 100.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(R, rotation_from_rotvec([0, 0, math.pi / 2]) @ R_tb, atol=1e-12)


def test_body_in_tracker_inverts_tip_in_base() -> None:
    tf = TrackerTransform.from_transforms(
        RigidTransformConfig(rotvec_rad=[0.1, -0.4, 2.0], translation_mm=[-300, 25, 1200]),
        RigidTransformConfig(rotvec_rad=[0.0, 0.3, 0.0], translation_mm=[3, -4, 80]),
        1000.0,
    )
    R_tip = rotation_from_rotvec([0.5, 0.2, -0.1])
    p_tip = np.array([12.0, -40.0, 85.0])
    p_body, R_tb = tf.body_in_tracker(p_tip, R_tip)
    p_back, R_back = tf.tip_in_base(p_body, R_tb)
    np.testing.assert_allclose(p_back, p_tip, atol=1e-9)
    np.testing.assert_allclose(R_back, R_tip, atol=1e-12)


def test_config_units_default_by_kind_and_validation() -> None:
    assert TrackerConfig().mm_per_unit == 1000.0
    assert TrackerConfig(kind="udp_stream").mm_per_unit == 1.0
    assert TrackerConfig(kind="tcp_stream", units_to_mm=25.4).mm_per_unit == 25.4
    cfg = validate_mapping(
        {"kind": "natnet", "host": LOCAL, "marker_to_tip": {"translation_mm": [0, 0, 5]}},
        TrackerConfig,
        "rig.yaml",
    )
    assert cfg.marker_to_tip.translation_mm == [0, 0, 5]
    with pytest.raises(ConfigError, match=r"marker_to_tip\.translation_mm"):
        validate_mapping({"marker_to_tip": {"translation_mm": [0, 0]}}, TrackerConfig, "rig.yaml")


# -- NatNet client against recorded datagrams --------------------------------------------------


V41 = NatNetVersion(4, 1)


def info_datagram(version: NatNetVersion = V41) -> bytes:
    return pack_server_info(
        ServerInfo("Motive", (3, 1, 0, 0), version, 1000, 1511, False, "0.0.0.0")
    )


def frame_datagram(
    n: int,
    position: tuple[float, float, float] = (0.1, 0.2, 0.3),
    *,
    body_id: int = 1,
    valid: bool = True,
    quat: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0),
    version: NatNetVersion = V41,
) -> bytes:
    frame = FrameOfData(
        frame_number=n,
        rigid_bodies=(RigidBodyPose(body_id, position, quat, 0.0, valid),),
        timestamp_s=n / 100,
        stamp_mid_exposure=10_000,
        stamp_transmit=10_004,  # 4 ticks of a 1 kHz clock: 4 ms server latency
    )
    return pack_frame_of_data(frame, version)


class FakeClock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def recorded_tracker(
    sock: socket.socket, clock: FakeClock, server: tuple[str, int] = SERVER
) -> NatNetTracker:
    return NatNetTracker(
        sock, server, TrackerTransform.identity(1000.0), 1, stale_after_s=0.1, clock=clock
    )


def test_recorded_datagrams_with_faults(sockets: Callable[[], socket.socket]) -> None:
    clock = FakeClock()
    tr = recorded_tracker(sockets(), clock)
    good = frame_datagram(1)
    tr.handle_datagram(good, SERVER)  # before the server info: the version is unknown
    assert tr.latest().seq == 0
    tr.handle_datagram(info_datagram(), SERVER)
    assert tr.version == NatNetVersion(4, 1)

    tr.handle_datagram(frame_datagram(2), SERVER)
    s = tr.latest()
    assert s.seq == 1 and not s.stale and not s.occluded
    np.testing.assert_allclose(s.position_mm, [100.0, 200.0, 300.0], rtol=1e-6)
    assert s.t_s == pytest.approx(100.0 - 0.004)  # receipt minus the server's latency
    assert s.frame == 2

    recorded = [
        b"\x07\x00\x05\x00garbage",  # header announces 5 bytes, carries 7
        frame_datagram(3)[:-9],  # cut short
        b"\xde\xad\xbe\xef" * 20,
        frame_datagram(4)[:40] + b"\xff" * (len(frame_datagram(4)) - 40),  # damaged body
        frame_datagram(5, body_id=9),  # body missing
        frame_datagram(6, valid=False),  # tracking-valid flag cleared
        frame_datagram(7, quat=(0.0, 0.0, 0.0, 0.0)),  # not a rotation
        frame_datagram(8, (math.nan, 0.0, 0.0)),
        frame_datagram(2, (9.0, 9.0, 9.0)),  # repeated frame number
        pack_keepalive(),  # not a frame
    ]
    for d in recorded:
        tr.handle_datagram(d, SERVER)
    tr.handle_datagram(frame_datagram(10, (5.0, 5.0, 5.0)), ("127.0.0.2", 1511))  # other host
    assert tr.latest().seq == 1  # nothing of that was published
    np.testing.assert_allclose(tr.latest().position_mm, [100.0, 200.0, 300.0], rtol=1e-6)
    assert tr.latest().occluded
    assert tr.stats.bad == 4
    assert tr.stats.occluded == 4
    assert tr.stats.out_of_order == 1
    assert tr.stats.foreign == 1
    assert tr.stats.other_messages == 2  # the early frame and the keep-alive

    tr.handle_datagram(frame_datagram(11, (0.0, 0.0, 1.0)), SERVER)
    s = tr.latest()
    assert s.seq == 2 and not s.occluded
    np.testing.assert_allclose(s.position_mm, [0.0, 0.0, 1000.0], rtol=1e-6)


def test_stale_and_lost_follow_the_clock(sockets: Callable[[], socket.socket]) -> None:
    clock = FakeClock()
    fake_server = sockets()  # stands in for Motive's command port, to see what the client sends
    server = fake_server.getsockname()
    tr = recorded_tracker(sockets(), clock, server)
    tr.handle_datagram(info_datagram(), server)
    tr.handle_datagram(frame_datagram(1), server)
    clock.t += 0.05
    assert not tr.latest().stale
    clock.t += 0.1
    assert tr.latest().stale and tr.failure is None
    clock.t += 1.0
    tr.poll()  # notices the silence: re-sends NAT_CONNECT, and the unicast keep-alive
    assert isinstance(tr.failure, SensorError)
    assert tr.failure.port == f"natnet://127.0.0.1:{server[1]}" and "lost" in str(tr.failure)
    fake_server.settimeout(WAIT_S)
    assert fake_server.recv(1024) == pack_connect()
    assert fake_server.recv(1024) == pack_keepalive()
    tr.handle_datagram(frame_datagram(2), server)
    assert tr.failure is None and not tr.latest().stale


def test_old_server_version_is_a_clear_error(sockets: Callable[[], socket.socket]) -> None:
    tr = recorded_tracker(sockets(), FakeClock())
    tr.handle_datagram(info_datagram(NatNetVersion(2, 9)), SERVER)
    assert tr.version is None
    assert isinstance(tr.failure, SensorError) and "not supported" in str(tr.failure)


@settings(max_examples=400, deadline=None, derandomize=True)
@given(st.lists(st.binary(max_size=300), max_size=6))
def test_property_random_datagrams_never_crash_or_publish(datagrams: list[bytes]) -> None:
    with udp_socket() as sock:
        tr = recorded_tracker(sock, FakeClock())
        tr.handle_datagram(info_datagram(), SERVER)
        for d in datagrams:
            tr.handle_datagram(d, SERVER)
        assert tr.latest().seq == 0


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.binary(max_size=300))
def test_property_random_payload_behind_a_frame_header(payload: bytes) -> None:
    with udp_socket() as sock:
        tr = recorded_tracker(sock, FakeClock())
        tr.handle_datagram(info_datagram(), SERVER)
        tr.handle_datagram(pack_message(MessageId.NAT_FRAMEOFDATA, payload), SERVER)
        assert tr.latest().seq == 0


# -- NatNet client against the simulated server ---------------------------------------------


def circle_truth(t0: float) -> Callable[[], tuple[np.ndarray, np.ndarray]]:
    def truth() -> tuple[np.ndarray, np.ndarray]:
        t = time.monotonic() - t0
        return rotation_from_rotvec([0.0, 0.0, 0.5 * t]), np.array(
            [20.0 * math.cos(t), 20.0 * math.sin(t), 150.0]
        )

    return truth


def test_natnet_client_follows_simulated_server() -> None:
    tf = hand_transform()
    truth = circle_truth(time.monotonic())
    with SimNatNetServer(
        truth, transform=tf, rate_hz=200.0, latency_s=0.003, include_markers=True
    ) as server:
        sock = udp_socket()
        with NatNetTracker(sock, server.command_address, tf, 1, stale_after_s=1.0) as tr:
            info = tr.connect(timeout_s=WAIT_S)
            assert info.natnet_version == NatNetVersion(4, 1)
            assert info.data_port == server.data_address[1]
            assert wait_until(lambda: tr.latest().seq >= 20)
            s = tr.latest()
            R_truth, p_truth = truth()
            # The circle moves 20 mm/s; the sample is at most a few frames old.
            assert np.linalg.norm(s.position_mm - p_truth) < 2.0
            assert s.rotation is not None
            assert np.allclose(s.rotation[2], R_truth[2], atol=1e-6)  # rotation is about z
            assert s.frame >= 20 and not s.stale
            assert tr.stats.bad == 0 and tr.stats.occluded == 0
            assert s.t_s < time.monotonic() - 0.0029  # the server's 3 ms were taken off
            assert server.subscribers  # the client registered and keeps alive


@pytest.mark.parametrize("mode", ["invalid", "missing"])
def test_occlusion_dropouts_are_counted_not_published(mode: str) -> None:
    fixed = (np.eye(3), np.array([1.0, 2.0, 3.0]))
    with (
        SimNatNetServer(
            lambda: fixed, rate_hz=200.0, dropout=0.5, dropout_mode=mode, seed=3
        ) as server,
        NatNetTracker(
            udp_socket(), server.command_address, TrackerTransform.identity(1000.0), 1
        ) as tr,
    ):
        tr.connect(WAIT_S)
        assert wait_until(lambda: tr.stats.occluded >= 5 and tr.latest().seq >= 5)
        np.testing.assert_allclose(tr.latest().position_mm, [1.0, 2.0, 3.0], atol=1e-4)
        assert tr.stats.bad == 0


def test_silence_then_recovery_then_disconnect() -> None:
    with SimNatNetServer(lambda: np.array([0.0, 0.0, 100.0]), rate_hz=200.0) as server:
        sock = udp_socket()
        tr = NatNetTracker(
            sock, server.command_address, TrackerTransform.identity(1000.0), 1, lost_after_s=0.2
        )
        with tr:
            tr.connect(WAIT_S)
            assert wait_until(lambda: tr.latest().seq > 0)
            server.pause()  # fault hook: stop serving
            assert wait_until(lambda: tr.failure is not None)
            assert "natnet://127.0.0.1" in str(tr.failure) and "lost" in str(tr.failure)
            assert tr.latest().stale
            assert tr.running  # UDP silence is not fatal: the client keeps trying
            server.resume()
            seq = tr.latest().seq
            assert wait_until(lambda: tr.failure is None and tr.latest().seq > seq)
            server.inject(b"\x07\x00\x03\x00\x01\x02")  # fault hook: garbage on the wire
            assert wait_until(lambda: tr.stats.bad >= 1)
            sock.close()  # the transport dies mid-run
            assert wait_until(lambda: not tr.running)
            assert isinstance(tr.failure, SensorError)
            assert tr.failure.port == f"natnet://127.0.0.1:{server.command_address[1]}"
            assert tr.latest().stale


def test_open_tracker_from_config_and_unanswered_connect() -> None:
    with SimNatNetServer(lambda: np.array([1.0, 0.0, 0.0]), rate_hz=200.0) as server:
        cfg = TrackerConfig(host=LOCAL, command_port=server.command_address[1], port=1511)
        with open_tracker(cfg) as tr:
            assert isinstance(tr, NatNetTracker)
            assert tr.sock.getsockname()[0] == LOCAL  # loopback server -> loopback socket
            assert wait_until(lambda: tr.latest().seq > 0)
            x, age = tr.position_and_age()
            assert x == pytest.approx([1.0, 0.0, 0.0], abs=1e-4) and age < WAIT_S
    with udp_socket() as silent:
        cfg = TrackerConfig(host=LOCAL, command_port=silent.getsockname()[1], connect_timeout_s=0.2)
        with pytest.raises(SensorError, match="no NAT_SERVERINFO") as err:
            open_tracker(cfg)
        assert err.value.port == f"natnet://127.0.0.1:{silent.getsockname()[1]}"


def test_simulator_refuses_non_loopback_addresses() -> None:
    assert require_loopback("127.0.0.1") == "127.0.0.1"
    for host in ("0.0.0.0", "192.0.2.1", "239.255.42.99", "localhost"):
        with pytest.raises(ValueError):
            require_loopback(host)


# -- line stream ----------------------------------------------------------------------------

GOOD_LINES = [
    (b"1.5,10,-20.25,300", (1.5, (10.0, -20.25, 300.0), None)),
    (b" 2 , 1e2 , .5 , -3. ", (2.0, (100.0, 0.5, -3.0), None)),
    (b"3,0,0,0,0,0,0.7071068,0.7071068", (3.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.7071068, 0.7071068))),
]
BAD_LINES = [
    b"1,2,3",
    b"1,2,3,4,5",
    b"1,2,3,4,0,0,0,2",  # quaternion norm 2
    b"1,2,3,inf",
    b"1,2,3,nan",
    b"1,2,3,1e999",
    b"1,2,3,4x",
    b"1;2;3;4",
    b"1,2,3,1_0",
    b"1," * 100 + b"1",
]


@pytest.mark.parametrize(("line", "expected"), GOOD_LINES)
def test_parse_good_stream_lines(line: bytes, expected: tuple) -> None:
    p = parse_stream_line(line)
    assert p is not None
    assert (p.t_s, p.position, p.orientation_xyzw) == expected


@pytest.mark.parametrize("line", BAD_LINES)
def test_parse_bad_stream_lines(line: bytes) -> None:
    assert parse_stream_line(line) is None


def test_format_stream_line_round_trips() -> None:
    line = format_stream_line(12.25, (1.0, -2.5, 3.125), (0.0, 0.0, 0.0, 1.0))
    assert line == b"12.250000,1.0000,-2.5000,3.1250,0.0000000,0.0000000,0.0000000,1.0000000\n"
    p = parse_stream_line(line.rstrip(b"\n"))
    assert p is not None and p.position == (1.0, -2.5, 3.125)


def tcp_reader(clock: Callable[[], float] = time.monotonic) -> LineStreamTracker:
    # handle_bytes() is fed directly: the socket is only there to be owned and closed.
    a, b = socket.socketpair()
    b.close()
    return LineStreamTracker(
        a, TrackerTransform.identity(1.0), transport="tcp", port_name="tcp://test", clock=clock
    )


RECORDED_TCP = (
    b"# laser tracker bridge v1\n"
    b"1.00,10,20,30\r\n"
    b"\x00\xff garbage\n"
    b"1.01,11,21,31\n"
    b"1.02,12,22\n"  # a field lost
    + b"9"
    * 300  # an overlong run with no line end (a stuck sender)
    + b"\n1.03,13,23,33\n"
    b"1.01,99,99,99\n"  # older than the last: reordered
    b"1.04,14,24,34\n"
)


@pytest.mark.parametrize("chunk", [1, 3, 7, 64, len(RECORDED_TCP)])
def test_tcp_recorded_stream_split_anywhere(chunk: int) -> None:
    reader = tcp_reader(FakeClock())
    for i in range(0, len(RECORDED_TCP), chunk):
        reader.handle_bytes(RECORDED_TCP[i : i + chunk])
    s = reader.latest()
    assert s.seq == 4 and s.frame == 4 and s.tracker_time_s == 1.04
    assert list(s.position_mm) == [14.0, 24.0, 34.0]
    assert s.rotation is None
    assert reader.stats.bad == 3  # garbage, short line, overlong run
    assert reader.stats.out_of_order == 1
    reader.close()


def test_udp_stream_datagrams_end_lines() -> None:
    with udp_socket() as sock:
        reader = LineStreamTracker(
            sock, TrackerTransform.identity(1.0), transport="udp", port_name="udp://t"
        )
        reader.handle_bytes(b"1,1,2,3")  # no line end: the datagram ends it
        reader.handle_bytes(b"2,4,5,6\n3,7,8")  # the second line is incomplete: bad
        assert reader.latest().seq == 2 and reader.stats.bad == 1
        assert list(reader.latest().position_mm) == [4.0, 5.0, 6.0]


def test_udp_stream_against_simulated_sender() -> None:
    tf = TrackerTransform.from_transforms(
        RigidTransformConfig(translation_mm=[0, 0, -100]), RigidTransformConfig(), 1.0
    )
    with udp_socket() as sock:
        reader = LineStreamTracker(sock, tf, transport="udp", port_name="udp://sim")
        with (
            reader,
            SimLineStreamServer(
                lambda: np.array([5.0, 6.0, 107.0]),
                transport="udp",
                target=sock.getsockname(),
                transform=tf,
                rate_hz=200.0,
                with_orientation=True,
            ) as sender,
        ):
            assert wait_until(lambda: reader.latest().seq >= 10)
            np.testing.assert_allclose(reader.latest().position_mm, [5.0, 6.0, 107.0], atol=1e-3)
            assert reader.latest().rotation is not None
            sender.inject(b"nonsense\n")
            assert wait_until(lambda: reader.stats.bad == 1)


def test_tcp_stream_against_simulated_sender_then_hang_up() -> None:
    with SimLineStreamServer(
        lambda: np.array([1.0, 2.0, 3.0]), transport="tcp", rate_hz=200.0, noise_mm=0.01
    ) as sender:
        cfg = TrackerConfig(kind="tcp_stream", host=LOCAL, port=sender.address[1])
        with open_tracker(cfg) as reader:
            assert isinstance(reader, LineStreamTracker)
            assert wait_until(lambda: reader.latest().seq >= 10)
            np.testing.assert_allclose(reader.latest().position_mm, [1.0, 2.0, 3.0], atol=0.1)
            sender.hang_up()  # the sender dies mid-run
            assert wait_until(lambda: reader.failure is not None)
            assert reader.failure.port == f"tcp://127.0.0.1:{sender.address[1]}"
            assert "closed" in str(reader.failure)
            assert reader.latest().stale


def test_tcp_stream_nobody_listening() -> None:
    with socket.socket() as s:
        s.bind((LOCAL, 0))
        port = s.getsockname()[1]  # bound, not listening: connection refused
        with pytest.raises(SensorError, match="cannot connect") as err:
            open_tracker(TrackerConfig(kind="tcp_stream", host=LOCAL, port=port))
        assert err.value.port == f"tcp://127.0.0.1:{port}"


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.binary(max_size=400).filter(lambda b: b"," not in b))
def test_property_stream_bytes_without_commas_never_publish(data: bytes) -> None:
    reader = tcp_reader(FakeClock())
    reader.handle_bytes(data + b"\n")
    assert reader.latest().seq == 0
    reader.close()


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.lists(st.binary(max_size=120), max_size=6))
def test_property_random_stream_never_crashes(chunks: list[bytes]) -> None:
    reader = tcp_reader(FakeClock())
    for c in chunks:
        reader.handle_bytes(c)
    s = reader.latest()
    assert s.seq == reader.stats.samples
    assert s.seq == 0 or np.all(np.isfinite(s.position_mm))
    reader.close()
    for line in b"".join(chunks).split(b"\n"):
        p = parse_stream_line(line)
        assert p is None or all(math.isfinite(v) for v in (p.t_s, *p.position))


def test_simulated_tracker_from_the_rig_and_simulator_configs() -> None:
    """The simulator's tracker offset shows up as a tip error the controller cannot see."""
    rig = TrackerConfig(
        host=LOCAL,
        base_from_tracker=RigidTransformConfig(rotvec_rad=[0, 0, 0.3], translation_mm=[0, 0, 50]),
        marker_to_tip=RigidTransformConfig(translation_mm=[0, 0, 20]),
    )
    sim = SimConfig(
        rig="rig.yaml",
        effects=TruthEffects(tracker_offset=RigidTransformConfig(translation_mm=[5, 0, 0])),
        tracker=TrackerSimConfig(rate_hz=200.0),
    )
    tip = np.array([10.0, -20.0, 90.0])
    # Port 0 (ephemeral) is not a valid rig config value: the copy skips validation on purpose.
    server = sim_tracker_from_config(lambda: tip, rig.model_copy(update={"command_port": 0}), sim)
    assert isinstance(server, SimNatNetServer)
    with server:
        cfg = rig.model_copy(update={"command_port": server.command_address[1]})
        with open_tracker(cfg) as tr:
            assert wait_until(lambda: tr.latest().seq > 0)
            np.testing.assert_allclose(tr.latest().position_mm, tip - [5.0, 0.0, 0.0], atol=1e-3)
