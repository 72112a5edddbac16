"""What the run log and the CAN traffic log cost the loop (issue #21): the daemon on the
simulated rig at RATE_HZ (loop and SYNC), a slow go-and-return run with the run log off, then
on, REPEATS times each, and optionally with the CAN traffic log off; per run, the loop's long
cycles, missed deadlines and lateness histogram (the difference of ``status`` ``loop`` before
and after the run's first SECONDS).

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_rig_log_cost.py [--rt 50] [--no-traffic]
[--rate-hz 1000] [--seconds 8] [--repeats 2]`` (about 1 minute). No floor is measured here:
compare the rows of one invocation with each other (``benchmarks/bench_stop_battery.py`` has
the floor).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "system"))

from syshelp import client, session, start_daemon, start_sim, wait_for_socket  # noqa: E402

from cdcr_ctl.control import trajectory as tj  # noqa: E402


def _configure(rig: Path, rate_hz: float, rt: int, traffic: bool) -> None:
    doc = yaml.safe_load(rig.read_text())
    doc.setdefault("control", {})["rate_hz"] = rate_hz
    doc["control"]["realtime_priority"] = rt
    doc.setdefault("can", {})["sync_period_s"] = 1.0 / rate_hz
    doc["can"]["log_traffic"] = traffic
    rig.write_text(yaml.safe_dump(doc, sort_keys=False))


def _window(c, log: bool, seconds: float) -> dict:
    with contextlib.suppress(Exception):
        c.call("reset_fault", confirm=True)
    with contextlib.suppress(Exception):
        c.call("enable")
    traj = tj.go_and_return(theta_max_rad=0.3, rate_rad_s=0.3 / 5)
    st0 = c.call("status")
    before, before_cpu = st0["loop"], st0.get("rig_threads_cpu_s", {})
    c.call("trajectory", name="cost", samples=traj.rows(), compensation="model", log=log)
    time.sleep(seconds)
    st = c.call("status")
    after = st["loop"]
    c.call("stop", mode="halt")
    hb, ha = before["timing"]["lateness_histogram"], after["timing"]["lateness_histogram"]
    return {
        "long": after["long_cycles"] - before["long_cycles"],
        "missed": after["missed_cycles"] - before["missed_cycles"],
        "hist": {k: ha[k] - hb.get(k, 0) for k in ha if ha[k] - hb.get(k, 0)},
        "max_us": after["timing"]["lateness_max_us"],
        "long_ms": {
            k: round(v - before.get("long_cycles_ms", {}).get(k, 0.0), 1)
            for k, v in after.get("long_cycles_ms", {}).items()
        },
        "gc": st.get("rig_gc"),
        "cpu": {
            k: round(v - before_cpu.get(k, 0.0), 2)
            for k, v in st.get("rig_threads_cpu_s", {}).items()
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rt", type=int, default=0, help="SCHED_FIFO priority (daemon and sim)")
    ap.add_argument("--no-traffic", action="store_true", help="can.log_traffic: false")
    ap.add_argument("--rate-hz", type=float, default=1000.0)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="cdcr-logcost-"))
    with session(tmp) as (work, rig, sim, _runs), start_sim(sim, tmp / "sim.log") as sp:
        _configure(rig, a.rate_hz, a.rt, not a.no_traffic)
        if a.rt:
            subprocess.run(["chrt", "-a", "-f", "-p", str(a.rt), str(sp.pid)], check=True)
        with start_daemon(rig, tmp / "d.log") as d:
            wait_for_socket(work / "control.sock", d, tmp / "d.log")
            print(
                f"loop at {a.rate_hz:g} Hz, {'SCHED_FIFO ' + str(a.rt) if a.rt else 'SCHED_OTHER'},"
                f" CAN traffic log {'off' if a.no_traffic else 'on'}, {a.seconds:g} s per run,"
                f" load {os.getloadavg()[0]:.1f}"
            )
            with client(work) as c:
                for _ in range(a.repeats):
                    for log in (False, True):
                        w = _window(c, log, a.seconds)
                        print(
                            f"run log {'on ' if log else 'off'}: long cycles {w['long']:4d},"
                            f" missed deadlines {w['missed']:4d}, lateness {w['hist']}",
                            flush=True,
                        )
                        if w["long_ms"]:
                            print(f"  long cycles' time (ms): {w['long_ms']}", flush=True)
                        if w["gc"]:
                            print(f"  rig process gc so far: {w['gc']}", flush=True)
                        if w["cpu"]:
                            print(f"  rig threads' CPU in the run (s): {w['cpu']}", flush=True)
                        time.sleep(1.0)
                cmds = c.call("status").get("rig_commands")
                if cmds:
                    print(f"rig process commands, longest handling: {cmds}")
            print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
