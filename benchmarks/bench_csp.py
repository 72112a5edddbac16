"""Cyclic synchronous position with simulated EPOS4 drives: cycle rate, SYNC jitter, bus load.

What it does: starts N simulated EPOS4 nodes (in this process on python-can's ``virtual`` bus, or
in another process behind an slcan pseudo-terminal with ``--transport slcan``), boots,
configures and enables them with :class:`cdcr_ctl.drives.group.DriveGroup`, then streams a
smooth CSP trajectory for ``--seconds`` at ``--rate`` Hz: every cycle builds the RPDOs,
sends them and the SYNC as one burst (``send_cycle``), and sleeps to the next absolute deadline
(``time.sleep``; no busy wait, no real-time priority).

What it prints:

- master: cycles sent, achieved rate, SYNC send intervals (p50/p90/p99/p99.9/max) and their
  deviation from the period (jitter), lateness of the cycle start against its deadline;
- drives: SYNCs each drive saw and the difference to the SYNCs sent (missed SYNC), set-points
  missed (a SYNC with no new target), SYNC arrival intervals on the drive side, TPDOs received
  by the master, the drive's largest following error (counts);
- bus: the worst-case load of the cyclic PDO set (frame bits with stuffing, 135 bits per 8-byte
  frame) at ``--bitrate``, and the load of the frames actually exchanged during the run;
- fault reaction: after the run, ``--fault-trials`` times an EMCY 0x8611 is injected on drive 2
  while cycling; printed are the SYNCs the master sent between seeing the fault and its quick
  stops, and (virtual bus) the SYNCs on the wire between the EMCY frame and the last quick stop.

Run: ``.venv/bin/python benchmarks/bench_csp.py [--seconds 10] [--rate 1000] [--drives 3]
[--transport virtual|slcan]``. Numbers depend on the machine and its load; the script measures,
it asserts nothing.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import can

from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.drives.busload import cycle_load, drive_cycle_frames, frame_bits
from cdcr_ctl.drives.canbus import open_bus
from cdcr_ctl.drives.group import DriveGroup

#: Trajectory: drive j follows A·(-1/2)^j·(1 - cos 2π f t) counts from where it stood (starts at
#: rest; peak speed 2π f A = 62 832 counts/s = 1841 rpm for drive 1 at 2048 counts/rev).
AMPLITUDE_COUNTS = 20_000
FREQUENCY_HZ = 0.5


def percentiles(xs: list[float]) -> dict[str, float]:
    if not xs:
        return {}
    s = sorted(xs)

    def q(p: float) -> float:
        return s[min(len(s) - 1, int(p * len(s)))]

    return {"p50": q(0.5), "p90": q(0.9), "p99": q(0.99), "p99.9": q(0.999), "max": s[-1]}


def fmt_us(d: dict[str, float | None]) -> str:
    return "  ".join(f"{k} {v * 1e6:8.1f} us" for k, v in d.items() if v is not None)


class _Counter(can.Listener):
    """Counts the frames the master sees (TPDOs, heartbeats, EMCY) and their data bytes."""

    def __init__(self) -> None:
        self.bits = 0
        self.frames = 0

    def on_message_received(self, msg: can.Message) -> None:
        self.frames += 1
        self.bits += frame_bits(msg.dlc)


def fault_trials(
    group: DriveGroup, args: argparse.Namespace, period_s: float, inject, spy: can.BusABC | None
) -> tuple[list[int], list[int]]:
    """Inject EMCY 0x8611 on drive 2 while cycling; count SYNCs from the fault to the quick
    stops, as the group saw it and (virtual bus) on the wire."""
    group_side, wire = [], []
    for _ in range(args.fault_trials):
        if group.first_fault() is not None:
            group.reset_faults()
        group.enable()
        hold = [f.position_counts for f in group.feedback()]
        if spy is not None:
            while spy.recv(0) is not None:
                pass
        t0 = time.monotonic()
        k, injected_at = 0, None
        while injected_at is None or k < injected_at + 50:
            deadline = t0 + k * period_s
            if (delay := deadline - time.monotonic()) > 0:
                time.sleep(delay)
            if k == 50:
                inject()
                injected_at = k
            group.send_cycle(hold)
            k += 1
        if group.quick_stop_at_sync is None or group.fault_at_sync is None:
            continue
        group_side.append(group.quick_stop_at_sync - group.fault_at_sync)
        if spy is not None:
            msgs = []
            while (m := spy.recv(0)) is not None:
                msgs.append(m)
            ids = [m.arbitration_id for m in msgs]
            if 0x082 in ids:
                e = ids.index(0x082)
                stops = [
                    i
                    for i, m in enumerate(msgs)
                    if 0x301 <= m.arbitration_id <= 0x300 + args.drives
                    and bytes(m.data) == b"\x02\x00"
                    and i > e
                ]
                if stops:
                    wire.append(ids[e : stops[-1]].count(0x080))
    return group_side, wire


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0, help="SYNC rate, Hz")
    ap.add_argument("--drives", type=int, default=3)
    ap.add_argument("--bitrate", type=int, default=1_000_000)
    ap.add_argument("--transport", choices=("virtual", "slcan"), default="virtual")
    ap.add_argument(
        "--fault-trials",
        type=int,
        default=10,
        help="EMCY faults injected after the run to time the quick-stop reaction",
    )
    args = ap.parse_args(argv)

    period_s = 1.0 / args.rate
    ids = list(range(1, args.drives + 1))
    drives = [
        DriveConfig(
            name=f"m{i}", cable=f"c{i}", node_id=i, counts_per_mm=1238.6, heartbeat_producer_ms=100
        )
        for i in ids
    ]
    proc = None
    sim = None
    tmp = tempfile.TemporaryDirectory()
    if args.transport == "virtual":
        from cdcr_ctl.sim.epos.rig import SimDriveBus

        channel = f"bench-csp-{time.monotonic_ns()}"
        sim = SimDriveBus(drives, "virtual", channel, bitrate=args.bitrate).start()
        bus_cfg = CanBusConfig(
            interface="virtual",
            channel=channel,
            bitrate=args.bitrate,
            sync_period_s=period_s,
            feedback_timeout_s=0.2,
        )
    else:
        link = Path(tmp.name) / "can"
        cmd = [
            sys.executable,
            "-m",
            "cdcr_ctl.sim.epos",
            "--link",
            str(link),
            "--bitrate",
            str(args.bitrate),
        ] + [f"--node={i}:epos4" for i in ids]
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert proc.stdout is not None and proc.stdin is not None
        proc.stdout.readline()
        bus_cfg = CanBusConfig(
            interface="slcan",
            channel=str(link),
            bitrate=args.bitrate,
            sync_period_s=period_s,
            feedback_timeout_s=0.25,
        )

    spy = can.Bus(interface="virtual", channel=bus_cfg.channel) if sim is not None else None

    def inject() -> None:
        if sim is not None:
            sim.node(2).inject_following_error()
        else:
            assert proc is not None and proc.stdin is not None and proc.stdout is not None
            proc.stdin.write("fault 2 0x8611\n")
            proc.stdin.flush()
            proc.stdout.readline()

    def sim_stats() -> list[dict]:
        if sim is not None:
            return sim.stats()
        assert proc is not None and proc.stdin is not None and proc.stdout is not None
        proc.stdin.write("stats\n")
        proc.stdin.flush()
        return json.loads(proc.stdout.readline().removeprefix("ok "))

    counter = _Counter()
    group = DriveGroup(open_bus(bus_cfg), bus_cfg, drives)
    try:
        group.boot()
        group.configure()
        group.enable()
        assert group.network.notifier is not None
        group.network.notifier.add_listener(counter)
        if sim is not None:
            sim.reset_stats()
        else:
            assert proc is not None and proc.stdin is not None and proc.stdout is not None
            proc.stdin.write("reset-stats\n")
            proc.stdin.flush()
            proc.stdout.readline()
        time.sleep(0.05)  # the last TPDOs of the enable phase arrive
        start_pos = [f.position_counts for f in group.feedback()]
        tpdo0 = group.tpdo_counts()
        counter.bits = counter.frames = 0
        sync0 = group.sync_count
        sends: list[float] = []
        late: list[float] = []
        errors: list[float] = []
        n = int(args.seconds * args.rate)
        t0 = time.monotonic()
        for k in range(n):
            deadline = t0 + k * period_s
            now = time.monotonic()
            if now < deadline:
                time.sleep(deadline - now)
                now = time.monotonic()
            late.append(now - deadline)
            t = k * period_s
            c = 1.0 - math.cos(2 * math.pi * FREQUENCY_HZ * t)
            targets = [
                p + round(AMPLITUDE_COUNTS * (-0.5) ** j * c) for j, p in enumerate(start_pos)
            ]
            group.send_cycle(targets)
            sends.append(time.monotonic())
            if k % 10 == 0:
                fb = group.feedback()
                errors.append(
                    max(abs(f.position_counts - tt) for f, tt in zip(fb, targets, strict=True))
                )
        elapsed = sends[-1] - sends[0]
        time.sleep(0.05)
        stats = sim_stats()
        sent = group.sync_count - sync0
        tpdos = [a - b for a, b in zip(group.tpdo_counts(), tpdo0, strict=True)]
        fault = group.first_fault()
        tx_bits = sum(frame_bits(len(data)) for _, data in group.build_cycle(start_pos)) * sent
        rx = counter.bits
        # the injected faults log their frame dumps at ERROR: keep the report readable
        logging.getLogger("cdcr_ctl").setLevel(logging.CRITICAL)
        reaction = fault_trials(group, args, period_s, inject, spy)
    finally:
        group.close()
        if spy is not None:
            spy.shutdown()
        if sim is not None:
            sim.stop()
        if proc is not None:
            proc.terminate()
            proc.wait(10)
        tmp.cleanup()

    intervals = [b - a for a, b in itertools.pairwise(sends)]
    jitter = [abs(x - period_s) for x in intervals]
    load = cycle_load(drive_cycle_frames(drives), period_s, args.bitrate)
    print(
        f"transport {args.transport}, {args.drives} simulated EPOS4 in CSP, "
        f"{args.rate:g} Hz for {args.seconds:g} s, {sys.platform}, python {sys.version.split()[0]}"
    )
    print(
        f"master: {sent} SYNCs in {elapsed:.3f} s = {(len(sends) - 1) / elapsed:.1f} Hz "
        f"(target {args.rate:g} Hz)"
    )
    print(f"  SYNC interval   {fmt_us(percentiles(intervals))}")
    print(
        f"  |jitter|        {fmt_us(percentiles(jitter))}  "
        f"(mean {statistics.mean(jitter) * 1e6:.1f} us)"
    )
    print(f"  cycle lateness  {fmt_us(percentiles(late))}")
    for s in stats:
        gaps = s["sync_interval_s"]
        print(
            f"drive {s['node']}: SYNCs seen {s['syncs']} (missed {sent - s['syncs']}), "
            f"set-points missed {s['missed_setpoints']}, max following error "
            f"{s['max_following_error_counts']} counts"
        )
        print(f"  SYNC arrivals   {fmt_us(gaps)}")
    print(f"master TPDOs received per drive: {tpdos} (of {sent} SYNCs)")
    print(
        f"feedback vs target (|actual - target|, sampled every 10th cycle, includes 1-2 "
        f"periods of feedback delay): max {max(errors):.0f} counts"
    )
    print(f"bus: cyclic PDO set worst case {load}")
    measured = (tx_bits + rx) / (elapsed * args.bitrate)
    print(
        f"bus: frames exchanged during the run (worst-case stuffing): {100 * measured:.1f} % "
        f"of {args.bitrate / 1e3:g} kbit/s ({counter.frames} frames received)"
    )
    print(f"first fault during the run: {fault}")
    g_side, wire = reaction
    if not g_side:
        return 0
    print(
        f"fault reaction ({len(g_side)} EMCY 0x8611 injected at {args.rate:g} Hz): SYNCs sent "
        f"between the master seeing the fault and its quick stops: max {max(g_side)}"
    )
    if wire:
        print(
            f"  on the wire (spy bus): SYNCs between the EMCY frame and the last quick-stop "
            f"frame: {sorted(wire)} (includes time the EMCY waits in the receive queue)"
        )
    return 0


if __name__ == "__main__":
    threading.current_thread().name = "bench"
    sys.exit(main())
