"""Cyclic synchronous position: three simulated EPOS4 track a trajectory at 1 kHz over the virtual
bus with no SYNC missed on the drive side (the functional version of benchmarks/bench_csp.py),
and the simulated drives are deterministic: their time is the SYNC, not the wall clock."""

from __future__ import annotations

import math

from drivesim import Cycler, drive_cfgs, make_rig, wait_until

from cdcr_ctl.drives.cia402 import State
from cdcr_ctl.sim.epos.node import SimEpos
from cdcr_ctl.sim.epos.plant import MotorParams

AMPLITUDE = 20_000  # counts
FREQ_HZ = 1.0


def sine(k: int, period_s: float) -> list[int]:
    """A·(1 - cos 2πft) per drive (drive j with sign and scale): starts at rest."""
    w = 2 * math.pi * FREQ_HZ * k * period_s
    return [round(s * AMPLITUDE * (1 - math.cos(w))) for s in (1.0, -0.5, 0.25)]


def test_three_drives_track_1khz_csp_without_missed_sync():
    # Not a fault test: heartbeat and feedback timeouts long enough for a loaded CI machine.
    drives = drive_cfgs(3, heartbeat_producer_ms=500, heartbeat_consumer_ms=5000)
    r = make_rig(drives, sync_period_s=0.001, feedback_timeout_s=2.0)
    g = r.group
    try:
        with Cycler(g, targets=lambda k: [0, 0, 0]) as hold:
            g.enable()
            assert wait_until(lambda: hold.cycles > 5)
        # quiet: one TPDO per drive has come back for every SYNC so far (all after NMT start)
        assert wait_until(lambda: g.tpdo_counts() == [g.sync_count] * 3)
        r.sim.reset_stats()
        sent0 = g.sync_count
        with Cycler(g, targets=lambda k: sine(k, 0.001)) as cyc:
            assert wait_until(lambda: cyc.cycles >= 1500, 20)
        assert wait_until(lambda: g.tpdo_counts() == [g.sync_count] * 3)
        sent = g.sync_count - sent0
        assert g.first_fault() is None
        for n in r.sim.nodes:
            assert n.sync_count == sent  # every SYNC the master sent, every drive saw
            assert n.missed_setpoints == 0  # and each came with a fresh target
            assert n.state is State.OPERATION_ENABLED
            # The drive keeps up within a quarter of the distance the reference moves in one
            # SYNC period at the trajectory's peak speed (2π·f·A·T = 126 counts for drive 1).
            peak_step = 2 * math.pi * FREQ_HZ * AMPLITUDE * 0.001
            assert n.max_following_error_counts < peak_step / 4
        last = sine(cyc.cycles - 1, 0.001)
        with Cycler(g, targets=lambda k: last):  # hold the last target: the drives settle on it
            assert wait_until(lambda: r.sim.actual_positions() == last)
    finally:
        r.close()


def run_sequence(fast: bool) -> tuple[list[int], list[float]]:
    """The same 300 targets through the group; ``fast`` sends them back to back."""
    drives = drive_cfgs(3, heartbeat_producer_ms=500, heartbeat_consumer_ms=5000)
    r = make_rig(drives, sync_period_s=0.001, feedback_timeout_s=5.0)
    g = r.group
    try:
        with Cycler(g, targets=lambda k: [0, 0, 0]) as hold:
            g.enable()
            assert wait_until(lambda: hold.cycles > 3)
        assert wait_until(lambda: g.tpdo_counts() == [g.sync_count] * 3)  # all SYNCs processed
        r.sim.reset_stats()
        for k in range(300):
            g.send_cycle(sine(k, 0.001))
            if not fast:
                wait_until(lambda k=k: r.sim.nodes[0].sync_count > k, 1.0)
        assert wait_until(lambda: all(n.sync_count == 300 for n in r.sim.nodes))
        # A node counts a SYNC when it starts handling it and sends its TPDO after the motor step:
        # the positions are final only once every drive's TPDO of the last SYNC is back. (Reading
        # on sync_count alone raced the last step of the last drive under load.)
        assert wait_until(lambda: g.tpdo_counts() == [g.sync_count] * 3)
        assert g.first_fault() is None
        return r.sim.actual_positions(), [n.motor.x for n in r.sim.nodes]
    finally:
        r.close()


def test_simulated_drives_are_deterministic_whatever_the_wall_clock():
    paced = run_sequence(fast=False)
    burst = run_sequence(fast=True)
    assert paced == burst  # bit-identical motor states: time advanced by SYNC only


def test_explicit_step_without_sync():
    """advance_on_sync off: the owner steps the plant; a load torque moves a free motor."""
    import canopen

    net = canopen.Network()
    node = SimEpos(net, 1, "epos4", MotorParams())
    node.advance_on_sync = False
    node.load_torque_Nm = 0.05  # 50 mN·m at the gearbox output, + direction
    x = []
    for _ in range(2):
        node.step(0.01)
        x.append(node.position_counts)
    assert 0 < x[0] < x[1]  # unpowered (SWITCH ON DISABLED): the load turns the motor
    # a = τ/(N·J) on the motor: after 20 ms, x = a t²/2 (minus a little viscous drag)
    a_counts = 0.05 / 19.0 / 6e-7 * 2048 / (2 * math.pi)
    assert x[1] == __import__("pytest").approx(a_counts * 0.02**2 / 2, rel=0.02)
