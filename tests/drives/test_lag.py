"""The simulated drive lags like a real one: it samples its position at the SYNC and applies the
set-point that came with it after, so the TPDO after SYNC k shows the motor as it was before the
target of SYNC k acted. Frame level: the same targets into a zero-lag, a one-lag and a two-lag
drive give the same positions, one and two SYNCs later."""

from __future__ import annotations

import can
from drivesim import bus_cfg, channel, drain, drive_cfgs

from cdcr_ctl.drives.epos import parse_tpdo_feedback
from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.sim.epos.rig import SimDriveBus

N = 40


def positions_with_lag(lag: int) -> list[int]:
    """TPDO1 positions after each of N cycles of a ramp of targets, one drive."""
    ch = channel()
    drives = drive_cfgs(1)
    cfg = bus_cfg(ch)
    sim = SimDriveBus(drives, "virtual", ch, lag_cycles=lag, sync_period_s=cfg.sync_period_s)
    sim.start()
    spy = can.Bus(interface="virtual", channel=ch)
    g = DriveGroup(can.Bus(interface="virtual", channel=ch), cfg, drives)
    out = []
    try:
        g.boot()
        g.configure()
        g.enable()
        assert sim.node(1).position_counts == 0
        # Drain what enabling sent, bounded in time: heartbeats keep coming, and two producers
        # whose phases interleave left no 50 ms gap to end the open-ended drain this used to be.
        drain(spy, max_s=0.5)
        for k in range(N):
            g.send_cycle([300 * k])
            while True:  # this SYNC's TPDO (each cycle waits for it: nothing piles up)
                m = spy.recv(5.0)
                assert m is not None, f"no TPDO after SYNC {k}"
                if m.arbitration_id == 0x181:
                    out.append(parse_tpdo_feedback(bytes(m.data))[1])
                    break
    finally:
        g.close()
        spy.shutdown()
        sim.stop()
    return out


def test_one_and_two_cycles_of_feedback_lag():
    p0, p1, p2 = positions_with_lag(0), positions_with_lag(1), positions_with_lag(2)
    assert p0[-1] > 5000  # the ramp moved the motor (300 counts per SYNC)
    # zero lag: the TPDO after SYNC k already shows target k at work
    assert p0[0] != 0 or p0[1] != 0
    # one lag: the TPDO after SYNC k shows the motor at SYNC k (before target k)
    assert p1[0] == 0 and p1[1:] == p0[:-1]
    # two lags: each TPDO carries the sample of the SYNC before (from rest: 0 twice)
    assert p2[:2] == [0, 0] and p2[2:] == p0[:-2]
