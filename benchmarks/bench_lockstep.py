"""Lock-step simulated rig: speed factor (simulated s per wall s) and CPU per simulated cycle of
each part, over the Qi et al. 2023 planar bend (0 -> 90 deg at pi/10 rad/s) at the rig's 250 Hz.

    .venv/bin/python benchmarks/bench_lockstep.py [--sim-config config/sim/qi2023-truth.yaml]
        [--compensation model] [--repeat 1] [--truth-inline] [--no-parts] [--no-log]
        [--cpus auto]

One process: the controller's loop, drive layer (CANopen), Modbus RTU reader and NatNet parser,
the simulated EPOS nodes, transmitters, tracker and truth (cdcr_ctl.sim.lockstep). Parts:
``loop`` = the loop thread's cycle work minus what it spends in the simulated drives, the TPDO
decoding and the sensors; ``protocol`` = RPDO/SYNC encode (the loop's send stage minus the
nodes) + TPDO decode; ``sim drives`` = the nodes handling the frames and stepping at SYNC;
``sensors`` = Modbus and NatNet traffic, both ends; ``truth`` = the world's statics solves.

Then the wall against the CPU of each process, per simulated cycle: the loop's process, the
truth worker, the run's log writer process (the CSV/MCAP encoding; ``resource`` children's CPU
once it is reaped, less what it had used when the run took it) and the next run's spare writer
starting meanwhile (its interpreter and imports, at nice 10; ``/proc/<pid>/stat``). ``cycles``
is the wall from the first to the last cycle (without the run log's start and its close, which
flushes and fsyncs); on two free cores the wall per cycle can fall to the largest of the
processes, never below it. The machine's load average is printed with each run.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import tempfile
import time
from pathlib import Path

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.sim.lockstep.placement import Placement
from cdcr_ctl.sim.lockstep.session import LockstepSession
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]


def proc_cpu_s(pid: int) -> float:
    """User + system CPU (s) of process ``pid`` so far (0 if it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def thread_sched(tid: int) -> tuple[float, float, int, int]:
    """(s on a CPU, s runnable but waiting for one, voluntary and involuntary context switches)
    of thread ``tid`` of this process so far (``/proc/self/task/<tid>/``)."""
    try:
        with open(f"/proc/self/task/{tid}/schedstat") as f:
            run_ns, wait_ns = (int(v) for v in f.read().split()[:2])
        with open(f"/proc/self/task/{tid}/status") as f:
            status = f.read()
    except OSError:
        return 0.0, 0.0, 0, 0
    vol = int(status.split("voluntary_ctxt_switches:")[1].split()[0])
    invol = int(status.split("nonvoluntary_ctxt_switches:")[1].split()[0])
    return run_ns * 1e-9, wait_ns * 1e-9, vol, invol


def threads_sched(skip: int) -> tuple[float, int]:
    """CPU (s) and voluntary switches (wake-ups) of this process's threads other than ``skip``."""
    cpu, wakes = 0.0, 0
    for name in os.listdir("/proc/self/task"):
        if int(name) != skip:
            run_s, _, vol, _ = thread_sched(int(name))
            cpu, wakes = cpu + run_s, wakes + vol
    return cpu, wakes


def host_reference_ms(n: int = 1_000_000) -> float:
    """Thread CPU (ms) of a fixed pure-Python loop (``n`` additions), the least of three: how
    fast this host runs Python right now. On this VM it moves by up to 2x within an hour (the
    host's other guests); print it with every speed factor, so that runs can be compared."""
    best = math.inf
    for _ in range(3):
        c0, s = time.thread_time(), 0
        for i in range(n):
            s += i
        best = min(best, time.thread_time() - c0)
    return best * 1e3


def children_cpu_s() -> float:
    """User + system CPU (s) of the children reaped so far."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


class RunProbe:
    """The run's log writer process (made by the session's factory) and the wall of its first
    and last cycle, for the per-process lines."""

    def __init__(self, session) -> None:
        self.writer_pid = 0
        self.writer_cpu0 = 0.0
        self.first = self.last = 0.0
        factory = session.sinks

        def make(*a, **kw):
            w = factory(*a, **kw)
            proc = getattr(w, "_proc", None)
            if proc is not None:
                self.writer_pid = proc.pid
                self.writer_cpu0 = proc_cpu_s(proc.pid)  # its start-up and imports, before
            return w

        make.close_spare = factory.close_spare
        session.sinks = make
        self.factory = factory
        clock = session.rig.clock
        advance = clock.advance

        def timed_advance(t0, t1):
            now = time.perf_counter()
            if not self.first:
                self.first = now
            self.last = now
            advance(t0, t1)

        clock.advance = timed_advance

    def spare_pid(self) -> int:
        spare = self.factory._spare
        return spare.pid if spare is not None else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sim-config", default=str(ROOT / "config/sim/qi2023-truth.yaml"))
    ap.add_argument("--compensation", default="model", choices=["off", "model", "measured"])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument(
        "--truth-inline",
        action="store_true",
        help="Solve the truth in the loop's process right after each SYNC (default: a worker "
        "process, one period behind)",
    )
    ap.add_argument(
        "--no-parts",
        action="store_true",
        help="Speed factor only: do not time the simulated parts (the per-part CPU clock reads, "
        "~1.5 us each, some 20 per cycle, are themselves a cost); as experiments and tests run",
    )
    ap.add_argument(
        "--no-log",
        action="store_true",
        help="Runs without a run log (no writer process): what the log's writer costs the run",
    )
    ap.add_argument(
        "--cpus",
        default="auto",
        help="Loop thread and truth worker CPUs, as `cdcr-ctl sim --lockstep --cpus` (default "
        "auto: the first two allowed; none: the scheduler places them)",
    )
    args = ap.parse_args()
    placement = Placement.parse(args.cpus)
    loaded = load_sim_config(args.sim_config)
    ctl = load_rig_config(loaded.rig_path)
    traj = tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10)
    with tempfile.TemporaryDirectory() as tmp:
        s = LockstepSession.open(
            loaded, ctl, loaded.rig_path, tmp, not args.truth_inline, placement
        )
        try:
            s.rig.measure_cpu(not args.no_parts)
            send_cpu = [0.0]
            send = s.drives.send_cycle

            def timed_send(targets, send=send):
                c = time.thread_time()
                send(targets)
                send_cpu[0] += time.thread_time() - c

            if not args.no_parts:
                s.drives.send_cycle = timed_send  # the loop calls it through the port
            probe = RunProbe(s)
            for i in range(args.repeat):
                rig, loop = s.rig, s.loop
                cyc0, t_sim0 = rig.clock.cycles, rig.clock.now()
                parts0 = rig.cpu_breakdown_s()
                solves0 = rig.truth_steps
                work0, send0 = loop.counters.work_cpu_s, send_cpu[0]
                load = os.getloadavg()
                ref_ms = host_reference_ms()
                probe.first = 0.0
                spare0 = probe.spare_pid()
                spare_cpu0 = proc_cpu_s(spare0) if spare0 else 0.0
                kids0 = children_cpu_s()
                tid = loop._thread.native_id
                lt0, ot0 = thread_sched(tid), threads_sched(tid)
                w0, c0 = time.perf_counter(), time.process_time()
                run = s.run(traj, f"bench{i}", args.compensation, log=not args.no_log)
                wall, cpu = time.perf_counter() - w0, time.process_time() - c0
                writer = children_cpu_s() - kids0 - probe.writer_cpu0
                spare = probe.spare_pid()
                spare_cpu = proc_cpu_s(spare) - (spare_cpu0 if spare == spare0 else 0.0)
                cycles_wall = probe.last - probe.first
                lt = [b - a for a, b in zip(lt0, thread_sched(tid), strict=True)]
                ot = [b - a for a, b in zip(ot0, threads_sched(tid), strict=True)]
                n = rig.clock.cycles - cyc0
                sim_s = rig.clock.now() - t_sim0
                p = {k: v - parts0[k] for k, v in rig.cpu_breakdown_s().items()}
                work = loop.counters.work_cpu_s - work0
                sent = send_cpu[0] - send0
                world_here = (
                    p["truth"]
                    + p["loadcells_modbus"]
                    + p["tracker_natnet"]
                    + p["attitude_witmotion"]
                )
                total = cpu + p["truth_worker"]
                us = 1e6 / max(n, 1)
                print(
                    f"run {run.name}: {run.state}, {n} cycles = {sim_s:.2f} s simulated "
                    f"(load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; host reference "
                    f"{ref_ms:.0f} ms: 10^6 pure-Python additions, thread CPU, least of 3)"
                )
                print(
                    f"  truth {'inline' if args.truth_inline else 'in a worker process'}; "
                    f"{s.rig.placement.describe()}"
                )
                print(
                    f"  wall {wall:.2f} s -> speed factor {sim_s / wall:.1f}x real time "
                    f"(cycles {cycles_wall:.2f} s -> {sim_s / cycles_wall:.1f}x); CPU "
                    f"{total:.2f} s ({total / wall * 100:.0f} % of one core, loop process + truth)"
                )
                per = [
                    ("loop's process", cpu),
                    ("truth worker", p["truth_worker"]),
                    ("run-log writer process", writer),
                    ("next run's spare writer starting", spare_cpu),
                ]
                every = sum(v for _, v in per)
                print(
                    f"  per simulated cycle: wall {wall * us:.0f} us (cycles {cycles_wall * us:.0f}"
                    f" us); CPU {every * us:.0f} us in all, "
                    + ", ".join(f"{k} {v * us:.0f}" for k, v in per)
                )
                # Outside the cycles (log start and close) the loop thread sleeps, idle; in them
                # it is on a CPU, waiting for one, or sleeping (a hand-off, the truth's result).
                slept = max(0.0, cycles_wall - lt[0] - lt[1])
                print(
                    f"  loop thread: on a CPU {lt[0]:.2f} s, runnable but not running {lt[1]:.2f} s"
                    f", sleeping during the cycles ~{slept:.2f} s (their wall less the two); "
                    f"{lt[2]} voluntary and {lt[3]} involuntary context switches; the process's "
                    f"other threads {ot[0] * us:.0f} us CPU and {ot[1] / max(n, 1):.2f} wake-ups "
                    "a cycle"
                )
                if s.rig.truth_proc is not None and i == 0:
                    print(
                        f"  pids: loop process {os.getpid()}, truth worker "
                        f"{s.rig.truth_proc._proc.pid}"
                    )
                if args.no_parts:
                    continue
                print(f"  CPU per simulated cycle ({1e3 / ctl.control.rate_hz:.0f} ms period):")
                rows = [
                    ("loop (setpoint, model, checks, log row)", work - sent),
                    ("protocol: RPDO+SYNC encode/send", sent - p["sim_drives"] - p["tpdo_decode"]),
                    ("protocol: TPDO decode", p["tpdo_decode"]),
                    ("sim drives (nodes at RPDO/SYNC)", p["sim_drives"]),
                    ("sensors: Modbus RTU both ends", p["loadcells_modbus"]),
                    ("sensors: NatNet both ends", p["tracker_natnet"]),
                    ("sensors: WitMotion attitude both ends", p["attitude_witmotion"]),
                    ("truth (statics solves)", p["truth"] + p["truth_worker"]),
                    ("rest of the loop's process (writer, threads)", cpu - work - world_here),
                    ("total", total),
                ]
                for label, v in rows:
                    print(f"    {label:46s} {v * us:8.1f} us")
                solves = rig.truth_steps - solves0
                truth_s = p["truth"] + p["truth_worker"]
                print(
                    f"  truth: {solves} statics solves, {truth_s / max(solves, 1) * 1e6:.1f} us "
                    "CPU per solve (the solve without a loop beside it: benchmarks/bench_truth.py)"
                )
        finally:
            s.close()


if __name__ == "__main__":
    main()
