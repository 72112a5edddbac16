"""Frames in flight around an NMT command (CiA 301): a heartbeat a node's CAN controller queued
before it processed ``NMT start`` leaves after it and reports PRE-OPERATIONAL. Within one producer
period, before the node has reported OPERATIONAL, that is not a fault; once the node was
OPERATIONAL, a PRE-OPERATIONAL report is (``enable`` refuses, naming the node)."""

from __future__ import annotations

import threading

import can
import pytest
from drivesim import Cycler, make_rig, wait_until

from cdcr_ctl.drives.heartbeat import (
    NMT_BOOTUP,
    NMT_OPERATIONAL,
    NMT_PRE_OPERATIONAL,
    HeartbeatConsumer,
)
from cdcr_ctl.errors import DriveFault

NMT_START = 0x01


#: When the stale report leaves after the ``NMT start`` (s): after the master armed its heartbeat
#: consumer, before the node's first heartbeat from OPERATIONAL (its producer time is 50 ms).
STALE_AFTER_S = 0.002


class StaleHeartbeat(can.Listener):
    """Node ``node`` of ``sim`` as the EPOS4 emulator behaved: its heartbeat producer (0x1017,
    written during configuration) holds its first report until the ``NMT start``; then, as
    :data:`STALE_AFTER_S` later, that report leaves, PRE-OPERATIONAL (queued before the node acted
    on the command), and the node's own OPERATIONAL heartbeats follow. Its only report since the
    boot-up is the stale one. A second station on the channel sends it."""

    def __init__(self, sim, node: int) -> None:
        self.node = node
        self.armed = threading.Event()
        nmt = sim.node(node).node.nmt
        self._start_heartbeat = nmt.start_heartbeat
        self._period_ms = 0
        nmt.start_heartbeat = self._hold  # the producer starts at the NMT start
        channel = sim.channel_path
        self.sent = threading.Event()
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.notifier = can.Notifier(self.bus, [self])

    def on_message_received(self, msg: can.Message) -> None:
        data = bytes(msg.data)
        start = msg.arbitration_id == 0x000 and len(data) == 2 and data[0] == NMT_START
        if start and data[1] in (0, self.node) and not self.armed.is_set():
            self.armed.set()
            threading.Timer(STALE_AFTER_S, self._send).start()

    def _hold(self, period_ms: int) -> None:
        self._period_ms = period_ms

    def _send(self) -> None:
        msg = can.Message(
            arbitration_id=0x700 + self.node, data=[NMT_PRE_OPERATIONAL], is_extended_id=False
        )
        self.bus.send(msg)
        self.sent.set()
        self._start_heartbeat(self._period_ms)

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


def test_a_stale_pre_operational_heartbeat_after_nmt_start_is_not_a_fault():
    rig = make_rig(start=False)
    try:
        rig.group.boot()
        stale = StaleHeartbeat(rig.sim, 3)
        rig.group.configure()  # NMT start; node 3's stale report arrives after it
        assert stale.sent.wait(1.0)
        with Cycler(rig.group):
            rig.group.enable()
            assert rig.group.first_fault() is None
            # Once node 3 was OPERATIONAL, a PRE-OPERATIONAL report is the fault it always was.
            stale.bus.send(
                can.Message(arbitration_id=0x703, data=[NMT_PRE_OPERATIONAL], is_extended_id=False)
            )
            assert wait_until(lambda: rig.group.first_fault() is not None)
            cause, detail = rig.group.first_fault()
            assert cause == "nmt:node3" and "PRE-OPERATIONAL" in detail, detail
            with pytest.raises(DriveFault, match="node 3"):
                rig.group.enable()
        stale.close()
    finally:
        rig.close()


def test_the_window_after_an_nmt_command_ends_at_the_commanded_state_or_one_period():
    hb = HeartbeatConsumer({1: 0.05, 2: 0.05})
    hb.arm(0.0)
    assert hb.beat(1, NMT_OPERATIONAL, 0.0) is None
    hb.commanded(1, NMT_OPERATIONAL, 1.0)
    hb.commanded(2, NMT_OPERATIONAL, 1.0)
    # Sent before the command: neither a fault nor the node's state.
    assert hb.beat(1, NMT_PRE_OPERATIONAL, 1.0001) is None
    assert hb.beat(2, NMT_BOOTUP, 1.0001) is None and hb.settling(2, 1.0001)
    assert hb.state(1) == NMT_OPERATIONAL
    # Node 1 reports OPERATIONAL: its window ends; leaving OPERATIONAL now is a fault.
    assert hb.beat(1, NMT_OPERATIONAL, 1.01) is None and not hb.settling(1, 1.01)
    assert hb.beat(1, NMT_PRE_OPERATIONAL, 1.02) == "NMT state changed to PRE-OPERATIONAL"
    # Node 2 never did: one period later a PRE-OPERATIONAL report counts.
    assert hb.beat(2, NMT_PRE_OPERATIONAL, 1.06) == "NMT state changed to PRE-OPERATIONAL"
    # A node not watched (producer time 0) has no window.
    hb.commanded(9, NMT_OPERATIONAL, 2.0)
    assert not hb.settling(9, 2.0)


def test_without_the_window_the_stale_heartbeat_would_have_faulted():
    """The same report, with no NMT command before it, is an anomaly: the window is what
    tolerates it, not a consumer that ignores PRE-OPERATIONAL."""
    hb = HeartbeatConsumer({3: 0.05})
    hb.arm(0.0)
    assert hb.beat(3, NMT_OPERATIONAL, 0.01) is None
    assert hb.beat(3, NMT_PRE_OPERATIONAL, 0.0101) == "NMT state changed to PRE-OPERATIONAL"
