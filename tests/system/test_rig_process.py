"""System (issue #21): the daemon's rig side runs in a process of its own. If it dies the front
says so in ``status`` and exits non-zero (systemd restarts the unit); if the front dies the rig
process shuts down in order (run log closed, drives disabled) instead of running on unsupervised.
"""

from __future__ import annotations

import os
import signal
import time

import pytest
from battery import start_run
from syshelp import (
    client,
    lasting_run,
    realtime,
    relaunch,
    session,
    start_daemon,
    start_sim,
    wait_for_socket,
    wait_status,
)

from cdcr_ctl.daemon.front import EXIT_RIG_DIED, RIG_EXIT_REPORT_S, RIG_STOP_TIMEOUT_S
from cdcr_ctl.runlog import load_run

pytestmark = [pytest.mark.slow, pytest.mark.realtime, pytest.mark.timeout(240)]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie (exited, not reaped by its dead parent yet) is gone for our purpose.
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def _wait_gone(pid: int, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while _alive(pid):
        assert time.monotonic() < end, f"process {pid} still running after {timeout_s} s"
        time.sleep(0.1)


def test_a_dead_rig_process_is_reported_and_a_dead_front_stops_the_rig_in_order(tmp_path):
    with (
        session(tmp_path) as (work, rig, sim, _runs),
        start_sim(sim, tmp_path / "sim.log") as sim_proc,
    ):
        # Real-time, as a lab PC runs it: the subject is a run the front's death stops, which a
        # starved rig would trip first (syshelp.RT_PRIORITY).
        realtime(rig, sim_proc.pid)
        # The rig process dies (SIGKILL): the front reports it, then exits with its own status.
        with start_daemon(rig, tmp_path / "d1.log") as d:
            wait_for_socket(work / "control.sock", d, tmp_path / "d1.log")
            with client(work) as c:
                front = c.call("status")["front"]
            assert front["pid"] == d.pid and front["rig_pid"] != d.pid
            start_run(work, 20.0)
            os.kill(front["rig_pid"], signal.SIGKILL)
            st = wait_status(work, lambda s: s["state"].startswith("fault: rig process"))
            assert st["state"].startswith("fault: rig process exited -9"), st["state"]
            assert st["fault"]["cause"] == "rig_process_exited" and st["enabled"] is False
            with client(work) as c, pytest.raises(Exception, match="rig process exited -9"):
                c.call("enable")
            assert d.wait(RIG_EXIT_REPORT_S + RIG_STOP_TIMEOUT_S + 30) == EXIT_RIG_DIED

        # The front dies (SIGKILL of the front alone): the rig process ends the run, closes its
        # log, disables the drives and exits.
        with start_daemon(rig, tmp_path / "d2.log") as d:
            wait_for_socket(work / "control.sock", d, tmp_path / "d2.log")
            wait_status(work, lambda s: all(x["state"] != "UNKNOWN" for x in s["drives"]))
            with client(work) as c:
                rig_pid = c.call("status")["front"]["rig_pid"]
            # The subject is a run stopped by the front's death: a run a loaded machine tripped
            # before the kill (a lost heartbeat of a simulated drive under stress-ng) is
            # acknowledged and started again, up to 3 times (battery.start_run resets the fault).
            res = lasting_run(work, lambda _attempt: start_run(work, 20.0), 1.0)
            d.send_signal(signal.SIGKILL)
            d.wait(10)
            _wait_gone(rig_pid, RIG_STOP_TIMEOUT_S + 30)
        run = load_run(res["log_dir"])
        assert run.ended is not None and run.ended["outcome"] == "stopped", run.ended
        assert not run.warnings and len(run) > 50
        log = (tmp_path / "d2.log").read_text()
        assert "front process is gone" in log

        # Nothing left over: the next daemon starts, finds the drives disabled, and runs.
        relaunch(rig, work, tmp_path / "d3.log")


def _children(pid: int) -> set[int]:
    """The processes ``pid`` started (any of its threads) that still run."""
    kids: set[int] = set()
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/children") as f:
                kids.update(int(k) for k in f.read().split())
        except OSError:
            continue
    return kids


def test_a_front_killed_during_its_start_takes_its_rig_process_with_it(tmp_path):
    with (
        session(tmp_path) as (work, rig, sim, _runs),
        start_sim(sim, tmp_path / "sim.log") as sim_proc,
    ):
        realtime(rig, sim_proc.pid)
        with start_daemon(rig, tmp_path / "d1.log") as d:
            # The front has started its rig (and stop) processes, which are still building the
            # daemon: no control socket yet.
            end = time.monotonic() + 120  # the front imports and builds the model first
            while not (kids := _children(d.pid)):
                assert time.monotonic() < end and d.poll() is None, "the front started nothing"
                time.sleep(0.005)
            time.sleep(0.2)  # the rig process is importing and building
            assert not (work / "control.sock").exists(), "the start was already over"
            kids = _children(d.pid)
            d.send_signal(signal.SIGKILL)
            d.wait(10)
            for pid in kids:
                _wait_gone(pid, RIG_STOP_TIMEOUT_S + 30)
        assert "front process" in (tmp_path / "d1.log").read_text()
        # Its locks (CAN link, control socket) went with it: the next daemon starts and runs.
        relaunch(rig, work, tmp_path / "d2.log")
