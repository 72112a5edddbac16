"""Faults become a quick stop of every drive within 2 SYNC periods and an error naming node and
code: a drive that stops its heartbeat, an EMCY (0x8611, 0x2310), a drive or a whole bus that
stops answering, a drive restarting, a FAULT statusword whose EMCY got lost. Also: the drives'
own heartbeat consumer when the master dies, and fault reset with confirmation."""

from __future__ import annotations

import struct

import pytest
from drivesim import Cycler, collect, drive_cfgs, frames_of, make_rig, wait_until

from cdcr_ctl.drives.cia402 import State
from cdcr_ctl.errors import CommError, DriveFault

QUICK_STOP = struct.pack("<H", 0x0002)


def inject_heartbeat(sim):
    sim.node(1).stop_heartbeat()


def inject_following_error(sim):
    sim.node(2).inject_following_error()


def inject_over_current(sim):
    sim.node(3).inject_over_current()


def inject_silent_drive(sim):
    sim.node(2).go_silent()


def inject_silent_bus(sim):
    sim.unplug()  # on the virtual bus: every drive stops answering


def inject_lost_emcy(sim):
    sim.node(3).emcy_enabled = False
    sim.node(3).inject_fault(0x3210)


def inject_restart(sim):
    sim.node(2).power_cycle()  # boot-up message, defaults, SWITCH ON DISABLED


def inject_pre_operational(sim):
    """Someone knocks node 2 to PRE-OPERATIONAL while it is enabled: PDOs no longer reach it,
    so its quick stop must go by SDO."""
    import can

    with can.Bus(interface="virtual", channel=sim.channel_path) as other:
        other.send(can.Message(arbitration_id=0x000, data=[0x80, 2], is_extended_id=False))


CASES = [
    (inject_heartbeat, "heartbeat:node1", 1, 0, "heartbeat lost"),
    (inject_following_error, "emcy:node2:0x8611", 2, 0x8611, "EMCY 0x8611 following error"),
    (inject_over_current, "emcy:node3:0x2310", 3, 0x2310, "EMCY 0x2310 over-current"),
    (inject_silent_drive, "no_feedback:node2", 2, 0, "not answering"),
    (inject_silent_bus, "no_feedback:all", 0, 0, "bus not answering"),
    (inject_lost_emcy, "fault:node3", 3, 0, "reports FAULT (no EMCY seen)"),
    (inject_restart, "nmt:node2", 2, 0, "the drive restarted"),
    (inject_pre_operational, "nmt:node2", 2, 0, "NMT state changed to PRE-OPERATIONAL"),
]


@pytest.mark.parametrize(
    ("inject", "cause", "node", "code", "text"),
    CASES,
    ids=[c[1].split(":")[0] + "-" + c[0].__name__.removeprefix("inject_") for c in CASES],
)
def test_fault_quick_stops_every_drive_within_two_sync_periods(inject, cause, node, code, text):
    if cause.startswith("no_feedback"):
        # A silent drive also stops its heartbeat: make the missing TPDOs the first sign.
        r = make_rig(drive_cfgs(3, heartbeat_producer_ms=1000), feedback_timeout_s=0.25)
    else:
        r = make_rig()
    g = r.group
    try:
        with Cycler(g):
            g.enable()
            collect(r.spy, 0.02)
            inject(r.sim)
            assert wait_until(lambda: g.fault() is not None)
            assert wait_until(lambda: g.quick_stop_at_sync is not None)
            msgs = collect(r.spy, 0.1)
        f = g.fault()
        assert (f.cause, f.node, f.code) == (cause, node, code)
        assert f.text.startswith(f"node {node}: " if node else "CAN virtual:") and text in f.text
        assert g.first_fault() == (cause, f.text)
        # The quick stop went out to every drive within 2 SYNC periods of the fault...
        assert g.quick_stop_at_sync - g.fault_at_sync <= 2
        for n in (1, 2, 3):
            assert QUICK_STOP in frames_of(msgs, 0x300 + n)
        # ...and every drive still answering left OPERATION ENABLED.
        answering = [n for n in r.sim.nodes if not n.silent]
        assert wait_until(lambda: all(n.state is not State.OPERATION_ENABLED for n in answering))
        with pytest.raises(DriveFault if node else CommError) as exc:
            g.raise_if_faulted()
        if node:
            assert exc.value.node == node and exc.value.code == code
        assert any("last CAN frames" in note for note in exc.value.__notes__)
    finally:
        r.close()


def test_emcy_on_the_wire_then_quick_stop_frames_in_the_same_cycle(rig):
    """On the wire: the EMCY frame, then quick stops to all three drives; the group sent them
    in the SYNC period in which it received the EMCY (how many SYNC periods the EMCY waits in
    the receive queue depends on the machine's load: benchmarks/bench_csp.py measures it)."""
    g = rig.group
    with Cycler(g):
        g.enable()
        collect(rig.spy, 0.02)
        rig.sim.node(2).inject_following_error()
        assert wait_until(lambda: g.quick_stop_at_sync is not None)
        msgs = collect(rig.spy, 0.05)
    ids = [m.arbitration_id for m in msgs]
    emcy = ids.index(0x082)
    assert bytes(msgs[emcy].data) == bytes.fromhex("1186 11 0000000000")  # 0x8611, register 0x11
    for n in (1, 2, 3):
        stops = [
            i
            for i, m in enumerate(msgs)
            if m.arbitration_id == 0x300 + n and bytes(m.data) == QUICK_STOP
        ]
        assert stops and stops[0] > emcy
    assert g.quick_stop_at_sync - g.fault_at_sync <= 1


def test_master_death_faults_the_drives_by_their_heartbeat_consumer(rig):
    g = rig.group
    with Cycler(g):
        g.enable()
    g.stop_heartbeat()  # the master dies: no SYNC, no heartbeat
    assert wait_until(lambda: all(n.state is State.FAULT for n in rig.sim.nodes), 3.0)
    assert all(0x8130 in n.emcy_sent for n in rig.sim.nodes)
    assert wait_until(lambda: g.fault() is not None)  # the drives' EMCY reached the master
    assert g.fault().code == 0x8130 and "CAN heartbeat error" in g.fault().text


def test_fault_reset_is_confirmed_then_enable_works_again(rig):
    g = rig.group
    with Cycler(g):
        g.enable()
        rig.sim.node(3).inject_over_current()
        assert wait_until(lambda: g.feedback()[2].state is State.FAULT)
        with pytest.raises(DriveFault, match="reset_faults"):
            g.enable()  # refused while a fault is latched
        g.reset_faults()
        assert g.first_fault() is None and g.quick_stop_at_sync is None
        assert wait_until(
            lambda: all(f.state is not State.FAULT and f.fault == "" for f in g.feedback())
        )
        assert rig.sim.node(3).emcy_sent[-1] == 0x0000  # the drive's error reset EMCY
        g.enable()
        assert all(n.state is State.OPERATION_ENABLED for n in rig.sim.nodes)


def test_fault_reset_refused_while_a_drive_is_silent_or_without_heartbeat(rig):
    g = rig.group
    with Cycler(g):
        g.enable()
        rig.sim.node(2).go_silent()
        assert wait_until(lambda: g.fault() is not None)
        assert wait_until(lambda: g.sync_count - g._by_node[2].tpdo_sync > 3)
        with pytest.raises(DriveFault, match=r"not answering|no heartbeat") as exc:
            g.reset_faults()
        assert exc.value.node == 2
        assert g.fault().node == 2  # still latched
    r = make_rig()
    try:
        with Cycler(r.group):
            r.group.enable()
            r.sim.node(1).stop_heartbeat()
            assert wait_until(lambda: r.group.fault() is not None)
            with pytest.raises(DriveFault, match="no heartbeat") as exc:
                r.group.reset_faults()
            assert exc.value.node == 1
    finally:
        r.close()


def test_fault_reset_not_confirmed_names_the_drive():
    """A drive that stays in FAULT (its fault persists): the reset times out naming it."""
    r = make_rig()
    try:
        with Cycler(r.group):
            r.group.enable()
            sim3 = r.sim.node(3)
            sim3.inject_over_current()
            assert wait_until(lambda: r.group.feedback()[2].state is State.FAULT)
            original = sim3._controlword
            sim3._controlword = lambda cw: None  # this drive ignores the reset
            try:
                with pytest.raises(DriveFault, match="fault reset not confirmed") as exc:
                    r.group.reset_faults(timeout_s=0.1)
            finally:
                sim3._controlword = original
        assert exc.value.node == 3 and exc.value.code == 0x2310
    finally:
        r.close()


def test_silence_counts_from_the_first_sync_after_a_pause():
    """A cycle that starts long after configure() (the daemon builds its model meanwhile) must
    not find the drives "not answering" before their first TPDO could come back: with no SYNC
    for longer than the feedback timeout, a drive's silence counts from the next SYNC. (Over
    slcan to another process at 1 kHz the first TPDOs take a few ms: enabling failed.)"""
    import time

    r = make_rig(drive_cfgs(3, heartbeat_producer_ms=1000), feedback_timeout_s=0.1)
    g = r.group
    try:
        time.sleep(0.15)  # no SYNC for longer than the feedback timeout
        r.sim.node(2).go_silent()  # stands in for a TPDO that is still on its way
        first = time.monotonic()
        for _ in range(8):  # more than TPDO_MISSES SYNCs, well within the timeout
            g.send_sync()
            time.sleep(0.002)
        assert g.fault() is None
        # Silence beyond TPDO_MISSES SYNCs and the feedback timeout is a fault, as before.
        while g.fault() is None and time.monotonic() - first < 2.0:
            g.send_sync()
            time.sleep(0.002)
        f = g.fault()
        assert f is not None and f.cause == "no_feedback:node2"
        assert f.t_s - first >= 0.1
    finally:
        r.close()
