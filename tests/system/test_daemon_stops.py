"""System: SIGTERM, SIGKILL of the daemon and a killed simulator mid-trajectory leave the drives
disabled, the log on disk up to the last cycle, and the next start working without cleanup."""

from __future__ import annotations

import itertools
import math
import os
import signal
import time

import pytest
from faulthelp import rows_on_disk
from syshelp import (
    client,
    realtime,
    relaunch,
    session,
    start_daemon,
    start_sim,
    wait_for_socket,
    wait_status,
)

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.runlog import load_run

pytestmark = [pytest.mark.slow, pytest.mark.realtime, pytest.mark.timeout(240)]


def start_run(work, seconds: float = 20.0) -> dict:
    traj = tj.go_and_return(theta_max_rad=0.8, rate_rad_s=0.8 / (seconds / 2))
    with client(work) as c:
        c.call("enable")
        return c.call("trajectory", name="long", samples=traj.rows(), compensation="model")


def rows_so_far(run_dir) -> int:
    return len(load_run(run_dir))


def wait_under_way(run_dir, rows: int = 100, timeout_s: float = 30.0) -> None:
    """Until the run's log holds ``rows`` rows on disk (0.4 s of a 250 Hz run): mid-trajectory,
    the signal can come (it used to be a fixed 2 s wait)."""
    end = time.monotonic() + timeout_s
    while rows_on_disk(run_dir) <= rows:
        assert time.monotonic() < end, f"no {rows} rows on disk after {timeout_s} s: {run_dir}"
        time.sleep(0.05)


def test_sigterm_and_sigkill_of_the_daemon(tmp_path):
    with session(tmp_path) as (work, rig, sim, _runs), start_sim(sim, tmp_path / "sim.log"):
        realtime(rig)  # as the unit runs it: at SCHED_OTHER beside stress-ng no run got under way
        # SIGTERM mid-trajectory: clean stop, drives disabled, log closed with its reason.
        with start_daemon(rig, tmp_path / "d1.log") as d:
            wait_for_socket(work / "control.sock", d, tmp_path / "d1.log")
            res = start_run(work)
            wait_under_way(res["log_dir"])
            d.send_signal(signal.SIGTERM)
            assert d.wait(20) == 0
        run = load_run(res["log_dir"])
        assert run.ended["outcome"] == "stopped" and len(run) > 50
        assert not run.warnings  # no partial line: everything flushed

        # The next start works without cleanup; the drives were disabled by the SIGTERM path.
        with start_daemon(rig, tmp_path / "d2.log") as d:
            wait_for_socket(work / "control.sock", d, tmp_path / "d2.log")
            st = wait_status(work, lambda s: all(x["state"] != "UNKNOWN" for x in s["drives"]))
            assert all(x["state"] != "OPERATION ENABLED" for x in st["drives"])
            res = start_run(work)
            wait_under_way(res["log_dir"])
            n_before = rows_so_far(res["log_dir"])
            # The whole daemon (front and rig process: its process group, as systemd's final
            # SIGKILL hits the unit's cgroup); the front alone: tests/system/test_rig_process.py.
            os.killpg(d.pid, signal.SIGKILL)
            d.wait(10)
        # SIGKILL of the whole tree (front, rig process, the run log's writer process): the log
        # holds everything up to the writer's last fsync (0.5 s), readable, with no end record.
        # (A rig process killed alone leaves the writer to drain and close the run as aborted:
        # tests/runlog/test_runlog_process.py.)
        run = load_run(res["log_dir"])
        assert run.ended is None and len(run) >= n_before > 50
        t = run.t_s
        assert all(b > a for a, b in itertools.pairwise(t))

        # The drives' heartbeat consumers noticed the master's death and disabled them.
        relaunch(rig, work, tmp_path / "d3.log")


def test_killed_simulator_mid_trajectory_quick_stops_and_keeps_the_log(tmp_path):
    with session(tmp_path) as (work, rig, sim, _runs):
        realtime(rig)  # the daemon at SCHED_FIFO as the unit runs it
        sim_ctx = start_sim(sim, tmp_path / "sim.log")
        proc = sim_ctx.__enter__()
        with start_daemon(rig, tmp_path / "d.log") as d:
            wait_for_socket(work / "control.sock", d, tmp_path / "d.log")
            res = start_run(work)
            wait_under_way(res["log_dir"])
            proc.send_signal(signal.SIGKILL)
            proc.wait(10)
            st = wait_status(work, lambda s: s["fault"] is not None, 10)
            assert st["fault"]["reaction"] == "QUICK_STOP"
            assert st["fault"]["cause"].startswith(("no_feedback", "heartbeat", "bus"))
            st = wait_status(work, lambda s: s["run"] is None, 10)
        sim_ctx.__exit__(None, None, None)
        run = load_run(res["log_dir"])
        assert run.ended["outcome"] == "tripped"
        assert any(isinstance(e, str) and e for e in run.data["event"])
        assert len(run) > 50 and math.isfinite(run.t_s[-1])
