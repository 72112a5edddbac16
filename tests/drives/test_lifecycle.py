"""The group as a resource: its exit makes the drives safe even when start-up failed half way;
the bus budget is checked before anything is sent; raw traffic goes to a python-can log file;
halt and resume; homing and profile moves confirmed by the statusword."""

from __future__ import annotations

import can
import pytest
from drivesim import Cycler, bus_cfg, channel, collect, drive_cfgs, frames_of, make_rig, wait_until

from cdcr_ctl.drives.cia402 import Mode, State
from cdcr_ctl.drives.group import DriveGroup, open_drive_group, sdo_controlword_request
from cdcr_ctl.errors import ConfigError, DriveFault, RigTimeoutError
from cdcr_ctl.sim.epos.plant import MotorParams
from cdcr_ctl.sim.epos.rig import SimDriveBus


def test_exit_quick_stops_and_disables_enabled_drives(rig):
    g = rig.group
    with Cycler(g):
        g.enable()
        collect(rig.spy, 0.01)
    g.close()
    msgs = collect(rig.spy, 0.05)
    for n in (1, 2, 3):
        cws = frames_of(msgs, 0x300 + n)
        assert cws[:1] == [b"\x02\x00"] and cws[-1] == b"\x00\x00"  # quick stop ... disable
        # heartbeat consumer disarmed (0x1016:1 = 0): a clean exit leaves no 0x8130 behind
        assert bytes.fromhex("23 16 10 01 00 00 00 00") in frames_of(msgs, 0x600 + n)
    assert all(n.state is State.SWITCH_ON_DISABLED for n in rig.sim.nodes)
    assert all(n.node.nmt.state == "PRE-OPERATIONAL" for n in rig.sim.nodes)
    g.send_cycle([0, 0, 0])  # after close: a no-op, not an error


def test_exit_after_start_up_failed_half_way_disables_what_booted():
    """Node 3 is missing: boot fails; node 2 was left enabled by a previous session. Leaving the
    context disables nodes 1 and 2 by SDO (no PDO runs before configuration)."""
    ch = channel()
    drives = drive_cfgs(3)
    sim = SimDriveBus(drives[:2], "virtual", ch).start()
    sim.node(2).force_state(State.OPERATION_ENABLED, mode=int(Mode.CYCLIC_SYNC_POSITION))
    spy = can.Bus(interface="virtual", channel=ch)
    try:
        with pytest.raises(RigTimeoutError, match=r"node\(s\) 3: no boot-up"):  # noqa: SIM117
            with DriveGroup(can.Bus(interface="virtual", channel=ch), bus_cfg(ch), drives) as g:
                g.boot(timeout_s=0.2)
        msgs = collect(spy, 0.05)
        for n in (1, 2):
            assert sdo_controlword_request(0) in frames_of(msgs, 0x600 + n)
        assert frames_of(msgs, 0x603) == []  # nothing to a node that never answered
        assert sim.node(2).state is State.SWITCH_ON_DISABLED
    finally:
        spy.shutdown()
        sim.stop()


def test_open_drive_group_closes_on_failure_and_bus_budget_is_checked_first():
    ch = channel()
    with pytest.raises(RigTimeoutError):  # no drives at all on this channel
        open_drive_group(bus_cfg(ch, feedback_timeout_s=None), drive_cfgs(1), boot_timeout_s=0.1)
    bus = can.Bus(interface="virtual", channel=ch)
    with pytest.raises(ConfigError, match="over the 70 %"):
        DriveGroup(bus, bus_cfg(ch, sync_period_s=0.001), drive_cfgs(4))
    with pytest.raises(can.CanOperationError):
        bus.send(can.Message(arbitration_id=1))  # the group shut the bus it refused


def test_traffic_log_is_a_python_can_asc_file(rig, tmp_path):
    g = rig.group
    path = tmp_path / "run" / "can.asc"
    g.log_traffic(path)
    with Cycler(g) as cyc:
        g.enable()
        assert wait_until(lambda: cyc.cycles > 10)
    g.log_traffic(None)
    msgs = list(can.ASCReader(str(path)))
    tx = [m for m in msgs if not m.is_rx]
    rx = [m for m in msgs if m.is_rx]
    assert {0x080, 0x201, 0x301} <= {m.arbitration_id for m in tx}
    assert {0x181, 0x182, 0x183} <= {m.arbitration_id for m in rx}
    assert [bytes(m.data) for m in tx if m.arbitration_id == 0x301][:3] == [
        b"\x06\x00",
        b"\x07\x00",
        b"\x0f\x00",
    ]


def test_frame_ring_dump_names_frames():
    r = make_rig(drive_cfgs(1))
    try:
        dump = r.group.frame_dump().splitlines()
        assert any(" tx 000 [2] 82 01" in line for line in dump)  # NMT reset of node 1
        assert any(" rx 701 [1] 00" in line for line in dump)  # its boot-up
    finally:
        r.close()


def test_halt_holds_and_resume_follows(rig):
    g = rig.group
    with Cycler(g) as cyc:
        g.enable()
        g.halt_all()
        cyc.targets = [5000, 5000, 5000]
        assert wait_until(lambda: cyc.cycles > 30)
        assert rig.sim.actual_positions() == [0, 0, 0]  # halted: targets ignored
        g.resume_all()
        assert wait_until(lambda: rig.sim.actual_positions() == [5000, 5000, 5000])


def test_homing_by_current_threshold_against_a_hard_stop():
    """Method -3: run + until the current passes 0x30B2, back off 0x30B1, call it 0x30B0."""
    ch = channel()
    drives = [
        d.model_copy(
            update={
                "homing": d.homing.model_copy(
                    update={
                        "method": -3,
                        "current_threshold_mA": 600,
                        "speed_rpm": 600,
                        "offset_counts": 1000,
                        "home_position_counts": -250,
                    }
                )
            }
        )
        for d in drive_cfgs(2)
    ]
    motors = {
        1: MotorParams(hard_stops_counts=(-1e9, 3000.0)),
        2: MotorParams(hard_stops_counts=(-1e9, 8000.0)),
    }
    sim = SimDriveBus(drives, "virtual", ch, motors=motors).start()
    g = DriveGroup(can.Bus(interface="virtual", channel=ch), bus_cfg(ch), drives)
    try:
        g.boot()
        g.configure()
        home = g.home()  # the group clocks SYNC itself: no loop runs
        assert home == [-250, -250]
        # backed off 1000 counts from where the current passed 0.6 A, pressing on the stop
        for n, stop in zip(sim.nodes, (3000.0, 8000.0), strict=True):
            assert stop - 1000 - 5 < n.motor.x < stop - 1000 + 5
            assert n.mode == Mode.CYCLIC_SYNC_POSITION  # back in the configured mode
            assert n.statusword & 0x8000  # EPOS4: position referenced
        # left disabled, as it was found
        assert wait_until(lambda: all(n.state is State.SWITCH_ON_DISABLED for n in sim.nodes))
    finally:
        g.close()
        sim.stop()


def test_homing_without_a_stop_times_out_naming_the_drive():
    r = make_rig(drive_cfgs(1, homing={"method": -4, "speed_rpm": 100}))
    try:
        with pytest.raises(RigTimeoutError, match="node 1: homing not confirmed"):
            r.group.home(timeout_s=0.2)
    finally:
        r.close()


def test_homing_method_the_simulator_lacks_reports_homing_error():
    r = make_rig(drive_cfgs(1, homing={"method": 17}))
    try:
        with pytest.raises(DriveFault, match="homing error"):
            r.group.home(timeout_s=1.0)
    finally:
        r.close()
