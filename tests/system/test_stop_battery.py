"""System (issue #21, acceptance 1, light): hostile and unlucky requests while a trajectory runs
on the simulated rig; ``stop`` in the middle of each reaches the bus within 2 cycles, no drive
faults, the loop's counters and the run's rows agree, and each refusal names its limit. The full
battery at 1 kHz with 100 MB requests, 10^6 rows, 200 clients and the machine's floor is
``benchmarks/bench_stop_battery.py``.

Load-robust: the stop is counted in bus cycles (SYNC frames on the CAN traffic log between the
request's arrival and the first quick-stop controlword frame) and in loop cycles, not in
wall-clock margins; lateness and the floor are printed, not asserted (the benchmark compares them).
"""

from __future__ import annotations

import pytest
from battery import (
    big_request,
    counters_agree,
    file_trajectory,
    many_clients,
    recover,
    run_one,
    slow_client,
    tiny_jog,
)
from syshelp import client, session, start_daemon, start_sim, wait_for_socket

pytestmark = [pytest.mark.slow, pytest.mark.realtime, pytest.mark.timeout(300)]

#: The session's rig runs 250 Hz (the shipped simulated rig).
PERIOD_S = 1 / 250


def test_stop_acts_within_two_cycles_under_every_stressor(tmp_path):
    stressors = [
        ("16 MB request", big_request(16 * 1024 * 1024), 0.3, "MAX_LINE_BYTES"),
        ("100k-row file", file_trajectory(100_000, tmp_path), 1.0, None),
        ("50 clients", many_clients(50), 0.2, None),
        ("slow client", slow_client(1.0), 0.3, None),
        ("jog speed 1e-300", tiny_jog(1e-300), 0.05, "limits.bend_rad"),
    ]
    # The daemon at SCHED_FIFO as the unit runs it: at SCHED_OTHER beside stress-ng --cpu 2 its
    # runs tripped (heartbeat:node1, no_feedback:all) before the stressors' stops.
    with (
        session(tmp_path, realtime_daemon=True) as (work, rig, sim, _runs),
        start_sim(sim, tmp_path / "sim.log"),
        start_daemon(rig, tmp_path / "d.log") as d,
    ):
        wait_for_socket(work / "control.sock", d, tmp_path / "d.log")
        records = []
        for name, fn, after_s, limit in stressors:
            rec = run_one(work, name, fn, after_s, PERIOD_S, tmp_path)
            print(rec)
            records.append(rec)
            assert rec["cycles_waited"] is not None and rec["cycles_waited"] <= 2, rec
            assert not rec["drive_faults"], rec
            if rec["bus"] is not None:
                # On the bus: at most 2 SYNCs (bus cycles) went out before the quick stop.
                assert rec["bus"]["syncs_before"] <= 2, rec
            else:
                # No quick-stop frame: only if a trip had quick-stopped the drives already.
                assert rec["trips"], rec
            assert counters_agree(rec), (rec.get("rows"), rec.get("run_counters"))
            if limit is not None:
                assert limit in rec["reply"], rec
            recover(work)
        assert records[2]["reply"] == "50/50 answered"
        # The lead-ins of the runs after the first were planned in the rig process's planner
        # worker, not under its interpreter lock.
        with client(work) as c:
            planner = c.call("status")["rig_planner"]
        assert planner["plans"] >= 1 and planner["failures"] == 0, planner
        # The bus measurement is not vacuous: most stops were timed on the bus.
        assert sum(r["bus"] is not None for r in records) >= 3, records
