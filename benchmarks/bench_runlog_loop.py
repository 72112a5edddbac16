"""Benchmark: the 1 kHz loop's log stage with and without MCAP, runs interleaved.

Runs ``benchmarks/bench_loop.py --seconds S --runlog KIND`` for each variant in turn, ``--runs``
rounds, the order rotated each round (A B C, B C A, C A B, ...: a load that comes and goes hits
every variant alike, and none always runs first or right after another), and prints per run
(with the 1-minute load average of the machine as the run started, ``/proc/loadavg``) and per
variant (median over the runs, and the range): the loop rate, overruns, and the log stage's mean,
p50, p99, p99.9 (us).

What the log stage is: the wall time (``time.perf_counter``, the loop's own stage marks) of the
loop thread from the end of its send stage to the end of its cycle: the drives' positions to mm,
the row (``CycleRow``: one ``numpy.concatenate`` of the cycle's arrays), the writer's ``write``
(base: a ``deque.append``; process writer: the row's numbers into the shared ring), the check
of the writer's failure flag, and whatever the loop thread waits meanwhile (the interpreter lock
held by another thread of its process, the CPU taken by another process). The loop's side of
the log differs between the variants only in ``write``; the rest of the process differs in who
formats: the writer thread (base, ``-thread``) or the writer process, and the CAN traffic log
(base: the frames formatted on the sending and receiving threads; here by a thread of its own,
between the loop's cycles, as the daemon sets it up).

Each variant runs as its daemon would: the process writer from a spare writer process started
``--spare-s`` before the run (the daemon's factory keeps one ready, so its interpreter start
and imports never fall in a run), the CAN traffic log's thread formatting between cycles.

Variants (``--variants``, comma-separated):

- ``csv-thread``: samples.csv by a writer thread (the writer before the writer process);
- ``mcap-thread``: samples.csv + run.mcap by a writer thread;
- ``csv``, ``mcap``: the same through the writer process (``logging.writer: process``), the
  rows stored into its ring between the loop's cycles as the daemon does
  (``cdcr_ctl/runlog/writer/handoff.py``);
- ``csv-process-direct``, ``mcap-process-direct``: the writer process with the rows stored on
  the loop's thread in its log stage (the writer process before that handoff);
- ``base=DIR``: ``DIR/.venv/bin/python DIR/benchmarks/bench_loop.py --runlog csv`` run from
  ``DIR`` (another checkout, e.g. the main branch before the writer process).

    .venv/bin/python benchmarks/bench_runlog_loop.py [--runs 5] [--seconds 12] [--spare-s 3]
        [--variants base=/work/main,mcap,csv]
"""

from __future__ import annotations

import argparse
import math
import re
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
PATTERNS = {
    "rate_hz": r"= ([0-9.]+) Hz achieved",
    "overruns": r"overruns: ([0-9]+)",
    "mean_us": r"log stage mean ([0-9.]+) us",
    "p50_us": r"log stage mean [0-9.]+ us, p50 ([0-9.]+)",
    "p99_us": r", p99 ([0-9.]+), p99\.9",
    "p999_us": r"p99\.9 ([0-9.]+), max",
    "dropped": r"dropped ([0-9]+), lost",
}


def command(variant: str, args: argparse.Namespace) -> tuple[list[str], Path]:
    common = ["--seconds", str(args.seconds), "--rt-priority", str(args.rt_priority)]
    common += ["--transport", args.transport]
    if variant.startswith("base="):
        root = Path(variant.removeprefix("base=")).resolve()
        py = root / ".venv/bin/python"
        return [str(py), str(root / "benchmarks/bench_loop.py"), "--runlog", "csv", *common], root
    kind, _, writer = variant.partition("-")
    writer = writer or "process"
    cmd = [sys.executable, str(HERE / "benchmarks/bench_loop.py"), "--runlog", kind]
    cmd += [*common, "--writer", writer]
    if writer.startswith("process"):
        cmd += ["--spare-s", str(args.spare_s)]
    return cmd, HERE


def load_1min() -> float:
    """The machine's 1-minute load average now (/proc/loadavg)."""
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


def parse(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for key, pat in PATTERNS.items():
        m = re.search(pat, text)
        out[key] = float(m.group(1)) if m else float("nan")
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--variants", default="csv-thread,mcap")
    ap.add_argument(
        "--spare-s",
        type=float,
        default=3.0,
        help="process-writer variants: their spare writer process starts this long before the "
        "run (as the daemon's factory keeps one ready)",
    )
    ap.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="every variant's loop asks for SCHED_FIFO at this priority (bench_loop.py "
        "--rt-priority; as the rig runs it): other processes' load then cannot preempt it",
    )
    ap.add_argument(
        "--transport",
        default="virtual",
        help="bench_loop.py --transport: virtual (the simulated drives share the loop's "
        "process and interpreter lock) or slcan (their own process behind the slcan adapter "
        "emulator, as drives on a USB-CAN adapter would be)",
    )
    args = ap.parse_args()
    variants = args.variants.split(",")
    results: dict[str, list[dict[str, float]]] = {v: [] for v in variants}
    for n in range(args.runs):
        k = n % len(variants)
        for v in variants[k:] + variants[:k]:
            cmd, cwd = command(v, args)
            load = load_1min()
            proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
            r = {"load1": load, **parse(proc.stdout)}
            results[v].append(r)
            print(f"run {n + 1} {v}: " + ", ".join(f"{k} {x:g}" for k, x in r.items()), flush=True)
            if proc.returncode:
                print(f"  exit status {proc.returncode}: {proc.stderr[-400:]}", flush=True)
    print(
        f"median [min, max] over the runs of {args.seconds:g} s each that ran (a run whose rig "
        "did not start, e.g. a drive's heartbeat lost while enabling, has no numbers):"
    )
    for v, rs in results.items():
        ran = [r for r in rs if not math.isnan(r["mean_us"])]
        if not ran:
            print(f"  {v}: no run completed")
            continue
        parts = [f"runs {len(ran)}"]
        for key in ("load1", *PATTERNS):
            xs = [r[key] for r in ran]
            parts.append(f"{key} {statistics.median(xs):g} [{min(xs):g}, {max(xs):g}]")
        print(f"  {v}: " + ", ".join(parts))


if __name__ == "__main__":
    main()
