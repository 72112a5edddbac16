"""System: the same trajectory on the simulated rig in real time (simulator and daemon processes,
slcan and Modbus over loopback TCP, NatNet on loopback) and in lock-step (`cdcr-ctl sim
--lockstep`, one process on simulated time) gives the same tip errors.

The trajectory: the planar bend of Qi et al. 2023 (0 to 90 deg) and back at twice the paper's
rate (pi/5 rad/s, 2 x 2.5 s): the paper's poses, both ways, and each run ends straight, where
the next begins. The faster rate is a stricter test of the timing, since what differs between
the two per sample, the tip's motion over the offset between their truths' solves, grows with
the rate (at most (L/2) * rate * 5 ms = 0.14 mm here, |dp/dtheta| <= L/2 for a
constant-curvature segment of L = 90 mm).

Tolerance: 5 % of the real-time value, for the mean and the max tip error, compensation off and
model. The two differ only in timing: in real time the physics thread
solves the truth at 200 Hz on the wall clock and every message crosses a process boundary; in
lock-step the truth is solved right after each SYNC that moved a drive. The real-time run goes
as a lab PC runs it: the daemon and the stand-in rig at SCHED_FIFO (``syshelp.realtime``), so
another job's CPU-bound work does not distort the reference. It is a reference only if it kept
its 250 Hz. A run that skipped more than 1 % of its deadlines or ran late (a
lateness p99 over a quarter period: the real-time run itself is distorted), or that tripped
because its stand-in rig fell silent (a starved machine: ``faulthelp.STARVED_CAUSES``), is no
reference: a second session is tried, and when it is no reference either, the comparison is
skipped with the reasons, not loosened. Measured on fresh clones: idle, the
real-time runs' lateness p99 was 199-426 us and the max tip errors within 2.5 %; beside
``stress-ng --cpu 2`` it was 1374-1381 us (26-34 cycles over 1 ms) and the compensated max
7.7 % over lock-step's, and one real-time run tripped (no TPDO for 0.25 s). This trajectory,
on the 2-core VM at load average 10 (others' jobs and a user's ``cdcr-ctl sim``): differences
0.02/0.48 % (off, mean/max) and 0.33/2.40 % (model); the paper's bend up at pi/10 rad/s and a
return run (the earlier form of this test): 0.10/1.37 % and 0.11/2.02 %, in twice the time.

The lock-step rig runs as fast as the CPU allows: beside ``stress-ng --cpu 2`` a run takes
longer, so each run is waited for as long as its elapsed (simulated) time grows
(``syshelp.wait_progress``), not for a fixed wall time.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest
from faulthelp import STARVED_CAUSES
from syshelp import (
    client,
    realtime,
    session,
    start_daemon,
    start_sim,
    wait_for_socket,
    wait_progress,
)

from cdcr_ctl.analysis import tip_errors
from cdcr_ctl.cli.demo import _cli, running
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.runlog import load_run
from cdcr_ctl.runlog.reader import wait_run_closed

TOLERANCE = 0.05
MODES = ("off", "model")
#: A real-time run is a reference only if its loop's lateness p99 (``lateness_us``) stays within
#: this fraction of the period (1 ms at 250 Hz).
LATE_P99_FRACTION = 0.25
#: Real-time sessions tried for a reference before the comparison is skipped.
REFERENCE_ATTEMPTS = 2
#: Longest wall time for a run's log to close after the run ended (s): its writer is a process
#: at a low priority, seconds behind on a loaded machine (as ``cdcr-ctl identify`` allows).
LOG_CLOSE_S = 60.0


def _follow(work, name: str, rows, comp: str) -> dict:
    """Run a logged trajectory through the daemon; its answer with the run's end state and
    reason once it has ended (waited for while its elapsed time grows) and its log is closed."""
    with client(work) as c:
        res = c.call("trajectory", name=name, samples=rows, compensation=comp, log=True)

    def ended(st: dict) -> bool:
        return st["run"] is None and any(r["id"] == res["run"] for r in st["runs"])

    st = wait_progress(work, ended, lambda st: (st["run"] or {}).get("elapsed_s", 0.0))
    run = next(r for r in st["runs"] if r["id"] == res["run"])
    assert wait_run_closed(res["log_dir"], LOG_CLOSE_S), res["log_dir"]
    return {**res, "state": run["state"], "end_reason": run["end_reason"]}


def _late_p99_s(log_dir) -> float:
    """The loop's lateness p99 (s) over a run's rows."""
    late = np.asarray(load_run(log_dir).column("lateness_us"), dtype=float)
    late = late[np.isfinite(late)]
    return float(np.percentile(late, 99)) * 1e-6 if late.size else 0.0


def _measure(
    work, rig, sim, lockstep: bool, traj=None
) -> dict[str, tuple[float, float, float, float]]:
    """(mean, max tip error mm, fraction of the expected rows logged, lateness p99 s) per
    mode."""
    traj = traj or tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 5, back=True)
    out = {}
    with contextlib.ExitStack() as procs:
        if lockstep:
            cmd = _cli("--config", str(rig), "sim", str(sim), "--lockstep")
            d = procs.enter_context(running(cmd, work / "lockstep.log", ready='"ready"'))
        else:
            # The reference at SCHED_FIFO, as a lab PC's unit runs the daemon and as the
            # stand-in hardware would be (syshelp.RT_PRIORITY): its timing is the rig's, not
            # whatever else the machine runs.
            sim_proc = procs.enter_context(start_sim(sim, work / "sim.log"))
            realtime(rig, sim_proc.pid)
            d = procs.enter_context(start_daemon(rig, work / "daemon.log"))
        wait_for_socket(work / "control.sock", d, work / "daemon.log")
        with client(work) as c:
            c.call("enable")
            c.call("home")
        for comp in MODES:
            res = _follow(work, f"bend-{comp}", traj.rows(), comp)
            reason = str(res.get("end_reason") or "")
            if not lockstep and res["state"] == "tripped" and reason.startswith(STARVED_CAUSES):
                raise NotAReference(f"the real-time reference's rig was starved: {res}")
            assert res["state"] == "completed", res
            e = tip_errors(res["log_dir"], settle_s=0.0).summary()
            kept = e["samples"] / (res["duration_s"] * 250.0)
            out[comp] = (e["mean_mm"], e["max_mm"], kept, _late_p99_s(res["log_dir"]))
    return out


class NotAReference(Exception):
    """A real-time run that says nothing of the timing it was meant to show (its rig starved)."""


def _realtime_reference(tmp_path) -> tuple[dict | None, list[str]]:
    """The real-time figures (as :func:`_measure`) of the first of :data:`REFERENCE_ATTEMPTS`
    sessions that kept its 250 Hz, with what was wrong with the ones before; (None, reasons)
    when none did. A burst of other work (in the suite, a previous test's processes still
    ending) can cost one run its rate on an idle machine; the next one is a fresh session."""
    why: list[str] = []
    for k in range(REFERENCE_ATTEMPTS):
        (tmp_path / f"rt{k}").mkdir()
        with session(tmp_path / f"rt{k}") as (work, rig, sim, _runs):
            try:
                real = _measure(work, rig, sim, lockstep=False)
            except NotAReference as exc:
                why.append(str(exc))
                continue
        kept = {m: real[m][2] for m in MODES}
        late = {m: real[m][3] for m in MODES}
        if min(kept.values()) < 0.99:
            why.append(f"it could not keep 250 Hz (rows kept {kept})")
        elif max(late.values()) > LATE_P99_FRACTION / 250.0:
            why.append(f"its cycles ran late (lateness p99 {late} s)")
        else:
            return real, why
    return None, why


@pytest.mark.slow
@pytest.mark.realtime
@pytest.mark.timeout(400)
def test_lockstep_and_real_time_give_the_same_tip_errors(tmp_path):
    with session(tmp_path) as (work, rig, sim, _runs):
        lock = _measure(work, rig, sim, lockstep=True)
    assert all(lock[m][2] > 0.99 for m in MODES), lock  # lock-step never skips a cycle
    real, why = _realtime_reference(tmp_path)
    if real is None:
        pytest.skip(f"no real-time reference on this machine in {REFERENCE_ATTEMPTS} runs: {why}")
    figures = {m: {"lockstep": lock[m][:2], "realtime": real[m][:2]} for m in MODES}
    for m in MODES:
        for i, what in enumerate(("mean", "max")):
            ls, rt = lock[m][i], real[m][i]
            assert abs(ls - rt) <= TOLERANCE * rt, f"{m} {what}: {figures}"
