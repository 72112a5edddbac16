"""Benchmark: the real-time loop at the rate the bus allows, compensation on, for N seconds.

What runs: the control loop (ControlLoop) with the Qi rig's model (compensation "model", all
effects on, chord geometry), three simulated EPOS4, the DriveGroup sending RPDO targets + SYNC
each cycle and reading TPDOs, a planar bend and circle repeated as the setpoint (each with its
lead-in from where the previous run ends, made before the timed window; ``--lead-in-in-window``
makes them in the window, as the daemon would). Printed, for the timed window only (start-up and
enabling excluded): cycles, overruns, lateness p50/p99/p99.9/max and histogram, the loop's work
per cycle (wall time per stage, CPU time), garbage-collector passes, this process's CPU use, the
simulated drives' process's CPU use and the SYNC intervals the drives saw, the bus load.

    .venv/bin/python benchmarks/bench_loop.py [--seconds 60] [--rate 1000] [--rt-priority 80]
        [--transport virtual|slcan|slcan-tcp|udp_multicast] [--lead-in-in-window]
    .venv/bin/python benchmarks/bench_loop.py --floor 250 [--seconds 60] [--rt-priority 80]

``--transport virtual`` (default): the simulated drives share this process and its interpreter
lock with the loop (python-can ``virtual`` bus). ``slcan``: the simulated drives run in their own
process (``python -m cdcr_ctl.sim.epos``) behind the slcan adapter emulator on a pseudo-terminal,
as a USB-CAN adapter and real drives would be. ``slcan-tcp``: the same, the emulator on a loopback
TCP port (``--tcp``): bytes written to a pty reach the other process through a kernel worker
thread that a busy machine can delay by tens of ms, loopback TCP hands them over in the writer's
system call. ``udp_multicast`` (needs root for ``ip netns``): the simulated drives in their own
process on python-can's ``udp_multicast`` bus inside a network namespace made for the run with
loopback only (``ip netns add``, ``lo`` up with multicast, 224.0.0.0/4 routed on ``lo``); nothing
leaves the namespace, which is deleted afterwards. With ``--rt-priority P`` the loop asks for
SCHED_FIFO P and mlockall and the simulated drives' process (standing in for drives with their
own processors) for P - 1. ``--floor WORK_US`` runs no loop at all: the loop's ticker with that
much busy work per cycle in one thread, what the machine allows any Python loop.
"""

from __future__ import annotations

import argparse
import atexit
import gc
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import can
import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.control.io import DriveGroupPort
from cdcr_ctl.control.loop import ControlLoop, LoopConfig
from cdcr_ctl.control.ports import NoTension, NoTip
from cdcr_ctl.control.supervisor import Supervisor
from cdcr_ctl.control.timing import Ticker, try_realtime
from cdcr_ctl.drives.busload import cycle_load, pdo_cycle_frames
from cdcr_ctl.drives.group import open_drive_group
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.mcap_sink import McapSinkFactory
from cdcr_ctl.runlog.model_tip import ModelTip
from cdcr_ctl.runlog.writer import RunLogWriter, RunMetadata, new_run_dir
from cdcr_ctl.runlog.writer import spawn as spawn_mod
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
from cdcr_ctl.runlog.writer.spawn import start_writer_process
from cdcr_ctl.sim.epos.rig import SimDriveBus

#: Multicast group of the benchmark's udp_multicast bus (inside its own network namespace).
MCAST = "239.74.163.2"


def sim_child(cfg_path: str, rt_priority: int) -> None:
    """The simulated drives alone in this process, on the udp_multicast bus, until SIGTERM.

    They stand in for drives with their own processors, so they get the loop's real-time priority
    (one below it) when it asks for one."""
    import canopen

    if rt_priority > 0:
        try_realtime(rt_priority - 1, lock_memory=False)

    from cdcr_ctl.sim.epos.node import SimEpos

    cfg = load_rig_config(cfg_path)
    net = canopen.Network(can.Bus(interface="udp_multicast", channel=MCAST))
    net.connect()
    nodes = [SimEpos(net, d.node_id, d.type) for d in cfg.drives]
    for n in nodes:
        n.boot()
    print("ready", flush=True)
    signal.sigwait({signal.SIGTERM, signal.SIGINT})
    net.disconnect()


def in_namespace(argv: list[str]) -> int:
    """Re-run this benchmark inside a fresh loopback-only network namespace."""
    name = f"cdcr-bench-{os.getpid()}"
    steps = [
        ["ip", "netns", "add", name],
        ["ip", "netns", "exec", name, "ip", "link", "set", "lo", "up", "multicast", "on"],
        ["ip", "netns", "exec", name, "ip", "route", "add", "224.0.0.0/4", "dev", "lo"],
    ]
    try:
        for cmd in steps:
            subprocess.run(cmd, check=True)
        env = {**os.environ, "CDCR_BENCH_NETNS": name}
        cmd = ["ip", "netns", "exec", name, sys.executable, __file__, *argv]
        return subprocess.run(cmd, env=env).returncode
    finally:
        subprocess.run(["ip", "netns", "del", name], check=False)


class GcPauses:
    """Collector passes while the benchmark runs (any thread): count and longest, per
    generation, timed with ``time.perf_counter`` from gc.callbacks."""

    def __init__(self) -> None:
        self.count = [0, 0, 0]
        self.max_us = [0.0, 0.0, 0.0]
        self._t0 = 0.0

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
            return
        g = info["generation"]
        self.count[g] += 1
        self.max_us[g] = max(self.max_us[g], (time.perf_counter() - self._t0) * 1e6)

    def text(self) -> str:
        return ", ".join(
            f"gen{g} {n} (max {m:.0f} us)"
            for g, (n, m) in enumerate(zip(self.count, self.max_us, strict=True))
        )


def proc_cpu_s(pid: int) -> float:
    """User + system CPU time (s) of process ``pid`` so far, all its threads (/proc/PID/stat)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def steal_s() -> float:
    """CPU time the hypervisor gave to others while this VM wanted it, all CPUs (s; the 8th
    field of the ``cpu`` line of /proc/stat). It stalls any thread, real-time or not."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def ask_child(child: subprocess.Popen, line: str) -> str:
    """One command to the simulated drives' stdin channel (slcan child), its answer line."""
    assert child.stdin is not None and child.stdout is not None
    child.stdin.write(line + "\n")
    child.stdin.flush()
    return child.stdout.readline().strip()


def floor(args: argparse.Namespace) -> None:
    """What this machine allows a Python loop: the loop's Ticker (same sleep and spin) in one
    thread with ``--floor`` us of busy work per cycle, no bus, no model, no other thread."""
    notes = try_realtime(args.rt_priority, lock_memory=args.rt_priority > 0)
    period = 1.0 / args.rate
    ticker = Ticker(period)
    work_s = args.floor * 1e-6
    steal0 = steal_s()
    end = time.monotonic() + args.seconds
    longest = 0.0
    cycles = 0
    while time.monotonic() < end:
        ticker.wait()
        w0 = time.perf_counter()
        while time.perf_counter() - w0 < work_s:
            pass
        longest = max(longest, time.perf_counter() - w0)
        ticker.done()
        cycles += 1
    s = ticker.stats.summary()
    print(
        f"floor: {args.seconds:.0f} s at {args.rate:.0f} Hz, {args.floor:.0f} us of busy work a "
        f"cycle, one thread, no bus; realtime: {'; '.join(notes) or 'not requested'}"
    )
    print(f"overruns: {s['overruns']}, skipped deadlines: {s['skipped_deadlines']}")
    print(
        f"lateness: p50 {s['lateness_p50_us']} us, p99 {s['lateness_p99_us']} us, "
        f"p99.9 {s['lateness_p99.9_us']} us, max {s['lateness_max_us']} us over {cycles} cycles; "
        f"longest work {longest * 1e6:.0f} us"
    )
    print(f"lateness histogram: {s['lateness_histogram']}")
    print(f"hypervisor steal time meanwhile: {1e3 * (steal_s() - steal0):.0f} ms (/proc/stat)")


def _end_child(child: subprocess.Popen) -> None:
    if child.poll() is None:
        child.terminate()
        try:
            child.wait(10)
        except subprocess.TimeoutExpired:
            child.kill()


class RunLogBench:
    """``--runlog``: a run-log writer attached to the loop (as ``cdcr-ctl log start`` does), the
    CAN traffic to ``can.asc`` (and, with mcap, to ``run.mcap``'s ``/can``), and the log stage of
    every cycle recorded (the stage from the loop's own perf_counter marks)."""

    def __init__(self, args, loop, group, model, work: str) -> None:
        self.kind = args.runlog
        second = McapSinkFactory(ModelTip(model.tip), args.rate) if self.kind == "mcap" else None
        meta = RunMetadata(name=f"bench-{self.kind}", rate_hz=args.rate)
        self.writer_kind = getattr(args, "writer", "thread")
        self.rate = args.rate
        if getattr(args, "writer_nice", None) is not None:
            spawn_mod.WRITER_NICE = args.writer_nice
        if getattr(args, "writer_policy", None) is not None:
            spawn_mod.WRITER_POLICY = args.writer_policy
        if getattr(args, "writer_rt_priority", None) is not None:
            spawn_mod.WRITER_RT_PRIORITY = args.writer_rt_priority
        process = self.writer_kind.startswith("process")
        cls = ProcessRunLogWriter if process else RunLogWriter
        cols = sample_columns(model.n_segments, model.n_cables, LOOP_EXTRA_COLUMNS)
        run_dir = new_run_dir(Path(work) / "runs", meta.name)
        kw = {}
        if self.writer_kind == "process":
            # As the daemon sets it up (cdcr_ctl.daemon.service): the rows go into the ring
            # between the loop's cycles (runlog/writer/handoff.py); "process-direct": on the
            # loop's thread, in its log stage (the writer process before that handoff).
            kw["quiet"] = loop.between_cycles
        if process and getattr(args, "spare_s", 0.0) > 0:
            # As the daemon's factory does: a spare writer process started ahead, its imports
            # done by the time the run starts (the benchmark gives it spare_s seconds).
            kw["process"] = start_writer_process()
            time.sleep(args.spare_s)
        self.writer = cls(run_dir, cols, meta, second_sink=second, **kw)
        self.loop, self.group = loop, group
        self.samples = np.zeros(int(args.seconds * args.rate * 1.5) + 1000)
        self.n = 0
        stages = loop.counters._stages

        def record(marks) -> None:
            stages(marks)
            if self.n < len(self.samples):
                self.samples[self.n] = marks[-1] - marks[-2]  # the "log" stage
                self.n += 1

        loop.counters._stages = record
        # As the daemon does (cdcr_ctl.daemon.service): the traffic log's writer thread formats
        # frames only between the loop's cycles. Read when the traffic log starts.
        if hasattr(group, "traffic_quiet"):
            group.traffic_quiet = loop.between_cycles
        group.log_traffic(self.writer.can_log_path(), self.writer.can_tap)
        loop.attach_sink(self.writer)

    def stop(self) -> None:
        self.loop.attach_sink(None)
        time.sleep(0.1)
        self.group.log_traffic(None)
        self.writer.close("benchmark done")

    def writer_policy(self) -> str:
        """The writer process's scheduling with its run (``spawn.take_realtime``)."""
        rt = getattr(self.writer, "writer_policy", None)
        return rt or f"{spawn_mod.WRITER_POLICY}, nice +{spawn_mod.WRITER_NICE}"

    def report(self, wall: float) -> list[str]:
        log_us = self.samples[100 : self.n] * 1e6  # past the first cycles with the sink attached
        st = self.writer.stats
        run_dir = self.writer.run_dir
        sizes = {p.name: p.stat().st_size for p in run_dir.iterdir() if p.is_file()}
        per_row = {k: v / max(st.written, 1) for k, v in sizes.items()}
        return [
            f"run log ({self.kind}, writer {self.writer_kind}): log stage mean "
            f"{log_us.mean():.1f} us, p50 "
            f"{np.percentile(log_us, 50):.1f}, p99 {np.percentile(log_us, 99):.1f}, p99.9 "
            f"{np.percentile(log_us, 99.9):.1f}, max {log_us.max():.1f} us over {len(log_us)} "
            "cycles",
            f"run log rows: queued {st.queued}, written {st.written}, dropped {st.dropped}, "
            f"lost {st.lost}"
            + (
                f"; ring high-water {self.writer.high_water} rows of {self.writer.max_queued_rows}"
                f" ({self.writer.high_water / self.rate * 1e3:.0f} ms of rows; at the writer's "
                f"first drain {self.writer.start_backlog}; writer process "
                f"{self.writer_policy()})"
                if self.writer_kind.startswith("process")
                else ""
            ),
            "run log size: "
            + ", ".join(
                f"{k} {v / 1e6:.2f} MB = {per_row[k]:.0f} B/row = {per_row[k] * 3.6e6 / 1e6:.0f}"
                " MB/h at 1 kHz"
                for k, v in sizes.items()
            )
            + f" (over {wall:.1f} s, {st.written} rows at {st.written / wall:.0f} rows/s)",
        ]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--rt-priority", type=int, default=0)
    ap.add_argument(
        "--transport",
        choices=("virtual", "slcan", "slcan-tcp", "udp_multicast"),
        default="virtual",
    )
    ap.add_argument(
        "--lead-in-in-window",
        action="store_true",
        help="make each run's lead-in trajectory in the timed window, as the daemon would",
    )
    ap.add_argument(
        "--floor",
        type=float,
        default=None,
        metavar="WORK_US",
        help="no bus and no loop: the same ticker with WORK_US of busy work a cycle in one "
        "thread (what the machine allows a Python loop)",
    )
    ap.add_argument(
        "--runlog",
        choices=("none", "csv", "mcap"),
        default="none",
        help="log every cycle as the daemon does: csv = samples.csv, mcap = samples.csv + "
        "run.mcap (with the CAN frames); prints the log stage's percentiles and bytes per hour",
    )
    ap.add_argument(
        "--writer-nice",
        type=int,
        default=None,
        help="with --writer process: the writer process's nice increment (default: the "
        "daemon's, WRITER_NICE)",
    )
    ap.add_argument(
        "--spare-s",
        type=float,
        default=0.0,
        help="with --writer process: start the writer process this long before the run, as "
        "the daemon keeps a spare (0: started with the run)",
    )
    ap.add_argument(
        "--writer-policy",
        choices=("SCHED_BATCH", "SCHED_OTHER"),
        default=None,
        help="with --writer process: its scheduling policy (default: the daemon's)",
    )
    ap.add_argument(
        "--writer-rt-priority",
        type=int,
        default=None,
        help="with --writer process and --rt-priority: the writer process's SCHED_FIFO "
        "priority with its run (default: the daemon's, WRITER_RT_PRIORITY; 0: it stays off "
        "real time, at --writer-policy)",
    )
    ap.add_argument(
        "--writer",
        choices=("process", "process-direct", "thread"),
        default="process",
        help="with --runlog: encode and write in a writer process fed through shared memory "
        "(logging.writer: process, the default; the rows stored into it between the loop's "
        "cycles, as the daemon does), the same storing them on the loop's thread "
        "(process-direct, the writer before that), or in a thread of this process (the old "
        "writer)",
    )
    ap.add_argument(
        "--backlash-mm",
        type=float,
        default=0.3,
        help="lost motion per cable in the loop's model (robot.cables[].backlash_mm), so the model "
        "stage includes the dead-zone compensation with its direction memory (0: without)",
    )
    ap.add_argument("--sim-child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.floor is not None:
        floor(args)
        return
    if args.sim_child:
        sim_child(args.sim_child, args.rt_priority)
        return
    if args.transport == "udp_multicast" and "CDCR_BENCH_NETNS" not in os.environ:
        sys.exit(in_namespace(sys.argv[1:]))
    period = 1.0 / args.rate
    cfg = load_rig_config("config/qi2023.yaml")
    cables = [c.model_copy(update={"backlash_mm": args.backlash_mm}) for c in cfg.robot.cables]
    cfg = cfg.model_copy(update={"robot": cfg.robot.model_copy(update={"cables": cables})})
    child = None
    sim = None
    work = tempfile.TemporaryDirectory(prefix="cdcr-bench-")
    if args.transport == "virtual":
        interface, channel = "virtual", "bench"
    elif args.transport == "udp_multicast":
        interface, channel = "udp_multicast", MCAST
        cmd = [sys.executable, __file__, "--sim-child", "config/qi2023.yaml"]
        child = subprocess.Popen(
            [*cmd, "--rt-priority", str(args.rt_priority)], stdout=subprocess.PIPE, text=True
        )
    else:
        interface, channel = "slcan", str(Path(work.name) / "can")
        nodes = [f"--node={d.node_id}:{d.type}" for d in cfg.drives]
        where_to = ["--tcp"] if args.transport == "slcan-tcp" else ["--link", channel]
        cmd = [sys.executable, "-m", "cdcr_ctl.sim.epos", *where_to, *nodes]
        if args.rt_priority > 0 and shutil.which("chrt"):
            cmd = ["chrt", "-f", str(args.rt_priority - 1), *cmd]
        child = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    if child is not None:
        # Whatever happens from here (a drive fault at enable, Ctrl-C), the child goes too.
        atexit.register(_end_child, child)
        assert child.stdout is not None
        first = child.stdout.readline().strip()
        if not first:
            sys.exit(f"the simulated drives did not start ({' '.join(cmd)})")
        if args.transport == "slcan-tcp":
            channel = first  # socket://127.0.0.1:PORT
    can_cfg = cfg.can.model_copy(
        update={
            "interface": interface,
            "channel": channel,
            "sync_period_s": period,
            # The same latency allowance as the simulated rig's config (config/qi2023-sim.yaml):
            # simulated drives in another process behind a pty or a socket, or in this one
            # sharing its interpreter lock with the loop, answer later than real ones.
            "feedback_timeout_s": 0.25,
        }
    )
    cfg = cfg.model_copy(update={"can": can_cfg})
    if args.transport == "virtual":
        # Made before the loop asks for real-time priority: the simulated drives' threads stay
        # time-shared (they share this interpreter's lock with the loop).
        sim = SimDriveBus(cfg, "virtual", "bench").start()
    by = {d.cable: d for d in cfg.drives}
    drives = [by[c.name] for c in cfg.robot.cables]
    # Before the group's threads exist, so they inherit it: a lower-priority thread holding the
    # interpreter lock would otherwise block the loop (priority inversion through the GIL).
    notes = try_realtime(args.rt_priority, lock_memory=args.rt_priority > 0)
    group = open_drive_group(cfg.can, drives)
    model = build_model(cfg)
    port = DriveGroupPort(group)
    loop = ControlLoop(
        LoopConfig(period, np.array([d.counts_per_mm for d in drives]), "model", 40.0),
        model,
        port,
        NoTension(3),
        NoTip(),
        Supervisor(cfg.limits),
    )
    loop.start()
    group.enable()
    bend = tj.planar_bend(theta_max_rad=1.2, back=True)
    circle = tj.spatial_circle(theta_rad=0.6)
    # Each run with its lead-in from where the previous one ends, made before the timed window
    # (a trajectory is made in the caller's thread; see readme-6 for what making one costs the
    # loop when it happens while the loop runs).
    first = tj.with_lead_in(loop.psi_cmd, bend)
    to_circle = tj.with_lead_in(bend.psi[-1], circle)
    to_bend = tj.with_lead_in(circle.psi[-1], bend)
    plan = [first, to_circle] if not args.lead_in_in_window else [bend, circle]
    if args.transport.startswith("slcan") and child is not None:
        ask_child(child, "reset-stats")
    runlog = RunLogBench(args, loop, group, model, work.name) if args.runlog != "none" else None
    gc_pauses = GcPauses()
    gc.callbacks.append(gc_pauses)
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    child_cpu0 = proc_cpu_s(child.pid) if child is not None else 0.0
    steal0 = steal_s()
    t0 = time.monotonic()
    c0 = loop.counters.cycles
    # Timing statistics of the timed window only (start-up and enabling excluded).
    loop.ticker.reset_stats()
    loop.counters.reset_timing()
    assert loop._thread is not None and loop._thread.ident is not None
    loop_clock = time.pthread_getcpuclockid(loop._thread.ident)
    loop_cpu0 = time.clock_gettime(loop_clock)
    while time.monotonic() - t0 < args.seconds:
        for traj in plan:
            if args.lead_in_in_window:
                traj = tj.with_lead_in(loop.psi_cmd, traj)
            run = loop.follow(traj, "bench", "model")
            while run.state == "running" and time.monotonic() - t0 < args.seconds:
                time.sleep(0.05)
            if time.monotonic() - t0 >= args.seconds:
                break
        if not args.lead_in_in_window:
            plan = [to_bend, to_circle]
    wall = time.monotonic() - t0
    stolen = steal_s() - steal0
    loop_cpu = time.clock_gettime(loop_clock) - loop_cpu0
    gc.callbacks.remove(gc_pauses)
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    child_cpu = proc_cpu_s(child.pid) - child_cpu0 if child is not None else float("nan")
    drive_stats = (
        json.loads(ask_child(child, "stats").removeprefix("ok "))
        if args.transport.startswith("slcan") and child is not None
        else None
    )
    cycles = loop.counters.cycles - c0
    if runlog is not None:
        runlog.stop()
    loop.stop()
    s = loop.ticker.stats.summary()
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    fault = group.first_fault()
    group.close()
    if sim is not None:
        sim.stop()
    if child is not None:
        _end_child(child)
    runlog_text = runlog.report(wall) if runlog is not None else []
    work.cleanup()
    load = cycle_load(pdo_cycle_frames(3), period, cfg.can.bitrate)
    where = {
        "virtual": "in this process on a python-can virtual bus",
        "slcan": "in another process behind the slcan adapter emulator on a pty",
        "slcan-tcp": "in another process behind the slcan adapter emulator on loopback TCP",
        "udp_multicast": "in another process on udp_multicast in a loopback-only network namespace",
    }[args.transport]
    print(
        f"loop benchmark: {args.seconds:.0f} s at {args.rate:.0f} Hz, compensation 'model' "
        f"(Qi rig, all effects, chord geometry), 3 simulated EPOS4 {where}, "
        f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs"
    )
    print(f"realtime: {'; '.join(notes) or 'not requested (SCHED_OTHER)'}")
    print(f"cycles run: {cycles} in {wall:.1f} s = {cycles / wall:.1f} Hz achieved")
    print(f"overruns: {s['overruns']}, skipped deadlines: {s['skipped_deadlines']}")
    print(
        f"lateness (cycle start after its absolute deadline, time.monotonic): "
        f"p50 {s['lateness_p50_us']} us, p99 {s['lateness_p99_us']} us, "
        f"p99.9 {s['lateness_p99.9_us']} us, max {s['lateness_max_us']} us "
        f"(percentiles over the last {min(s['cycles'], 65536)} cycles, max over all)"
    )
    print(f"lateness histogram: {s['lateness_histogram']}")
    print(
        f"loop cycle work: max {loop.counters.max_cycle_us:.0f} us (wall); CPU "
        f"{loop.counters.work_cpu_us():.0f} us per cycle in the work (time.thread_time), "
        f"{1e6 * loop_cpu / max(cycles, 1):.0f} us per cycle with waiting and spinning "
        "(the thread's CPU clock)"
    )
    print(
        "loop stages (wall time, time.perf_counter marks in the loop): mean "
        + ", ".join(f"{k} {v:.0f}" for k, v in loop.counters.stage_mean_us().items())
        + " us; max "
        + ", ".join(f"{k} {v:.0f}" for k, v in loop.counters.stage_max_us.items())
        + " us"
    )
    for line in runlog_text:
        print(line)
    print(f"garbage collector passes: {gc_pauses.text()}")
    print(f"process CPU use: {100 * cpu / wall:.0f} % of one core (this process only)")
    if child is not None:
        print(
            f"simulated drives' process CPU use: {100 * child_cpu / wall:.0f} % of one core "
            "(/proc/PID/stat)"
        )
    if drive_stats:
        for st in drive_stats:
            iv = {
                k: None if v is None else round(v * 1e6) for k, v in st["sync_interval_s"].items()
            }
            print(
                f"node {st['node']}: {st['syncs']} SYNCs seen, {st['missed_setpoints']} set-points "
                f"missed, SYNC interval at the drive p50/p99/p99.9/max {iv['p50']}/{iv['p99']}/"
                f"{iv['p99.9']}/{iv['max']} us"
            )
    print(f"bus load of the PDO set: {load}")
    print(f"hypervisor steal time meanwhile: {1e3 * stolen:.0f} ms (/proc/stat, both CPUs)")
    print(f"drive faults: {fault}")


if __name__ == "__main__":
    main()
