"""Benchmark: the 1 kHz loop's log stage split into its parts, and what changes it (issue #23).

Runs ``benchmarks/bench_loop.py`` (of this checkout, or of ``--root DIR``, e.g. a worktree of an
older commit, with its own ``.venv``: run this file with that interpreter) in this process, with
``time.perf_counter`` marks around the parts of the loop's log stage, and prints after
``bench_loop.py``'s own report, over the timed window (mean / p50, us):

- ``q_act``: the drives' positions to mm (``ControlLoop._q_act_mm``),
- ``row``: the cycle's row (``ControlLoop._row``: one ``numpy.concatenate``, the ``CycleRow``),
- ``write``: the run-log writer's ``write`` (thread writer: a ``deque.append``; process writer:
  the ring store, or with the handoff a ``deque.append``),
- ``rest``: the stage's remainder (the failure check, the run's row counters, the wrappers'
  own calls).

Diagnostic switches (each changes what is measured; none is how the daemon runs):

- ``--pause-writer``: the writer process stopped (SIGSTOP) and continued every other second;
  the parts are printed for the cycles of each state (does the writer process's work on the other
  core slow the loop?);
- ``--no-traffic``: no CAN traffic log (does its thread's interpreter lock land in the stage?);
- ``--hot-slot N``: the process writer (``--writer process-direct``) stores every row into the
  ring's first N slots (16: always in the cache) instead of its next slot: the rows written are
  wrong, only the store's time counts (is it the ring's memory or the interpreter?). ``0``: the
  same wrapper around the store, the real slot (the control run).

    .venv/bin/python benchmarks/bench_runlog_split.py [--pause-writer] [--no-traffic] [--hot-slot]
        [--root DIR] -- --runlog csv --seconds 12 --rt-priority 80 --transport slcan \
        --writer process-direct --spare-s 3
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

PARTS = ("q_act", "row", "write", "rest")


def patch(bl, opts: argparse.Namespace) -> None:
    """Wrap ``bench_loop.RunLogBench`` so that it records the parts of every cycle's log stage."""
    init0, report0 = bl.RunLogBench.__init__, bl.RunLogBench.report

    def init(self, args, loop, group, model, work) -> None:
        if opts.no_traffic:
            group.log_traffic = lambda *a, **k: None
        init0(self, args, loop, group, model, work)
        n = len(self.samples)
        self.parts = np.zeros((n, len(PARTS)))
        self.paused = np.zeros(n, bool)
        state = {"paused": False}
        cur = [0.0, 0.0, 0.0]
        pc = time.perf_counter
        q_act0, row0, write0 = loop._q_act_mm, loop._row, self.writer.write

        def q_act(fb):
            t = pc()
            out = q_act0(fb)
            cur[0] = pc() - t
            return out

        def row(*a):
            t = pc()
            out = row0(*a)
            cur[1] = pc() - t
            return out

        def write(r):
            t = pc()
            ok = write0(r)
            cur[2] = pc() - t
            return ok

        loop._q_act_mm, loop._row, self.writer.write = q_act, row, write
        record0 = loop.counters._stages

        def record(marks) -> None:
            i = self.n
            record0(marks)
            if i < n:
                self.parts[i, :3] = cur
                self.parts[i, 3] = (marks[-1] - marks[-2]) - sum(cur)
                self.paused[i] = state["paused"]

        loop.counters._stages = record
        proc = getattr(self.writer, "_proc", None)
        if opts.pause_writer and proc is not None:

            def toggle() -> None:
                time.sleep(1.0)
                while not self.writer._closing:
                    os.kill(proc.pid, signal.SIGSTOP)
                    state["paused"] = True
                    time.sleep(1.0)
                    state["paused"] = False
                    os.kill(proc.pid, signal.SIGCONT)
                    time.sleep(1.0)

            threading.Thread(target=toggle, daemon=True).start()

    def report(self, wall: float) -> list[str]:
        out = report0(self, wall)
        sl = slice(100, self.n)
        parts, total, paused = self.parts[sl] * 1e6, self.samples[sl] * 1e6, self.paused[sl]

        def line(mask: np.ndarray, label: str) -> None:
            if not mask.any():
                return
            p = parts[mask]
            out.append(
                f"log stage split, {label} ({int(mask.sum())} cycles; mean/p50 us): total "
                f"{total[mask].mean():.1f}/{np.percentile(total[mask], 50):.1f}, p99.9 "
                f"{np.percentile(total[mask], 99.9):.1f}; "
                + ", ".join(
                    f"{k} {p[:, j].mean():.1f}/{np.percentile(p[:, j], 50):.1f}"
                    for j, k in enumerate(PARTS)
                )
            )

        line(np.ones(len(paused), bool), "all")
        if opts.pause_writer:
            line(paused, "writer process stopped")
            line(~paused, "writer process running")
        return out

    bl.RunLogBench.__init__, bl.RunLogBench.report = init, report


def hot_slot(n: int) -> None:
    """``--hot-slot N``: the process writer's store into slot ``head % N`` (see the docstring;
    the ring's size swapped for the store only, on the loop's thread: ``process-direct``)."""
    from cdcr_ctl.runlog.writer import process

    store0 = process.ProcessRunLogWriter._store

    def store(self, row, head):
        cap = self._cap
        self._cap = n or cap
        try:
            return store0(self, row, head)
        finally:
            self._cap = cap

    process.ProcessRunLogWriter._store = store


def main() -> None:
    ap = argparse.ArgumentParser(usage=__doc__.split("\n\n")[-1])
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--pause-writer", action="store_true")
    ap.add_argument("--no-traffic", action="store_true")
    ap.add_argument("--hot-slot", type=int, default=None, metavar="N")
    opts, rest = ap.parse_known_args()
    rest = [a for a in rest if a != "--"]
    root = Path(opts.root).resolve()
    sys.path.insert(0, str(root / "benchmarks"))
    sys.path.insert(0, str(root))
    os.chdir(root)
    import bench_loop

    patch(bench_loop, opts)
    if opts.hot_slot is not None:
        hot_slot(opts.hot_slot)
    sys.argv = [str(root / "benchmarks/bench_loop.py"), *rest]
    bench_loop.main()


if __name__ == "__main__":
    main()
