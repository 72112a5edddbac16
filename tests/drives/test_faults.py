"""Faults become a quick stop of every drive within 2 SYNC periods, naming node and code."""

from __future__ import annotations

import numpy as np
import pytest
from drivesim import wait_until

from cdcr_ctl.config.control import LimitsConfig
from cdcr_ctl.control.io import DriveGroupPort
from cdcr_ctl.control.loop import ControlLoop, LoopConfig
from cdcr_ctl.control.ports import NoTension, NoTip
from cdcr_ctl.control.supervisor import Reaction, Supervisor
from cdcr_ctl.drives.cia402 import State


class StillModel:
    n_segments, n_cables = 1, 3

    def new_state(self):
        return None

    def q_nominal(self, psi):
        return np.zeros(3)

    def q_command(self, psi, q_nominal, state, mode, measured_N):
        return q_nominal

    def tip(self, psi):
        return np.array([0.0, 0.0, 90.0])


def run_loop(rig):
    cfg, _sim, group, _spy = rig
    sup = Supervisor(LimitsConfig())
    loop = ControlLoop(
        LoopConfig(period_s=cfg.can.sync_period_s, counts_per_mm=np.ones(3)),
        StillModel(),
        DriveGroupPort(group),
        NoTension(3),
        NoTip(),
        sup,
    )
    loop.start()
    group.enable()
    assert all(f.state is State.OPERATION_ENABLED for f in group.feedback())
    return loop, sup


@pytest.mark.parametrize(
    "inject,cause,text",
    [
        (lambda sim: sim.node(2).inject_emcy(0x8611), "emcy:node2:0x8611", "following error"),
        (lambda sim: sim.node(3).inject_emcy(0x2310), "emcy:node3:0x2310", "over-current"),
        (lambda sim: sim.node(1).stop_heartbeat(), "heartbeat:node1", "heartbeat lost"),
        (lambda sim: sim.node(2).go_silent(), "no_feedback:node2", "no TPDO"),
    ],
    ids=["emcy-following-error", "emcy-over-current", "heartbeat-lost", "bus-silent"],
)
def test_fault_quick_stops_all_drives_within_two_sync_periods(rig, inject, cause, text):
    _cfg, sim, group, _spy = rig
    loop, sup = run_loop(rig)
    try:
        inject(sim)
        assert wait_until(lambda: sup.trip is not None, 3.0)
        assert wait_until(lambda: group.quick_stop_at_sync is not None, 1.0)
    finally:
        loop.stop()
    assert sup.trip.cause == cause and sup.trip.reaction is Reaction.QUICK_STOP
    assert text in sup.trip.detail and f"node {cause.split('node')[1][0]}" in sup.trip.detail
    assert group.quick_stop_at_sync - group.fault_at_sync <= 2
    # Every drive that still answers has left OPERATION ENABLED.
    alive = [n for n in sim.nodes if not n.silent]
    assert all(n.state is not State.OPERATION_ENABLED for n in alive)


def test_master_death_disables_drives_by_their_heartbeat_consumer(rig):
    _cfg, sim, group, _spy = rig
    loop, _sup = run_loop(rig)
    loop.stop()
    group._heartbeat_task.stop()  # the master dies: no more heartbeat, no SYNC
    assert wait_until(lambda: all(n.state is State.FAULT for n in sim.nodes), 2.0)
    assert all(0x8130 in n.emcy_sent for n in sim.nodes)
