"""The sequences' waits on the drives' time: a group whose drives live on a clock of their own
(``watch_clock``, here advanced one SYNC period by each SYNC the group clocks while idle)
measures each 402 step's timeout on that clock. A starved
host, on which much wall time passes per SYNC, delays an enable but cannot fail it; a drive
that never answers still times out after the same time of its own; a clock that never advances
is ended by the wall-clock backstop, which names itself.

The host's starvation is a fake wall clock (the group's ``clock``) that advances a fixed amount
with every SYNC the group clocks, so the counts below follow from the SYNCs, not from how busy
this machine is. The simulated drives are real CANopen nodes on a virtual bus; a node "answers
late" because its controlwords are held on the wire for N SYNCs (:class:`HoldingBus`).
"""

from __future__ import annotations

import can
import pytest
from drivesim import bus_cfg, channel, drive_cfgs, wait_until

from cdcr_ctl.drives.cia402 import MODE_BY_NAME, State
from cdcr_ctl.drives.epos import pdo_layout
from cdcr_ctl.drives.group import STATE_STEP_TIMEOUT_S, DriveGroup
from cdcr_ctl.drives.group.common import WALL_BACKSTOP_FACTOR
from cdcr_ctl.errors import RigTimeoutError
from cdcr_ctl.sim.epos.rig import SimDriveBus

PERIOD_S = 0.002
#: The RPDO each node's controlword rides in (CSP layout), by node id.
CW_COB_ID = {n: pdo_layout(n, MODE_BY_NAME["csp"]).controlword.cob_id for n in (1, 2, 3)}


class HoldingBus(can.BusABC):
    """The group's side of a virtual channel that holds the frames with a COB-ID of ``cob_ids``
    for ``hold_syncs`` SYNCs (None: for ever) before they go on the wire: nodes that take N SYNC
    periods to answer a controlword."""

    def __init__(
        self, ch: str, cob_ids: set[int], hold_syncs: int | None, on_sync=lambda: None
    ) -> None:
        self._inner = can.Bus(interface="virtual", channel=ch)
        self.cob_ids, self.hold_syncs, self.on_sync = cob_ids, hold_syncs, on_sync
        self._held: list[tuple[int, can.Message]] = []
        self.syncs = 0
        super().__init__(channel=ch)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == 0x080:
            self.syncs += 1
            self.on_sync()
            if self.hold_syncs is not None:
                due = [m for at, m in self._held if self.syncs - at >= self.hold_syncs]
                self._held = [(at, m) for at, m in self._held if self.syncs - at < self.hold_syncs]
                for m in due:
                    self._inner.send(m, timeout)
        elif msg.arbitration_id in self.cob_ids:
            copy = can.Message(arbitration_id=msg.arbitration_id, data=bytes(msg.data))
            self._held.append((self.syncs, copy))
            return
        self._inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._inner._recv_internal(timeout)

    def shutdown(self) -> None:
        self._inner.shutdown()
        super().shutdown()


class StarvedHost:
    """After ``syncs`` SYNCs clocked by the group: the drives' clock (``drive_s``, one SYNC
    period each, or none when it does not advance) and a fake wall clock (``wall_s``, on which
    ``wall_per_sync_s`` passes with each)."""

    def __init__(self, wall_per_sync_s: float, drive_clock_advances: bool = True) -> None:
        self.syncs = 0
        self.wall_per_sync_s = wall_per_sync_s
        self.drive_clock_advances = drive_clock_advances

    def sync_sent(self) -> None:
        self.syncs += 1

    @property
    def drive_s(self) -> float:
        return self.syncs * PERIOD_S if self.drive_clock_advances else 0.0

    @property
    def wall_s(self) -> float:
        return self.syncs * self.wall_per_sync_s

    def drive_clock(self) -> float:
        return self.drive_s

    def wall_clock(self) -> float:
        return self.wall_s


@pytest.fixture
def make_group():
    opened: list = []

    def make(
        host: StarvedHost, held: set[int], hold_syncs: int | None, on_drive_time: bool = True
    ) -> DriveGroup:
        """Three drives; the controlwords to the nodes ``held`` held ``hold_syncs`` SYNCs."""
        # No heartbeats (not the subject): the nodes' consumer runs on the real wall clock.
        drives = drive_cfgs(heartbeat_producer_ms=0, heartbeat_consumer_ms=10_000)
        ch = channel()
        cfg = bus_cfg(ch, sync_period_s=PERIOD_S, feedback_timeout_s=10.0)
        sim = SimDriveBus(drives, "virtual", ch, sync_period_s=PERIOD_S).start()
        opened.append(sim)
        group = DriveGroup(
            HoldingBus(ch, {CW_COB_ID[n] for n in held}, hold_syncs, host.sync_sent),
            cfg,
            drives,
            clock=host.wall_clock,
            watch_clock=host.drive_clock if on_drive_time else None,
        )
        opened.insert(0, group)
        group.boot()
        group.configure()
        # One SYNC (on neither clock) for the drives' first feedback: the walk starts from their
        # states, and only a state change restarts a step's timeout.
        group.send_sync()
        assert wait_until(lambda: State.UNKNOWN not in [f.state for f in group.feedback()])
        host.syncs = 0  # both clocks start with the sequence under test
        return group

    yield make
    for part in opened:
        if isinstance(part, DriveGroup):
            part.close()
        else:
            part.stop()


def test_a_node_answering_after_n_periods_on_a_starved_host_is_enabled(make_group):
    # Node 1 sees each controlword 20 SYNCs late; 0.1 s of wall time passes per SYNC: each step
    # takes >= 20 SYNCs, 2 s of wall time (4x the 0.5 s step timeout) but 40 ms of the drives'.
    host = StarvedHost(wall_per_sync_s=0.1)
    g = make_group(host, {1}, hold_syncs=20)
    g.enable()
    assert [f.state for f in g.feedback()] == [State.OPERATION_ENABLED] * 3
    steps = 3  # 0x06, 0x07, 0x0F, each held 20 SYNCs
    assert host.syncs >= steps * 20
    assert host.wall_s >= steps * 4 * STATE_STEP_TIMEOUT_S  # on wall time: a timeout
    assert host.drive_s < steps * STATE_STEP_TIMEOUT_S


def test_on_wall_time_the_same_starved_enable_times_out(make_group):
    # The control: the same node and host with the waits on the wall clock (a wall-clock rig's
    # default) give up after 0.5 s of wall time, i.e. 5 SYNCs, before node 1 answers.
    host = StarvedHost(wall_per_sync_s=0.1)
    g = make_group(host, {1}, hold_syncs=20, on_drive_time=False)
    with pytest.raises(RigTimeoutError, match=r"node 1: still SWITCH ON DISABLED 0\.5 s after"):
        g.enable()


def test_a_node_that_never_answers_times_out_on_the_drives_time(make_group):
    # No drive ever answers (no state change restarts the step's timeout). 10 ms of wall time
    # per 2 ms SYNC period: the drives' 0.5 s pass after 250 SYNCs and 2.5 s of wall time,
    # within the backstop (30 x 0.5 s): the timeout is the drives' own.
    host = StarvedHost(wall_per_sync_s=0.01)
    g = make_group(host, {1, 2, 3}, hold_syncs=None)
    with pytest.raises(
        RigTimeoutError, match=r"node 1: still SWITCH ON DISABLED 0\.5 s after"
    ) as e:
        g.enable()
    assert "backstop" not in str(e.value)
    # Expired on the first look past 0.5 s: 251 SYNCs (250 x 2 ms is not yet past it).
    assert host.syncs == 251
    assert host.wall_s < WALL_BACKSTOP_FACTOR * STATE_STEP_TIMEOUT_S


def test_a_drive_clock_that_stands_still_is_ended_by_the_wall_backstop(make_group):
    # The drives' clock never advances (a caller whose drives' time stands still): a 62.5 ms step
    # ends after 30 x 62.5 ms = 1.875 s of wall time, on the first look past it (16 SYNCs of
    # 0.125 s; both exact in binary), and says it was the backstop.
    host = StarvedHost(wall_per_sync_s=0.125, drive_clock_advances=False)
    g = make_group(host, {1, 2, 3}, hold_syncs=None)
    with pytest.raises(RigTimeoutError, match="wall-clock backstop") as e:
        g.enable(timeout_s=0.0625)
    assert "node 1: still SWITCH ON DISABLED 0.0625 s after" in str(e.value)
    assert host.drive_s == 0.0
    assert host.syncs == 16
