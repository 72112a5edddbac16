"""Where the lock-step loop's process spends its CPU: the loop thread's stages and a cProfile of
its cycles, over the Qi et al. 2023 planar bend (0 -> 90 deg at pi/10 rad/s) at the rig's 250 Hz,
compensation model (the session of ``benchmarks/bench_lockstep.py``).

    .venv/bin/python benchmarks/bench_loop_profile.py [--top 40] [--sort tottime|cumulative]
        [--no-profile] [--cpu-timer] [--callees REGEX]

Printed first: the CPU per simulated cycle of the loop thread and of the whole loop's process
(``--no-profile`` for figures without the profiler). Everything the loop's process does per
cycle runs on the loop thread: the cycle itself
(``ControlLoop._cycle``: inputs, setpoint, model, checks, RPDOs + SYNC with the simulated nodes
answering inside the send, log row) and, before it, the world's advance
(``LockstepRig.advance``: truth hand-off, Modbus transactions, NatNet frames). Both are profiled
(only while the run goes, the set-up and homing are not). Printed:

- the loop's stage means (wall us per cycle, ``LoopCounters.stage_mean_us``; ``--no-profile``
  for figures without the profiler's overhead, which roughly doubles every Python call);
- the profile, sorted by ``--sort``, per call and per cycle (us per simulated cycle: the
  figure to rank the parts by; absolute values include the profiler's overhead, so compare
  parts with each other, and the CPU per part with ``bench_lockstep.py``). Wall time by
  default: ``posix.read`` / ``posix.write`` at the top are the truth pipe's waits for the
  worker process, not CPU.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import tempfile
import time
from pathlib import Path

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.control.loop import ControlLoop
from cdcr_ctl.sim.lockstep.rig import LockstepRig
from cdcr_ctl.sim.lockstep.session import LockstepSession
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]


def thread_cpu_s(tid: int | None) -> float:
    """CPU time (s) of thread ``tid`` of this process so far, from the scheduler's nanosecond
    count (``/proc/self/task/TID/schedstat``; 0 where there is none)."""
    try:
        with open(f"/proc/self/task/{tid}/schedstat") as f:
            return int(f.read().split()[0]) * 1e-9
    except (OSError, ValueError, IndexError):
        return 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sim-config", default=str(ROOT / "config/sim/qi2023-truth.yaml"))
    ap.add_argument("--compensation", default="model", choices=["off", "model", "measured"])
    ap.add_argument("--top", type=int, default=40, help="profile rows printed")
    ap.add_argument("--sort", default="tottime", choices=["tottime", "cumulative"])
    ap.add_argument("--no-profile", action="store_true", help="stage means only")
    ap.add_argument(
        "--cpu-timer", action="store_true", help="profile on the thread-CPU clock (slow)"
    )
    ap.add_argument("--callees", default=None, help="print the callees of functions matching")
    args = ap.parse_args()

    # Wall time by default: the thread-CPU clock is a system call per event, which swamps the
    # small functions; the waits (the truth pipe's posix.read / posix.write) then show as such.
    prof = cProfile.Profile(time.thread_time) if args.cpu_timer else cProfile.Profile()
    on = [False]
    cycle, advance = ControlLoop._cycle, LockstepRig.advance

    def profiled(fn):
        def wrapper(*a):
            if not on[0]:
                return fn(*a)
            prof.enable()
            try:
                return fn(*a)
            finally:
                prof.disable()

        return wrapper

    if not args.no_profile:
        ControlLoop._cycle = profiled(cycle)  # type: ignore[method-assign]
        LockstepRig.advance = profiled(advance)  # type: ignore[method-assign]

    loaded = load_sim_config(args.sim_config)
    ctl = load_rig_config(loaded.rig_path)
    traj = tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10)
    try:
        with (
            tempfile.TemporaryDirectory() as tmp,
            LockstepSession.open(loaded, ctl, loaded.rig_path, tmp) as s,
        ):
            tid = s.loop._thread.native_id if s.loop._thread is not None else None
            c0 = s.rig.clock.cycles
            s.loop.counters.reset_timing()
            cpu0, thread0 = time.process_time(), thread_cpu_s(tid)
            on[0] = True
            run = s.run(traj, "profile", args.compensation)
            on[0] = False
            cpu, thread = time.process_time() - cpu0, thread_cpu_s(tid) - thread0
            n = s.rig.clock.cycles - c0
            stages = s.loop.counters.stage_mean_us()
    finally:
        ControlLoop._cycle, LockstepRig.advance = cycle, advance  # type: ignore[method-assign]
    print(f"run {run.name}: {run.state}, {n} cycles")
    what = "profiled" if not args.no_profile else "the figure to compare"
    print(
        f"CPU per simulated cycle ({what}): loop thread {thread / n * 1e6:.1f} us, the loop's "
        f"process {cpu / n * 1e6:.1f} us (all its threads; the truth worker is another process)"
    )
    print("loop stages, wall us per cycle" + ("" if args.no_profile else " (profiled)") + ":")
    for k, v in stages.items():
        print(f"  {k:10s} {v:8.1f}")
    if args.no_profile:
        return
    st = pstats.Stats(prof)
    st.sort_stats(args.sort)
    if args.callees:
        st.print_callees(args.callees)
        return
    key = 2 if args.sort == "tottime" else 3  # (cc, nc, tt, ct, callers)
    rows = sorted(st.stats.items(), key=lambda kv: kv[1][key], reverse=True)[: args.top]
    print(f"profile ({args.sort}), us per simulated cycle (profiler overhead included):")
    print(f"  {'calls/cycle':>11s} {'own':>8s} {'cumul.':>8s}  function")
    for (file, line, name), (_cc, nc, tt, ct, _callers) in rows:
        where = f"{Path(file).name}:{line}({name})" if line else name
        print(f"  {nc / n:11.2f} {tt / n * 1e6:8.1f} {ct / n * 1e6:8.1f}  {where}")


if __name__ == "__main__":
    main()
