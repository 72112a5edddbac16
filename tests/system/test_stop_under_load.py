"""System: ``stop`` under client load puts the quick-stop frame on the bus within 2 loop cycles
+ 50 ms of the client's send (the shipped simulated rig at 250 Hz; the daemon and the stand-in
rig at SCHED_FIFO 50, as a lab PC runs the daemon): behind 200 clients flooding
``status``, 50 clients sending 16 MB requests, and slow-loris clients on the control and the stop
socket.

Timed from the client's ``time.monotonic()`` before it sends, to the daemon's own record of the
quick-stop frame handed to the CAN adapter (its traffic log's stop tap); the simulated drives'
reaction (the first drive entering QUICK STOP ACTIVE) must be seen too, and is printed: it measures
the simulator's CPU share beside the flood as much as the daemon. Light: 1 trial per load;
``benchmarks/bench_stop_load.py`` runs 20 per load at 250 Hz and 1 kHz and reports both.
"""

from __future__ import annotations

import time

import pytest
from faulthelp import start_sim_with_faults
from stopload import loaded, trials
from syshelp import realtime, session, start_daemon, wait_for_socket

from cdcr_ctl.daemon.protocol import stop_socket_path
from cdcr_ctl.sim.faults import FaultClient

pytestmark = [pytest.mark.slow, pytest.mark.realtime, pytest.mark.timeout(400)]

#: The session's rig runs 250 Hz (the shipped simulated rig).
PERIOD_S = 1 / 250
TRIALS = 1
LOADS = [("status", 200), ("big", 50), ("slowloris", 100)]


def test_stop_reaches_the_bus_within_two_cycles_and_50_ms_under_client_load(tmp_path):
    t0 = time.monotonic()
    with (
        session(tmp_path) as (work, rig, sim, _runs),
        start_sim_with_faults(sim, work / "faults.sock", tmp_path / "sim.log") as sim_proc,
    ):
        # The daemon at SCHED_FIFO as a lab PC's unit runs it, and the simulated rig's threads
        # too: they stand in for drives with processors of their own, so a 200-process flood on
        # two cores delays the daemon under test, not the stand-in drives (syshelp.realtime).
        realtime(rig, sim_proc.pid)
        with start_daemon(rig, tmp_path / "d.log") as d:
            control = work / "control.sock"
            wait_for_socket(control, d, tmp_path / "d.log")
            assert stop_socket_path(control).is_socket()
            fc = FaultClient(work / "faults.sock")
            results = {}
            print(f"started in {time.monotonic() - t0:.1f} s")
            for seed, (kind, n) in enumerate(LOADS):
                t1 = time.monotonic()
                with loaded(kind, n, control) as count:
                    got = trials(control, fc, PERIOD_S, TRIALS, 100 * seed)
                    results[kind] = (count.value, got)
                print(kind, n, count.value, got, f"{time.monotonic() - t1:.1f} s")
            fc.close()
    for kind, (count, got) in results.items():
        assert count > 0, f"{kind}: the load never got going"
        for trial in got:
            # The stand-in drive took the quick stop off the bus (its reaction time is printed:
            # it is the simulator's CPU share under the flood, not the daemon's).
            assert trial["latency_ms"] is not None, (kind, trial)
            # The quick-stop frame was on the bus (handed to the adapter, the daemon's tap)
            # within two cycles + 50 ms of the client's send.
            assert trial["daemon_bus_ms"] <= trial["budget_ms"], (kind, trial)
            # The loop acted within two of its cycles of the request's arrival.
            assert trial["reply"]["cycles_waited"] <= 2, (kind, trial)
