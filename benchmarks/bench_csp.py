"""Benchmark: 3 simulated EPOS4 tracking a 1 kHz CSP trajectory over the virtual bus.

The master (DriveGroup) sends, every 1 ms on absolute monotonic deadlines, the three RPDO1 targets
of a 0.5 Hz sine (+-20000 counts) and the SYNC; the simulated nodes apply the target at the SYNC,
step their position loop and answer with TPDO1. Printed: achieved cycle rate, SYNCs sent vs
SYNCs seen by each node (a missed SYNC is one sent and not seen), SYNC period jitter at the
nodes (percentiles of |interval - 1 ms|), the final tracking error and the bus load of the PDO set.

    .venv/bin/python benchmarks/bench_csp.py [--seconds 10] [--rate 1000]
"""

from __future__ import annotations

import argparse
import math
import time

import can
import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.control.timing import Ticker
from cdcr_ctl.drives.busload import cycle_load, pdo_cycle_frames
from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.sim.epos.rig import SimDriveBus


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    args = ap.parse_args()
    period = 1.0 / args.rate
    cfg = load_rig_config("config/qi2023.yaml")
    can_cfg = cfg.can.model_copy(
        update={"interface": "virtual", "channel": "csp", "sync_period_s": period}
    )
    cfg = cfg.model_copy(update={"can": can_cfg})
    sim = SimDriveBus(cfg, "virtual", "csp").start()
    drives = list(cfg.drives)
    group = DriveGroup(can.Bus(interface="virtual", channel="csp"), cfg.can, drives)
    group.boot()
    group.configure()
    ticker = Ticker(period)
    for _ in range(20):  # SYNCs flowing so the 402 walk gets feedback
        ticker.wait()
        group.send_cycle([0, 0, 0])
        ticker.done()
    import threading

    stop = threading.Event()

    def keep_syncing() -> None:
        while not stop.is_set():
            group.send_cycle([0, 0, 0])
            time.sleep(period)

    th = threading.Thread(target=keep_syncing)
    th.start()
    group.enable()
    stop.set()
    th.join()
    for n in sim.nodes:
        n.sync_times = []
    sent0 = group.sync_count
    ticker = Ticker(period)
    t0 = time.monotonic()
    n = 0
    errs = []
    while time.monotonic() - t0 < args.seconds:
        ticker.wait()
        t = n * period
        target = int(20000 * math.sin(2 * math.pi * 0.5 * t))
        group.send_cycle([target, -target // 2, -target // 2])
        if n % 100 == 0:
            fb = group.feedback()[0].position_counts
            errs.append(abs(fb - target))
        n += 1
        ticker.done()
    wall = time.monotonic() - t0
    time.sleep(0.05)
    sent = group.sync_count - sent0
    seen = [len(node.sync_times) for node in sim.nodes]
    intervals = np.concatenate([np.diff(node.sync_times) for node in sim.nodes])
    jitter_us = np.abs(intervals - period) * 1e6
    fault = group.first_fault()
    group.close()
    sim.stop()
    s = ticker.stats.summary()
    load = cycle_load(pdo_cycle_frames(3), period, cfg.can.bitrate)
    print(
        f"CSP benchmark: 3 simulated EPOS4, python-can virtual bus, {args.seconds:.0f} s at "
        f"{args.rate:.0f} Hz (master on absolute time.monotonic deadlines)"
    )
    print(
        f"cycles: {n} in {wall:.2f} s = {n / wall:.1f} Hz achieved; overruns {s['overruns']}, "
        f"skipped deadlines {s['skipped_deadlines']}"
    )
    print(
        f"SYNC sent {sent}; seen per node {seen}; missed on the drive side: "
        f"{[sent - k for k in seen]}"
    )
    p = np.percentile(jitter_us, [50, 99, 99.9])
    print(
        f"SYNC period jitter at the nodes |interval - {period * 1e3:g} ms|: p50 {p[0]:.0f} us, "
        f"p99 {p[1]:.0f} us, p99.9 {p[2]:.0f} us, max {jitter_us.max():.0f} us "
        f"({len(intervals)} intervals)"
    )
    print(
        f"master lateness: p50 {s['lateness_p50_us']} us, p99 {s['lateness_p99_us']} us, "
        f"max {s['lateness_max_us']} us"
    )
    print(
        f"tracking |actual - target| of node 1 (sampled every 100 cycles): median "
        f"{np.median(errs):.0f} counts, max {max(errs)} counts"
        " (the TPDO reports the position one cycle late)"
    )
    print(f"bus load: {load}")
    print(f"faults: {fault}")


if __name__ == "__main__":
    main()
