"""System: in lock-step the heartbeats live on simulated time (cdcr_ctl.sim.lockstep.rig).

A host that stalls while simulated time stands still (a loaded machine starving the loop thread:
the wall clock runs on, the simulated one does not) trips no heartbeat; a heartbeat that goes
missing in simulated time still trips, within the consumer time of simulated time. The
real-time path (the drive group on the wall clock) tripping on a missing heartbeat is
tests/drives/test_faults.py (``heartbeat:node1``).
"""

from __future__ import annotations

import re
import time

import pytest
from syshelp import TRUTH

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.drives.heartbeat import HEARTBEAT_TIMEOUT_FACTOR
from cdcr_ctl.sim.lockstep import rig as lockstep_rig
from cdcr_ctl.sim.lockstep.session import LockstepSession
from cdcr_ctl.sim.simconfig import load_sim_config

pytestmark = pytest.mark.timeout(120)

#: Heartbeat producer time in this test (ms): short, so that a stall of a few tenths of a second
#: of wall time is many producer periods and several consumer timeouts.
PRODUCER_MS = 50
#: The host stalls this long (s, wall clock) inside the loop's world advance, :data:`STALLS`
#: times during one run: each stall is 8 producer periods, 2.7 consumer timeouts (3 periods).
STALL_S = 0.4
STALLS = 3


def _session(tmp_path, monkeypatch) -> LockstepSession:
    monkeypatch.setattr(lockstep_rig, "LOCKSTEP_HEARTBEAT_MS", PRODUCER_MS)
    monkeypatch.setattr(lockstep_rig, "LOCKSTEP_HEARTBEAT_CONSUMER_MS", 5 * PRODUCER_MS)
    loaded = load_sim_config(TRUTH)
    ctl = load_rig_config(loaded.rig_path)
    return LockstepSession.open(loaded, ctl, loaded.rig_path, tmp_path, truth_process=False)


def test_a_stalled_host_trips_no_heartbeat_and_a_missing_one_trips_in_simulated_time(
    tmp_path, monkeypatch
):
    traj = tj.random_smooth(1, 1.5, 1.0, 0.5, seed=7)
    with _session(tmp_path, monkeypatch) as s:
        clock = s.rig.clock
        advance = clock.advance
        assert advance is not None
        stalls: list[float] = []  # simulated times at which the host stalled

        def stalling(t0: float, t1: float) -> None:
            # Every 0.3 s of simulated time, STALLS times: the loop thread stops (as a starved
            # one would) with the world's time standing still.
            if len(stalls) < STALLS and t1 >= (len(stalls) + 1) * 0.3 + clock.t0_s:
                stalls.append(t1)
                time.sleep(STALL_S)
            advance(t0, t1)

        clock.advance = stalling
        frames0 = s.rig.can.frames_to_host
        run = s.run(traj, "stalled", log=False)
        assert len(stalls) == STALLS
        assert run.state == "completed", run.end_reason
        assert s.drives.first_fault() is None
        # The heartbeats did flow in simulated time: 3 nodes, one every PRODUCER_MS, beside
        # 3 TPDOs per cycle (only counted here, nothing asserted on the frames' split).
        cycles = clock.cycles
        assert s.rig.can.frames_to_host - frames0 >= 3 * cycles

        # A node whose producer stops: tripped once the consumer time (3 producer periods) of
        # simulated time has passed since its last heartbeat (sent at most one producer period
        # before the stop), checked every SYNC (one loop period of simulated time each; a
        # heartbeat due within a period is stamped at the period's start: one period more).
        clock.advance = advance
        node = s.rig.nodes[0]
        group = s.drives.group
        node.stop_heartbeat()
        syncs0 = group.sync_count
        run = s.run(traj, "silent", log=False)
        assert run.state == "tripped"
        fault = group.fault()
        assert fault is not None and fault.cause == f"heartbeat:node{node.node_id}"
        limit, period = HEARTBEAT_TIMEOUT_FACTOR * PRODUCER_MS / 1e3, clock.period_s
        age = float(re.search(r"none for ([0-9.]+) s", fault.description).group(1))
        assert limit < age <= limit + 2 * period + 1e-3  # the text rounds to 1 ms
        elapsed = (fault.at_sync - syncs0) * period  # simulated time from the stop
        assert limit - PRODUCER_MS / 1e3 < elapsed <= limit + 2 * period + 1e-9
