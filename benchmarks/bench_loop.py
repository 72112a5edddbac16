"""Benchmark: the real-time loop at the rate the bus allows, compensation on, for N seconds.

What runs: the control loop (ControlLoop) with the Qi rig's model (compensation "model", all
effects on, chord geometry), three simulated EPOS4 on a python-can virtual bus in this process,
the DriveGroup sending RPDO targets + SYNC each cycle and reading TPDOs, a planar bend and circle
repeated as the setpoint. Printed: cycles, overruns, lateness p50/p99/max, the loop thread's
CPU time per cycle, the process CPU use, and the bus load of the PDO set.

    .venv/bin/python benchmarks/bench_loop.py [--seconds 60] [--rate 1000] [--rt-priority 80]
        [--transport virtual|slcan|udp_multicast]

``--transport virtual`` (default): the simulated drives share this process and its interpreter
lock with the loop (python-can ``virtual`` bus). ``slcan``: the simulated drives run in their own
process (``python -m cdcr_ctl.sim.epos``) behind the slcan adapter emulator on a pseudo-terminal,
as a USB-CAN adapter and real drives would be. ``udp_multicast`` (needs root for ``ip netns``): the
simulated drives in their own process on python-can's ``udp_multicast`` bus inside a network
namespace made for the run with loopback only (``ip netns add``, ``lo`` up with multicast,
224.0.0.0/4 routed on ``lo``); nothing leaves the namespace, which is deleted afterwards.
With ``--rt-priority P`` the loop asks for SCHED_FIFO P and mlockall and the simulated drives'
process (standing in for drives with their own processors) for P - 1.
"""

from __future__ import annotations

import argparse
import atexit
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
from cdcr_ctl.control.timing import try_realtime
from cdcr_ctl.drives.busload import cycle_load, pdo_cycle_frames
from cdcr_ctl.drives.group import open_drive_group
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


def _end_child(child: subprocess.Popen) -> None:
    if child.poll() is None:
        child.terminate()
        try:
            child.wait(10)
        except subprocess.TimeoutExpired:
            child.kill()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--rt-priority", type=int, default=0)
    ap.add_argument("--transport", choices=("virtual", "slcan", "udp_multicast"), default="virtual")
    ap.add_argument("--sim-child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.sim_child:
        sim_child(args.sim_child, args.rt_priority)
        return
    if args.transport == "udp_multicast" and "CDCR_BENCH_NETNS" not in os.environ:
        sys.exit(in_namespace(sys.argv[1:]))
    period = 1.0 / args.rate
    cfg = load_rig_config("config/qi2023.yaml")
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
        cmd = [sys.executable, "-m", "cdcr_ctl.sim.epos", "--link", channel, *nodes]
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
    can_cfg = cfg.can.model_copy(
        update={
            "interface": interface,
            "channel": channel,
            "sync_period_s": period,
            # Another process behind a pty or a socket: the same latency allowance as the
            # simulated rig's config (config/qi2023-sim.yaml).
            "feedback_timeout_s": None if args.transport == "virtual" else 0.25,
        }
    )
    cfg = cfg.model_copy(update={"can": can_cfg})
    if args.transport == "virtual":
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
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.monotonic()
    c0 = loop.counters.cycles
    stats0 = loop.ticker.stats.cycles
    while time.monotonic() - t0 < args.seconds:
        for traj in (bend, circle):
            run = loop.follow(tj.with_lead_in(loop.psi_cmd, traj), "bench", "model")
            while run.state == "running" and time.monotonic() - t0 < args.seconds:
                time.sleep(0.05)
            if time.monotonic() - t0 >= args.seconds:
                break
    wall = time.monotonic() - t0
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    cycles = loop.counters.cycles - c0
    loop.stop()
    s = loop.ticker.stats.summary()
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    fault = group.first_fault()
    group.close()
    if sim is not None:
        sim.stop()
    if child is not None:
        _end_child(child)
    work.cleanup()
    load = cycle_load(pdo_cycle_frames(3), period, cfg.can.bitrate)
    where = {
        "virtual": "in this process on a python-can virtual bus",
        "slcan": "in another process behind the slcan adapter emulator on a pty",
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
        f"(over the last {min(s['cycles'] - stats0, 65536)} cycles)"
    )
    print(f"lateness histogram: {s['lateness_histogram']}")
    print(
        f"loop cycle work: max {loop.counters.max_cycle_us:.0f} us; "
        f"loop thread CPU {1e6 * loop.counters.cpu_s / max(cycles, 1):.0f} us per cycle"
    )
    print(f"process CPU use: {100 * cpu / wall:.0f} % of one core (this process only)")
    print(f"bus load of the PDO set: {load}")
    print(f"drive faults: {fault}")


if __name__ == "__main__":
    main()
