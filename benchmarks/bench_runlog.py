"""Benchmark (not a test): run-log and trajectory costs on the real-time path.

Run: ``.venv/bin/python tests/runlog/bench_runlog.py [seconds]``. Prints

1. ``RunLogWriter.write`` cost per row (the loop's side), and the writer thread's throughput;
2. the wake-up lateness of a 1 kHz thread (sleeping to absolute deadlines, as the loop's Ticker
   does) without a log and with a writer formatting and writing its rows (the writer thread
   competes for the GIL);
3. ``load_run`` time for the file written;
4. ``Trajectory.sample`` cost.

Numbers depend on the machine and its load; they are measurements, not claims checked by tests.
"""

from __future__ import annotations

import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.control.trajectory import random_smooth, spatial_circle
from cdcr_ctl.runlog import RunLogWriter, RunMetadata, load_run, sample_columns


def loop_rows(n: int, S: int = 1, K: int = 3) -> list[dict]:
    """Rows shaped like the control loop's (plain floats, an empty event)."""
    rng = np.random.default_rng(0)
    cols = sample_columns(S, K, ("cycle", "lateness_us"))
    rows = []
    for i in range(n):
        row = {c: float(v) for c, v in zip(cols, rng.normal(0, 10, len(cols)), strict=True)}
        row["t_s"], row["cycle"], row["event"] = i * 0.001, i, ""
        rows.append(row)
    return rows


def pct(a_us: np.ndarray) -> str:
    return (
        f"median {np.median(a_us):.0f} us, p99 {np.percentile(a_us, 99):.0f} us, "
        f"p99.9 {np.percentile(a_us, 99.9):.0f} us, max {a_us.max():.0f} us"
    )


def ticking(sink, seconds: float, period_s: float = 0.001) -> np.ndarray:
    proto = loop_rows(1000)
    late: list[float] = []

    def loop() -> None:
        t0 = time.monotonic()
        n = 0
        while n * period_s < seconds:
            deadline = t0 + n * period_s
            now = time.monotonic()
            if deadline > now:
                time.sleep(deadline - now)
            late.append(time.monotonic() - deadline)
            if sink is not None:
                sink.write(dict(proto[n % 1000], t_s=n * period_s, cycle=n))
            n += 1

    th = threading.Thread(target=loop)
    th.start()
    th.join()
    return np.array(late) * 1e6


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    seconds = float(argv[0]) if argv else 5.0
    base = Path(tempfile.mkdtemp(prefix="bench_runlog_"))
    meta = RunMetadata(name="bench")

    n = 120_000
    rows = loop_rows(n)
    w = RunLogWriter.create(base, meta, 1, 3, ("cycle", "lateness_us", "event"), max_queued_rows=n)
    cost = np.empty(n)
    t0 = time.perf_counter()
    for i, row in enumerate(rows):
        a = time.perf_counter_ns()
        w.write(row)
        cost[i] = time.perf_counter_ns() - a
    w.close("done")
    total = time.perf_counter() - t0
    print(
        f"write(): median {np.median(cost):.0f} ns, p99.9 {np.percentile(cost, 99.9):.0f} ns, "
        f"max {cost.max() / 1e3:.0f} us ({n} rows queued back to back)"
    )
    print(f"writer thread: {n} rows on disk after {total:.2f} s = {n / total:.0f} rows/s")
    print(f"  {w.stats}")

    t0 = time.perf_counter()
    run = load_run(w.run_dir)
    size_mb = (w.run_dir / "samples.csv").stat().st_size / 1e6
    print(f"load_run: {len(run)} rows, {size_mb:.1f} MB in {time.perf_counter() - t0:.2f} s")

    print(
        f"1 kHz thread lateness, {seconds:.0f} s each (switch interval "
        f"{sys.getswitchinterval() * 1e3:.1f} ms):"
    )
    print(f"  no log:      {pct(ticking(None, seconds))}")
    w = RunLogWriter.create(base, meta, 1, 3, ("cycle", "lateness_us", "event"))
    print(f"  with writer: {pct(ticking(w, seconds))}")
    w.close("done")
    print(f"  writer stats {w.stats}")

    for traj in (random_smooth(3, 60.0, 1.0, 0.5, seed=1), spatial_circle()):
        ts = np.random.default_rng(1).uniform(0, traj.duration_s, 20_000)
        c = np.empty(ts.size)
        for i, t in enumerate(ts):
            a = time.perf_counter_ns()
            traj.sample(float(t))
            c[i] = time.perf_counter_ns() - a
        print(
            f"Trajectory.sample, {traj.n_segments} segment(s), {traj.n_samples} samples: "
            f"{pct(c / 1e3)}"
        )


if __name__ == "__main__":
    main()
