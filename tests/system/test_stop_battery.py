"""System (issue #21, acceptance 1, light): hostile and unlucky requests while a trajectory runs
on the simulated rig; ``stop`` in the middle of each acts within 2 loop cycles, no drive faults,
and each refusal names its limit. The full battery with 100 MB requests, 10^6 rows and 200
clients is ``benchmarks/bench_stop_battery.py``.

Load-robust: what is asserted is counted in loop cycles (the stop's cycle against the request's)
and in refusals, not in wall-clock margins; lateness is printed, not asserted.
"""

from __future__ import annotations

import pytest
from battery import (
    big_request,
    file_trajectory,
    many_clients,
    recover,
    run_one,
    slow_client,
    tiny_jog,
)
from syshelp import session, start_daemon, start_sim, wait_for_socket

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


def test_stop_acts_within_two_cycles_under_every_stressor(tmp_path):
    stressors = [
        ("16 MB request", big_request(16 * 1024 * 1024), 0.3, "MAX_LINE_BYTES"),
        ("100k-row file", file_trajectory(100_000, tmp_path), 1.0, None),
        ("50 clients", many_clients(50), 0.2, None),
        ("slow client", slow_client(1.0), 0.3, None),
        ("jog speed 1e-300", tiny_jog(1e-300), 0.05, "limits.bend_rad"),
    ]
    with (
        session(tmp_path) as (work, rig, sim, _runs),
        start_sim(sim, tmp_path / "sim.log"),
        start_daemon(rig, tmp_path / "d.log") as d,
    ):
        wait_for_socket(work / "control.sock", d, tmp_path / "d.log")
        records = []
        for name, fn, after_s, limit in stressors:
            rec = run_one(work, name, fn, after_s)
            print(rec)
            records.append(rec)
            assert rec["cycles_waited"] is not None and rec["cycles_waited"] <= 2, rec
            assert not rec["drive_faults"], rec
            if limit is not None:
                assert limit in rec["reply"], rec
            recover(work)
        assert records[2]["reply"] == "50/50 answered"
