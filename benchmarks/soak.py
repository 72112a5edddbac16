"""Soak: the daemon on the simulated rig for N minutes of random trajectories and random faults.

What runs: ``cdcr-ctl sim`` (with its fault channel) and ``cdcr-ctl daemon`` as processes, as on a
lab PC. Repeatedly: clear any trip and enable; start a logged random smooth trajectory
(:func:`~cdcr_ctl.control.trajectory.random_smooth`, 4-12 s); in about two runs of three inject
one random fault part-way (drive EMCY following error / over-current on a random node, heartbeat
loss, a drive bus off, tension spike, load-cell garbage, tracker dropout) and undo it once the
daemon has reacted; wait for the run to end and check it.

The first run after a fault's recovery gets no fault: it says whether the rig can run again.

Checks per run: the daemon reported the trip (cause, reaction) for an injected fault; the drives
reached a safe state (quick-stop faults: every drive in QUICK STOP ACTIVE / SWITCH ON DISABLED /
FAULT; halt faults: targets held); the log is readable, its ``cycle`` column has no gap (samples
expected = last cycle - first cycle + 1 = rows logged) and ``run.yaml`` counts nothing dropped or
lost; the rig recovers (fault reset, enable) for the next run.

Memory: the daemon's RSS (``/proc/PID/status`` VmRSS) after the first two runs (baseline, the
model and buffers warmed up) and at the end; growth in percent.

Verdict (``tests/system/soakverdict.py``): FAILED, naming each rule broken, on an unexpected trip
(a run without an injected fault that did not complete), a first run after a recovery that did
not complete, a lockout (three or more such runs in a row), a lost sample or log gap, a fault
missed, not made safe or not recovered, RSS growth over 10 %, a dead daemon or recovery errors.

    nice .venv/bin/python benchmarks/soak.py --minutes 30 [--seed N] [--rt 50]

``--rt``: the daemon and the simulated rig at SCHED_FIFO (as a lab PC runs the daemon); without
it, on a machine others load, the unexpected trips are the machine's starvation (heartbeat lost,
stale sensors): the JSON's ``loop`` counts the missed cycles and the worst lateness.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "system"))
sys.path.insert(0, str(ROOT / "tests"))  # standin.py, which syshelp imports

from faulthelp import (  # noqa: E402
    call,
    hold_after,
    make_ready,
    rows_on_disk,
    safe_after,
    start_sim_with_faults,
    status,
    wait_for,
)
from soakverdict import SoakRun, verdict  # noqa: E402
from syshelp import SIM_ABOVE, realtime  # noqa: E402

from cdcr_ctl.cli.demo import _cli, make_session, running, wait_for_socket  # noqa: E402
from cdcr_ctl.config import load_rig_config  # noqa: E402
from cdcr_ctl.control import trajectory as tj  # noqa: E402
from cdcr_ctl.daemon.client import DaemonError  # noqa: E402
from cdcr_ctl.runlog import load_run  # noqa: E402
from cdcr_ctl.sim.faults import FaultClient  # noqa: E402

# The clean world: these tests exercise the plumbing, not the physics (the default world's lost
# motion makes an uncompensated cable go slack, which the tension limit rightly trips on).
TRUTH = ROOT / "config" / "sim" / "qi2023-truth-clean.yaml"

#: (fault, args maker (rng, the rig's sensor timeout s), undo fault or None, expected reaction)
FAULTS = [
    (
        "emcy",
        lambda r, _t: {"node": r.randint(1, 3), "code": "following_error"},
        None,
        "QUICK_STOP",
    ),
    ("emcy", lambda r, _t: {"node": r.randint(1, 3), "code": "over_current"}, None, "QUICK_STOP"),
    ("heartbeat_stop", lambda r, _t: {"node": r.randint(1, 3)}, "heartbeat_start", "QUICK_STOP"),
    ("bus_off", lambda r, _t: {"node": r.randint(1, 3)}, "bus_recover", "QUICK_STOP"),
    (
        "tension_spike",
        lambda r, _t: {"cable": f"c{r.randint(1, 3)}", "add_N": 80.0, "duration_s": 0.3},
        None,
        "QUICK_STOP",
    ),
    # A sensor fault lasts twice the rig's ``limits.sensor_timeout_s``: one only a
    # little longer than the timeout trips only if a loop cycle lands in the difference, and a
    # loaded machine's loop can run that late, so the soak would count a right daemon as missing.
    ("loadcell_garbage", lambda r, t: {"duration_s": SENSOR_FAULT_TIMEOUTS * t}, None, "HALT"),
    ("tracker_dropout", lambda r, t: {"duration_s": SENSOR_FAULT_TIMEOUTS * t}, None, "HALT"),
]
#: Sensor faults last this many of the rig config's ``limits.sensor_timeout_s``.
SENSOR_FAULT_TIMEOUTS = 2.0


def rss_kB(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for pid {pid}")


def check_run(run_dir: str) -> tuple[int, int, int]:
    """(rows expected from the cycle span, rows logged, gaps); raises if the log is unreadable."""
    run = load_run(run_dir)
    cycles = run.data["cycle"]
    if len(run) == 0:
        return 0, 0, 0
    expected = int(cycles[-1] - cycles[0]) + 1
    gaps = int(np.sum(np.diff(cycles) != 1))
    ended = run.ended or {}
    rows = ended.get("rows") or {}
    if rows.get("dropped") or rows.get("lost"):
        gaps += 1
    return expected, len(run), gaps


def read_text(log_dir: str) -> str:
    """The run's ``run.yaml`` ('' before it exists)."""
    try:
        return (Path(log_dir) / "run.yaml").read_text()
    except OSError:
        return ""


def soak(minutes: float, seed: int, keep: bool, rt: int = 0) -> tuple[dict, list[SoakRun], bool]:
    """Run the soak; (counts, the record of its runs, whether a recovery had no run after it)."""
    rng = random.Random(seed)
    work = Path(tempfile.mkdtemp(prefix="cdcr-soak-", dir="/tmp"))
    runs_dir = work / "runs"
    runs_dir.mkdir()
    # The CAN adapter on loopback TCP: a pty waits for the kernel's tty worker (syshelp.session).
    rig, sim = make_session(TRUTH, work, runs_dir, tcp_links=True)
    sensor_timeout_s = load_rig_config(rig).limits.sensor_timeout_s
    if rt:
        realtime(rig, None, rt)
    out: dict = {
        "minutes": minutes,
        "runs": 0,
        "runs_completed": 0,
        "runs_tripped": 0,
        "faults_injected": 0,
        "faults_tripped": 0,
        "faults_safe": 0,
        "faults_recovered": 0,
        "faults_missed": [],
        "unexpected_trips": [],
        "recovery_errors": [],
        "samples_expected": 0,
        "samples_logged": 0,
        "log_gaps": 0,
        "by_fault": {},
    }
    t_end = time.monotonic() + minutes * 60
    record: list[SoakRun] = []
    pending_recovery: str | None = None
    after_recovery = False
    try:
        with (
            start_sim_with_faults(sim, work / "faults.sock", work / "sim.log") as sim_proc,
            running(_cli("--config", str(rig), "daemon"), work / "daemon.log") as d,
        ):
            if rt:
                # The stand-in drives and sensors at the daemon's policy (they are hardware).
                # Above the daemon (syshelp.SIM_ABOVE): the daemon under test never starves them.
                realtime(rig, sim_proc.pid, rt)
            wait_for_socket(work / "control.sock", d, work / "daemon.log")
            fc = FaultClient(work / "faults.sock")
            rss0 = None
            while time.monotonic() < t_end:
                try:
                    make_ready(work)
                except Exception as exc:  # counted; the next iteration tries again
                    out["recovery_errors"].append(f"{type(exc).__name__}: {exc}"[:200])
                    time.sleep(1.0)
                    if len(out["recovery_errors"]) > 20:
                        break
                    continue
                if pending_recovery is not None:
                    out["faults_recovered"] += 1
                    out["by_fault"][pending_recovery]["recovered"] += 1
                    pending_recovery = None
                    after_recovery = True
                if out["runs"] == 2:
                    rss0 = rss_kB(d.pid)
                    out["rss_baseline_kB"] = rss0
                duration = rng.uniform(4.0, 12.0)
                traj = tj.random_smooth(1, duration, 1.0, 0.5, seed=rng.randrange(1 << 30))
                name = f"soak{out['runs']}"
                try:
                    res = call(
                        work,
                        "trajectory",
                        name=name,
                        samples=traj.rows(),
                        compensation=rng.choice(["off", "model"]),
                        log=True,
                    )
                except DaemonError as exc:  # a trip between the enable and the run's start
                    fault_now = status(work)["fault"]
                    out["recovery_errors"].append(f"trajectory refused: {exc}; trip {fault_now}")
                    if len(out["recovery_errors"]) > 20:
                        break
                    continue
                out["runs"] += 1
                log_dir = res["log_dir"]
                wait_for(
                    lambda d=log_dir: rows_on_disk(d) > 50 or status(work)["run"] is None,
                    15,
                    "rows",
                )
                fault = None
                inject = rng.random() < 0.67
                if inject and not after_recovery and status(work)["run"] is not None:
                    at_s = rng.uniform(0.2, max(0.3, duration / 2))
                    fault, make_args, undo, reaction = rng.choice(FAULTS)
                    args = make_args(rng, sensor_timeout_s)

                    # At at_s on the run's own clock (its elapsed time in the daemon's status),
                    # not that long after its first rows reach the disk: a loaded machine's
                    # writer lags, and a fault injected in the run's last moments cannot trip
                    # before the run completes. A run already that near its end gets none.
                    def reached(at_s=at_s):
                        run_now = status(work)["run"]
                        return "ended" if run_now is None else run_now["elapsed_s"] >= at_s

                    left_s = duration - at_s
                    if wait_for(reached, duration + 15, "injection time") == "ended" or (
                        left_s < 2 * float(args.get("duration_s", 1.0))
                    ):
                        fault = None
                if fault is not None:
                    key = f"{fault}:{args.get('code', '')}".rstrip(":")
                    stats = out["by_fault"].setdefault(
                        key, {"injected": 0, "tripped": 0, "safe": 0, "recovered": 0}
                    )
                    inj = fc.inject(fault, **args)
                    out["faults_injected"] += 1
                    stats["injected"] += 1
                    try:
                        st = wait_for(lambda: (s := status(work))["fault"] and s, 10, "trip")
                        out["faults_tripped"] += 1
                        stats["tripped"] += 1
                        got = st["fault"]["reaction"]
                        if reaction == "QUICK_STOP":
                            safe = safe_after(fc, inj, 5).all_safe and got == "QUICK_STOP"
                        else:
                            safe = hold_after(fc, inj, 5).all_safe and got in ("HALT", "QUICK_STOP")
                        if safe:
                            out["faults_safe"] += 1
                            stats["safe"] += 1
                    except AssertionError:
                        out["faults_missed"].append(key)
                    if undo is not None:
                        fc.inject(undo, **args)
                    time.sleep(0.7)  # spikes, garbage and dropouts end
                    pending_recovery = key

                # Ended = in the daemon's run history (a run posted but not yet picked up by the
                # loop's next cycle is neither current nor in the history).
                def ended(res=res):
                    runs = status(work)["runs"]
                    return next((r for r in runs if r["log_dir"] == res["log_dir"]), None)

                done = wait_for(ended, duration + 30, "run end")
                if done["state"] == "completed":
                    out["runs_completed"] += 1
                else:
                    out["runs_tripped"] += 1
                    if fault is None:
                        out["unexpected_trips"].append(done["end_reason"])
                record.append(
                    SoakRun(name, done["state"], fault, done["end_reason"], after_recovery)
                )
                after_recovery = False
                try:  # the writer closes the log (run.yaml's ``ended``) before it is checked
                    wait_for(lambda d=log_dir: "\nended:" in read_text(d), 15, "log closed")
                except AssertionError:
                    out["log_gaps"] += 1
                expected, logged, gaps = check_run(res["log_dir"])
                out["samples_expected"] += expected
                out["samples_logged"] += logged
                out["log_gaps"] += gaps
                elapsed = minutes * 60 - (t_end - time.monotonic())
                print(
                    f"[{elapsed:7.1f} s] {name}: {done['state']:9s} {fault or '-':16s} "
                    f"rows {logged}/{expected}",
                    flush=True,
                )
            if pending_recovery is not None:
                make_ready(work)
                out["faults_recovered"] += 1
                out["by_fault"][pending_recovery]["recovered"] += 1
                pending_recovery = None
                record.append(_final_run(work, rng))
                after_recovery = False
            with contextlib.suppress(Exception):
                # Late and missed cycles: evidence of starvation by the machine's other load.
                lp = status(work)["loop"]
                out["loop"] = {
                    k: lp[k] for k in ("cycles", "missed_cycles", "long_cycles") if k in lp
                }
                out["loop"]["lateness_max_us"] = lp["timing"]["lateness_max_us"]
            rss1 = rss_kB(d.pid)
            out["rss_final_kB"] = rss1
            if rss0:
                out["rss_growth_pct"] = round(100.0 * (rss1 - rss0) / rss0, 2)
            out["daemon_alive"] = d.poll() is None
            with contextlib.suppress(Exception):
                fc.close()
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
        else:
            out["work_dir"] = str(work)
    return out, record, after_recovery


def _final_run(work: Path, rng: random.Random) -> SoakRun:
    """A short run with no fault after the soak's last recovery: it must complete."""
    traj = tj.random_smooth(1, 4.0, 1.0, 0.5, seed=rng.randrange(1 << 30))
    res = call(work, "trajectory", name="final", samples=traj.rows(), log=True)

    def ended():
        return next((r for r in status(work)["runs"] if r["log_dir"] == res["log_dir"]), None)

    done = wait_for(ended, 40, "run end")
    return SoakRun("final", done["state"], None, done["end_reason"], True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", action="store_true", help="keep the run logs and process logs")
    ap.add_argument(
        "--rt",
        type=int,
        default=0,
        help="SCHED_FIFO priority for the daemon (control.realtime_priority, as the shipped "
        "qi2023.yaml and its unit run it) and, SIM_ABOVE higher, the simulated rig (all its "
        "threads); "
        "0: SCHED_OTHER, the simulated rig config's own",
    )
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    out, record, recovery_pending = soak(args.minutes, args.seed, args.keep, args.rt)
    out["wall_s"] = round(time.monotonic() - t0, 1)
    print(json.dumps(out, indent=2))
    failures = verdict(out, record, recovery_pending)
    for failure in failures:
        print("  FAIL", failure)
    ok = not failures
    policy = f"SCHED_FIFO {args.rt}, sim {args.rt + SIM_ABOVE}" if args.rt else "SCHED_OTHER"
    print("SOAK", "PASSED" if ok else "FAILED", f"(seed {args.seed}, {len(record)} runs, {policy})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
