"""The simulated EPOS itself: supervision that comes from its physics (following error under load,
limits, limit switches), quick stop option codes, the SDO aborts a real drive gives, NMT reset
communication back to factory defaults."""

from __future__ import annotations

import struct

import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from drivesim import Cycler, channel, drive_cfgs, make_rig, wait_until

from cdcr_ctl.drives.cia402 import State
from cdcr_ctl.sim.epos.plant import MotorParams
from cdcr_ctl.sim.epos.rig import SimDriveBus


def test_following_error_from_a_load_the_motor_cannot_hold():
    """1 N·m at the gearbox output against at most 2 A x 10.6 mN·m x 19 = 0.40 N·m: the motor
    is pushed back until the error passes the 0x6065 window for 0x6066 ms -> EMCY 0x8611."""
    r = make_rig(drive_cfgs(1, following_error_window_counts=5000))
    g = r.group
    try:
        with Cycler(g):
            g.enable()
            r.sim.node(1).load_torque_Nm = -1.0
            assert wait_until(lambda: g.fault() is not None)
        assert g.fault().cause == "emcy:node1:0x8611"
        n = r.sim.node(1)
        assert n.state is State.FAULT and n.position_counts < -5000
        assert n.current_A == 0.0  # the fault reaction switched the power stage off
        assert abs(n.error_code) == 0x8611
    finally:
        r.close()


def test_load_within_the_current_limit_is_held():
    r = make_rig(drive_cfgs(1))
    g = r.group
    try:
        with Cycler(g) as cyc:
            g.enable()
            r.sim.node(1).load_torque_Nm = -0.2  # 0.2/19 = 10.5 mN·m: about 1 A
            assert wait_until(lambda: cyc.cycles > 200)
            n = r.sim.node(1)
            assert abs(n.position_counts) <= 1  # the integral action holds position
            assert n.current_A == pytest.approx(0.2 / 19 / 0.0106, rel=0.02)
        assert g.fault() is None
    finally:
        r.close()


def test_target_beyond_software_limit_faults():
    r = make_rig(drive_cfgs(1, software_limits_counts=[-10_000, 10_000]))
    g = r.group
    try:
        with Cycler(g) as cyc:
            g.enable()
            cyc.targets = [10_001]
            assert wait_until(lambda: g.fault() is not None)
        assert g.fault().cause == "emcy:node1:0x8A82"
        assert "software position limit" in g.fault().text
    finally:
        r.close()


def test_limit_switch_faults_when_the_motor_reaches_it():
    from cdcr_ctl.sim.epos.node import SimEpos

    # the node alone, stepped by hand (no bus: its EMCY is recorded, not sent)
    n = SimEpos(canopen.Network(), 1, "epos4", MotorParams(limit_switches_counts=(-1e9, 4000.0)))
    n.advance_on_sync = False
    n.force_state(State.OPERATION_ENABLED, mode=8)
    for k in range(1, 200):
        n._target(min(50 * k, 6000))
        n.step(0.001)
        if n.state is State.FAULT:
            break
    assert n.state is State.FAULT and n.emcy_sent == [0x8A81]
    assert 4000 <= n.motor.x < 4100


@pytest.mark.parametrize(("option", "holds"), [(2, False), (6, True)])
def test_quick_stop_option_code(option, holds):
    """Under a load: option 6 stops and holds powered (QUICK STOP ACTIVE); option 2 stops, then
    the power stage goes off (SWITCH ON DISABLED) and the load turns the motor."""
    r = make_rig(drive_cfgs(1, quick_stop_option_code=option))
    g = r.group
    n = r.sim.node(1)
    try:
        with Cycler(g) as cyc:
            g.enable()
            n.load_torque_Nm = 0.1
            cyc.targets = [3000]
            assert wait_until(lambda: abs(n.position_counts - 3000) <= 1)
            g.quick_stop_all()
            final = State.QUICK_STOP_ACTIVE if holds else State.SWITCH_ON_DISABLED
            assert wait_until(lambda: n.state is final)
            start = cyc.cycles
            assert wait_until(lambda: cyc.cycles > start + 50)
        if holds:
            assert abs(n.position_counts - 3000) <= 2
        else:
            assert n.position_counts > 3100
    finally:
        r.close()


@pytest.fixture
def remote():
    """A stock canopen RemoteNode (no OD: raw bytes) on a channel with one simulated EPOS4."""
    ch = channel()
    sim = SimDriveBus([(1, "epos4")], "virtual", ch).start()
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="virtual", channel=ch)
    node = net.add_node(1, canopen.ObjectDictionary())
    yield sim, node
    net.disconnect()
    sim.stop()


def abort_code(fn) -> int:
    with pytest.raises(SdoAbortedError) as exc:
        fn()
    return exc.value.code


def test_sdo_aborts_a_real_drive_gives(remote):
    _sim, node = remote
    sdo = node.sdo
    # remapping a valid PDO: general parameter incompatibility
    assert abort_code(lambda: sdo.download(0x1600, 1, struct.pack("<I", 0x607A0020))) == (
        0x06040043
    )
    sdo.download(0x1400, 1, struct.pack("<I", 0x80000201))  # switch RPDO1 off first
    # 0x6065 is not mappable; 0x607A with the wrong length
    assert abort_code(lambda: sdo.download(0x1600, 1, struct.pack("<I", 0x60650020))) == (
        0x06040041
    )
    assert abort_code(lambda: sdo.download(0x1600, 1, struct.pack("<I", 0x607A0010))) == (
        0x06040041
    )
    # 0x6064 is read-only: not mappable into an RPDO
    assert abort_code(lambda: sdo.download(0x1600, 2, struct.pack("<I", 0x60640020))) == (
        0x06040041
    )
    for sub, entry in ((1, 0x607A0020), (2, 0x607A0020), (3, 0x60400010)):
        sdo.download(0x1600, sub, struct.pack("<I", entry))
    assert abort_code(lambda: sdo.download(0x1600, 0, b"\x03")) == 0x06040042  # 80 bits > 64
    assert abort_code(lambda: sdo.download(0x6060, 0, b"\x07")) == 0x06090030  # EPOS4: no IP
    assert abort_code(lambda: sdo.download(0x6041, 0, b"\x00\x00")) == 0x06010002  # read only
    assert abort_code(lambda: sdo.download(0x60C2, 2, b"\xfc")) == 0x06010002  # index fixed
    assert abort_code(lambda: sdo.upload(0x2062, 0)) == 0x06020000  # an EPOS2 object


def test_nmt_reset_communication_restores_factory_pdos(remote):
    sim, node = remote
    sdo = node.sdo
    sdo.download(0x1801, 1, struct.pack("<I", 0x80000281))  # TPDO2 off
    sdo.download(0x1017, 0, struct.pack("<H", 20))  # heartbeat on
    assert sdo.upload(0x1801, 1) == struct.pack("<I", 0x80000281)
    node.nmt.send_command(0x82)
    assert wait_until(lambda: sim.node(1).node.nmt.state == "PRE-OPERATIONAL")
    assert sdo.upload(0x1801, 1) == struct.pack("<I", 0x281)  # factory: TPDO2 on
    assert sdo.upload(0x1017, 0) == b"\x00\x00"
    assert sdo.upload(0x1018, 1) == struct.pack("<I", 0xFB)


def test_free_running_drive_serves_an_sdo_only_master():
    """No SYNC at all: with free_run the simulated drive advances on the wall clock, so a plain
    CiA 402 master that only uses SDO (mode, controlwords, target, 0x6064) sees a profile move
    finish."""
    ch = channel()
    sim = SimDriveBus([(1, "epos4")], "virtual", ch, free_run=True).start()
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="virtual", channel=ch)
    try:
        sdo = net.add_node(1, canopen.ObjectDictionary()).sdo
        sdo.download(0x6060, 0, b"\x01")  # profile position
        for cw in (0x06, 0x07, 0x0F):
            sdo.download(0x6040, 0, struct.pack("<H", cw))
        assert struct.unpack("<H", sdo.upload(0x6041, 0))[0] & 0x6F == 0x27  # enabled
        sdo.download(0x607A, 0, struct.pack("<i", 5000))
        sdo.download(0x6040, 0, struct.pack("<H", 0x3F))  # new set-point, change immediately
        sdo.download(0x6040, 0, struct.pack("<H", 0x0F))

        def statusword() -> int:
            return struct.unpack("<H", sdo.upload(0x6041, 0))[0]

        assert wait_until(lambda: statusword() & 0x0400)  # target reached
        assert abs(struct.unpack("<i", sdo.upload(0x6064, 0))[0] - 5000) <= 4
        assert sim.node(1).sync_count == 0
    finally:
        net.disconnect()
        sim.stop()
