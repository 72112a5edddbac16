"""A NatNet client this project did not write reads the simulated tracker.

The stock client is the PyPI package ``natnet`` (0.3.0, MIT, pure Python, its own frame parser):
it sends NAT_CONNECT to the command port, reads NAT_SERVERINFO for the stream version, keeps
alive and decodes NAT_FRAMEOFDATA. In unicast mode it binds its unused data socket to all
interfaces; the test rebinds that to 127.0.0.1 so nothing here listens beyond loopback.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

import numpy as np
import pytest

from cdcr_ctl.sensors.natnet import NatNetVersion
from cdcr_ctl.sensors.tracker import quaternion_from_rotation, rotation_from_rotvec
from cdcr_ctl.sim.tracker import SimNatNetServer

natnet = pytest.importorskip("natnet", reason="stock NatNet client: pip install natnet==0.3.0")

WAIT_S = 5.0


def wait_until(pred: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


@pytest.fixture
def loopback_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make the stock client bind "" (all interfaces) as 127.0.0.1 instead."""
    cls = natnet.NatNetClient
    original = cls._NatNetClient__create_socket

    def create_socket(addr: str = "", port: int = 0) -> socket.socket:
        return original(addr or "127.0.0.1", port)

    monkeypatch.setattr(cls, "_NatNetClient__create_socket", staticmethod(create_socket))


@pytest.mark.usefixtures("loopback_only")
@pytest.mark.parametrize("version", [NatNetVersion(3, 1), NatNetVersion(4, 1)], ids=str)
def test_stock_natnet_client_reads_the_simulated_server(version: NatNetVersion) -> None:
    R = rotation_from_rotvec([0.2, -0.1, 0.7])
    p_mm = np.array([100.0, 200.0, 300.0])
    with SimNatNetServer(
        lambda: (R, p_mm),
        truth_frame="tracker",
        rigid_body_id=5,
        rate_hz=200.0,
        version=version,
        include_markers=True,
    ) as server:
        frames: list = []
        client = natnet.NatNetClient(
            server_ip_address="127.0.0.1",
            local_ip_address="127.0.0.1",
            command_port=server.command_address[1],
            data_port=server.data_address[1],
            use_multicast=False,
        )
        client.on_data_frame_received_event.handlers.append(frames.append)
        try:
            client.connect(timeout=WAIT_S)
            info = client.server_info
            assert info.application_name == "cdcr-ctl sim"
            assert info.nat_net_protocol_version.components == (*version[:2], 0, 0)
            client.run_async()
            assert wait_until(lambda: len(frames) >= 10)
            n = len(frames)
            server.occlude(True)  # fault hook: the stock client must see the body lost

            def lost() -> bool:
                return any(not f.rigid_bodies[0].tracking_valid for f in frames[n:])

            # Frames sampled before the occlusion may still be on their way (latency, a busy
            # machine): wait for the first one that shows the body lost.
            assert wait_until(lost)
        finally:
            client.shutdown()

    good = frames[5]
    (body,) = good.rigid_bodies
    assert body.id_num == 5 and body.tracking_valid is True
    np.testing.assert_allclose(body.pos, p_mm / 1000.0, rtol=1e-6)
    q = np.asarray(body.rot)
    assert abs(abs(float(q @ quaternion_from_rotation(R))) - 1.0) < 1e-6
    assert [m.model_name for m in good.marker_sets] == ["tip", "all"]
    assert len(good.labeled_markers) == 3
    numbers = [f.prefix.frame_number for f in frames]
    assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
    valid = [f.rigid_bodies[0].tracking_valid for f in frames]
    first_lost = valid.index(False)
    assert first_lost >= n and not any(valid[first_lost:])
