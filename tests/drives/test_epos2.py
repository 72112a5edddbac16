"""EPOS2 (no CSP): profile position (blocking moves and a streamed set-point), interpolated
position through the PVT buffer 0x20C1, maxon position mode 0x2062, and its own homing objects
(0x2080 threshold, 0x2081 home position) -- against simulated EPOS2 nodes, bytes checked."""

from __future__ import annotations

import struct

import pytest
from drivesim import Cycler, collect, drive_cfgs, frames_of, make_rig, wait_until

from cdcr_ctl.drives.cia402 import SW_IP_ACTIVE, State
from cdcr_ctl.drives.epos import pvt_payload


def test_profile_position_move_to_with_set_point_handshake():
    r = make_rig(drive_cfgs(3, "epos2", "pp"), sync_period_s=0.005, feedback_timeout_s=0.5)
    g = r.group
    try:
        g.enable()
        collect(r.spy, 0.01)
        final = g.move_to([4000, -2000, 1000], timeout_s=5.0)
        msgs = collect(r.spy, 0.02)
        assert all(abs(a - b) <= 4 for a, b in zip(final, [4000, -2000, 1000], strict=True))
        assert all(n.kind == "epos2" and n.mode == 1 for n in r.sim.nodes)
        # target 4000 with controlword 0x3F (new set-point, change immediately), then bit 4 off
        assert frames_of(msgs, 0x201)[:2] == [
            bytes.fromhex("a00f0000 3f00"),
            bytes.fromhex("a00f0000 0f00"),
        ]
        assert g.first_fault() is None
    finally:
        r.close()


def test_profile_position_streamed_from_the_cycle():
    r = make_rig(drive_cfgs(2, "epos2", "pp"), sync_period_s=0.005, feedback_timeout_s=0.5)
    g = r.group
    try:
        with Cycler(g) as cyc:
            g.enable()
            for k in range(1, 11):
                cyc.targets = [300 * k, -300 * k]
                start = cyc.cycles
                wait_until(lambda start=start: cyc.cycles > start + 2)
            assert wait_until(
                lambda: all(
                    abs(p - t) <= 4
                    for p, t in zip(r.sim.actual_positions(), [3000, -3000], strict=True)
                )
            )
        assert g.first_fault() is None
    finally:
        r.close()


def test_interpolated_position_streams_pvt_records_then_underflow_faults():
    r = make_rig(drive_cfgs(2, "epos2", "ip"), sync_period_s=0.005, feedback_timeout_s=0.5)
    g = r.group
    try:
        with Cycler(g, targets=lambda k: [0, 0]) as hold:
            g.enable()
            assert wait_until(lambda: hold.cycles > 10)
        assert all(n.pvt.active for n in r.sim.nodes)
        assert g.feedback()[0].statusword & SW_IP_ACTIVE
        collect(r.spy, 0.01)
        with Cycler(g, targets=lambda k: [100 * k, -50 * k]) as cyc:
            assert wait_until(lambda: cyc.cycles > 100)
        msgs = collect(r.spy, 0.05)
        records = frames_of(msgs, 0x201)
        # 100 counts per 5 ms = 20 000 counts/s = 586 rpm at 2048 counts/rev; 5 ms apart
        assert pvt_payload(500, 586, 5) in records
        assert struct.unpack("<i", records[-1][:4])[0] == 100 * (cyc.cycles - 1)
        last = [100 * (cyc.cycles - 1), -50 * (cyc.cycles - 1)]
        # the drives are 3 points (the prefill) behind the stream; the SYNCs of a hold catch up
        with Cycler(g, targets=lambda k: last):
            assert wait_until(
                lambda: all(
                    abs(p - t) <= 2 for p, t in zip(r.sim.actual_positions(), last, strict=True)
                )
            )
        assert g.first_fault() is None
        for _ in range(10):  # SYNC with no new PVT record: the buffer runs empty
            g.send_sync()
        assert wait_until(lambda: g.fault() is not None)
        f = g.fault()
        assert f.code == 0xFF0C and "interpolated position mode error" in f.text
    finally:
        r.close()


def test_epos2_position_mode_follows_set_points():
    r = make_rig(drive_cfgs(1, "epos2", "pm"), sync_period_s=0.005, feedback_timeout_s=0.5)
    g = r.group
    try:
        with Cycler(g) as cyc:
            g.enable()
            cyc.targets = [1500]
            assert wait_until(lambda: r.sim.actual_positions() == [1500])
            msgs = collect(r.spy, 0.02)
        assert bytes.fromhex("dc050000") in frames_of(msgs, 0x201)  # 0x2062 set-point, int32
        assert r.sim.node(1).mode == -1
    finally:
        r.close()


def test_epos2_homing_uses_its_own_objects():
    drives = drive_cfgs(1, "epos2", "pp", homing={"method": 37, "home_position_counts": -100})
    r = make_rig(drives, sync_period_s=0.005, feedback_timeout_s=0.5)
    try:
        collect(r.spy, 0.01)
        assert r.group.home() == [-100]
        msgs = collect(r.spy, 0.02)
        sdo = frames_of(msgs, 0x601)
        assert bytes.fromhex("23 81 20 00 9c ff ff ff") in sdo  # 0x2081 home position
        assert bytes.fromhex("23 7c 60 00 00 00 00 00") in sdo  # 0x607C home offset
        assert not [f for f in sdo if f[1:3] == bytes.fromhex("b230")]  # no EPOS4 0x30B2
        assert wait_until(lambda: r.sim.node(1).state is State.SWITCH_ON_DISABLED)
    finally:
        r.close()


def test_epos2_refuses_csp():
    import canopen
    from canopen.sdo.exceptions import SdoAbortedError
    from drivesim import channel

    from cdcr_ctl.sim.epos.rig import SimDriveBus

    ch = channel()
    sim = SimDriveBus([(1, "epos2")], "virtual", ch).start()
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="virtual", channel=ch)
    try:
        with pytest.raises(SdoAbortedError) as exc:
            net.add_node(1, canopen.ObjectDictionary()).sdo.download(0x6060, 0, b"\x08")
        assert exc.value.code == 0x06090030  # value range: mode 8 (CSP) does not exist
    finally:
        net.disconnect()
        sim.stop()
