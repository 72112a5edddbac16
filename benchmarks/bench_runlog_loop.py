"""Benchmark: the 1 kHz loop's log stage with and without MCAP, runs interleaved.

Runs ``benchmarks/bench_loop.py --seconds S --runlog KIND`` for each variant in turn, ``--runs``
rounds (A B C A B C ...), so a load that comes and goes hits every variant alike, and prints per
run and per variant (median over the runs): the loop rate, overruns, and the log stage's mean,
p50, p99, p99.9 (us; the loop's own ``time.perf_counter`` marks around the row hand-over).

Variants (``--variants``, comma-separated):

- ``csv-thread``: samples.csv by a writer thread (the writer before the writer process);
- ``mcap-thread``: samples.csv + run.mcap by a writer thread;
- ``csv``, ``mcap``: the same through the writer process (``logging.writer: process``);
- ``base=DIR``: ``DIR/.venv/bin/python DIR/benchmarks/bench_loop.py --runlog csv`` run from
  ``DIR`` (another checkout, e.g. the main branch before the writer process).

    .venv/bin/python benchmarks/bench_runlog_loop.py [--runs 3] [--seconds 12]
        [--variants base=/work/main,mcap,csv]
"""

from __future__ import annotations

import argparse
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


def command(variant: str, seconds: float) -> tuple[list[str], Path]:
    if variant.startswith("base="):
        root = Path(variant.removeprefix("base=")).resolve()
        py = root / ".venv/bin/python"
        return [str(py), str(root / "benchmarks/bench_loop.py"), "--runlog", "csv",
                "--seconds", str(seconds)], root  # fmt: skip
    kind, _, writer = variant.partition("-")
    cmd = [sys.executable, str(HERE / "benchmarks/bench_loop.py"), "--runlog", kind]
    cmd += ["--seconds", str(seconds), "--writer", writer or "process"]
    return cmd, HERE


def parse(text: str) -> dict[str, float]:
    out = {}
    for key, pat in PATTERNS.items():
        m = re.search(pat, text)
        out[key] = float(m.group(1)) if m else float("nan")
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--variants", default="csv-thread,mcap")
    args = ap.parse_args()
    variants = args.variants.split(",")
    results: dict[str, list[dict[str, float]]] = {v: [] for v in variants}
    for n in range(args.runs):
        for v in variants:
            cmd, cwd = command(v, args.seconds)
            proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
            r = parse(proc.stdout)
            results[v].append(r)
            print(f"run {n + 1} {v}: " + ", ".join(f"{k} {x:g}" for k, x in r.items()), flush=True)
            if proc.returncode:
                print(f"  exit status {proc.returncode}: {proc.stderr[-400:]}", flush=True)
    print(f"median over {args.runs} runs of {args.seconds:g} s each:")
    for v, rs in results.items():
        med = {k: statistics.median(r[k] for r in rs) for k in PATTERNS}
        print(f"  {v}: " + ", ".join(f"{k} {x:g}" for k, x in med.items()))


if __name__ == "__main__":
    main()
