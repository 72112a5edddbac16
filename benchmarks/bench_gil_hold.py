"""How long the rig process's command work keeps the interpreter lock from the loop (issue #21).

Run: ``chrt -f 50 .venv/bin/python benchmarks/bench_gil_hold.py [REPEATS]`` (about 30 s; without
``chrt`` the probe measures the scheduler as much as the lock).

How measured: in one process, as in the rig process, the interpreter's switch interval is the
loop's (``GIL_SWITCH_INTERVAL_S``, 50 us) and the heap is frozen (``gc.freeze()``); a probe
thread one real-time priority step above the process (as the loop thread) sleeps 0.2 ms in a
loop and records how late each sleep returns: to return it needs the interpreter lock, so its
worst lateness while the main thread does one piece of work is that work's longest hold of the
lock (plus the probe's own wake-up latency: the line ``nothing`` measures that alone). After
each wake-up the probe releases the lock PROBE_RELEASES times, as a loop cycle does at its bus
writes; the worst time those took ("10 releases") is what a busy thread adds to a cycle even
when it never holds the lock long (it takes it at each release). Each piece
of work runs REPEATS times (default 5); printed: its median wall time and the worst lateness of
the probe over all repeats. Each "before" line runs the way the code did it before issue #21's
fixes, on the same data:

- a lead-in's planning (``plan_lead``, 400 model commands in mode ``measured``) in the process,
  against the same plan from the planner worker (``cdcr_ctl.daemon.planner``: the command thread
  waits on a pipe);
- a jog move's planning (0.05 rad/s over 0.5 rad: 3,142 samples) likewise;
- a new run-log ring's pages touched by one bulk store, against 64 KB slices
  (``SharedRing.create``);
- a run log made by the factory (ring, first files, the writer process's settings, the next
  spare started), as ``trajectory --log`` does;
- a trajectory of 10,000 and 50,000 samples made from arrays (``Trajectory``): nested lists in
  one ``tolist`` each, against flat lists a slice at a time.
"""

from __future__ import annotations

import gc
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.control.loop import GIL_SWITCH_INTERVAL_S
from cdcr_ctl.daemon.planner import Planner
from cdcr_ctl.daemon.planning import plan_jog, plan_lead
from cdcr_ctl.runlog.columns import TEXT_COLUMNS, sample_columns
from cdcr_ctl.runlog.writer.factory import RunLogFactory
from cdcr_ctl.runlog.writer.process import DEFAULT_CAN_FRAMES
from cdcr_ctl.runlog.writer.ring import RingLayout, SharedRing

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "qi2023-sim.yaml"
#: The probe's sleep (s).
PROBE_SLEEP_S = 0.0002
#: Times the probe releases the lock after each wake-up (``time.sleep(0)``), as the loop's
#: cycle does at each bus write and read: with another thread busy in Python, each release can
#: cost up to a switch interval before the lock comes back (the convoy the loop's long cycles
#: showed: 40-170 context switches in one cycle).
PROBE_RELEASES = 10


class Probe:
    """A thread sleeping PROBE_SLEEP_S in a loop; :meth:`measure` runs work and returns the
    probe's worst lateness (s) meanwhile."""

    def __init__(self) -> None:
        self.worst = self.worst_cycle = 0.0
        self.on = False
        threading.Thread(target=self._run, daemon=True).start()
        time.sleep(0.05)

    def _run(self) -> None:
        try:
            policy = os.sched_getscheduler(0)
            if policy in (os.SCHED_FIFO, os.SCHED_RR):
                prio = os.sched_getparam(0).sched_priority + 1
                os.sched_setscheduler(0, policy, os.sched_param(prio))
        except OSError:
            pass
        while True:
            t = time.perf_counter()
            time.sleep(PROBE_SLEEP_S)
            t1 = time.perf_counter()
            for _ in range(PROBE_RELEASES):
                time.sleep(0)  # releases the lock, as each of the loop's bus writes does
            t2 = time.perf_counter()
            if self.on:
                self.worst = max(self.worst, t1 - t - PROBE_SLEEP_S)
                self.worst_cycle = max(self.worst_cycle, t2 - t1)

    def measure(self, name: str, work, repeats: int) -> None:
        walls, worst, worst_cycle = [], 0.0, 0.0
        for _ in range(repeats):
            time.sleep(0.02)
            self.worst = self.worst_cycle = 0.0
            self.on = True
            t = time.perf_counter()
            work()
            walls.append(time.perf_counter() - t)
            time.sleep(0.002)
            self.on = False
            worst, worst_cycle = max(worst, self.worst), max(worst_cycle, self.worst_cycle)
        print(
            f"{name:58s} wall {statistics.median(walls) * 1e3:7.2f} ms"
            f"  longest hold {worst * 1e3:5.2f} ms  {PROBE_RELEASES} releases"
            f" {worst_cycle * 1e3:5.2f} ms",
            flush=True,
        )


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    cfg = load_rig_config(CONFIG)
    model = build_model(cfg, source=str(CONFIG))
    v, bend = cfg.limits.cable_velocity_mm_s, cfg.limits.bend_rad
    planner = Planner(CONFIG).start()
    tmp = Path(tempfile.mkdtemp(prefix="cdcr-gil-"))
    factory = RunLogFactory.from_config(cfg, CONFIG, base_dir=tmp, tip_from_psi=model.tip)
    numbers = [
        c
        for c in sample_columns(model.n_segments, model.n_cables, factory.extra_columns)
        if c not in TEXT_COLUMNS
    ]
    layout = RingLayout(len(numbers), factory.max_queued_rows, DEFAULT_CAN_FRAMES)
    gc.freeze()
    policy = os.sched_getscheduler(0)
    print(
        f"policy {'SCHED_FIFO/RR' if policy in (os.SCHED_FIFO, os.SCHED_RR) else 'SCHED_OTHER'},"
        f" switch interval {sys.getswitchinterval() * 1e6:.0f} us, {repeats} repeats,"
        f" load {os.getloadavg()[0]:.1f}"
    )
    probe = Probe()
    probe.measure("nothing (the probe's own wake-up)", lambda: time.sleep(0.01), repeats)

    psi_now, first = np.array([[0.4, 0.3]]), np.array([[0.1, -1.0]])
    state = model.new_state()
    q_now = model.q_command(psi_now, model.q_nominal(psi_now), state, "off", None)
    force = np.full(model.n_cables, 5.0)
    args = (psi_now, q_now, first, "measured", v)
    probe.measure(
        "lead-in plan, before: in this process",
        lambda: plan_lead(model, *args, force, state),
        repeats,
    )
    probe.measure(
        "lead-in plan, after: planner worker",
        lambda: planner.lead(*args, bend, force, state),
        repeats,
    )
    start, goal = np.zeros((1, 2)), np.array([[0.5, 0.0]])
    probe.measure(
        "jog plan (3,142 samples), before: in this process",
        lambda: plan_jog(model, start, goal, 0.05, "model", v),
        repeats,
    )
    probe.measure(
        "jog plan (3,142 samples), after: planner worker",
        lambda: planner.jog(start, goal, 0.05, "model", v, bend),
        repeats,
    )

    def bulk_ring() -> None:
        fd = os.memfd_create("cdcr-bench", 0)
        os.ftruncate(fd, layout.size)
        ring = SharedRing(layout, fd)
        ring.hdr[:] = 0
        ring.nums[:] = 0.0
        ring.can[:] = bytes(len(ring.can))
        os.close(fd)

    def sliced_ring() -> None:
        SharedRing.create(layout).close()

    mb = (layout.events_offset + layout.size - layout.can_offset) / 1e6
    probe.measure(f"run-log ring ({mb:.1f} MB touched), before: one bulk store", bulk_ring, repeats)
    probe.measure(f"run-log ring ({mb:.1f} MB touched), after: 64 KB slices", sliced_ring, repeats)
    writers = []
    probe.measure(
        "run log from the factory (ring, files, writer, next spare)",
        lambda: writers.append(factory("bench", "model")),
        repeats,
    )
    for w in writers:
        w.close("benchmark", wait=False)
    for n in (10_000, 50_000):
        t = np.arange(n) * 0.01
        psi = np.zeros((n, model.n_segments, 2))
        psi[:, :, 0] = 0.3

        def nested(t=t, psi=psi) -> None:
            tr = tj.Trajectory(t[:2], psi[:2])
            tr._tl, tr._xl, tr._pl = t.tolist(), tj.bend_vectors(psi).tolist(), psi.tolist()

        probe.measure(f"trajectory of {n} samples, before: nested lists", nested, repeats)
        probe.measure(
            f"trajectory of {n} samples, after: flat lists in slices",
            lambda t=t, psi=psi: tj.Trajectory(t, psi),
            repeats,
        )
    for w in writers:
        w.wait_closed(10)
    planner.close()
    print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
