"""Benchmark (not a test): runtime of ``cdcr-ctl discrepancy`` on a 60 s run at 100 Hz.

Run: ``.venv/bin/python benchmarks/bench_discrepancy.py [--variant backlash] [--jobs 2]
[--run-dir DIR]``. Without ``--run-dir`` it first makes the run with
``scripts/make_discrepancy_runs.py`` (variant ``config/sim/effects/<variant>.yaml``, 60 s at
100 Hz, trajectory ``rich``; not timed), then times :func:`cdcr_ctl.discrepancy.analyse` with
every candidate effect (and pairs), the nonlinear refit and the report with plots.

How measured: wall clock (``time.monotonic``) around analyse + write_report in this process,
with ``jobs`` worker processes for the forward simulations; the process CPU time
(``time.process_time``, this process only) and the 1-minute load average before and after are
printed too, because the machine is shared. The acceptance limit is 120 s.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def make_run(variant: str, out: Path) -> Path:
    spec = importlib.util.spec_from_file_location(
        "make_discrepancy_runs", ROOT / "scripts" / "make_discrepancy_runs.py"
    )
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    return mod.make_run(
        ROOT / "config" / "sim" / "effects" / f"{variant}.yaml",
        out,
        duration_s=60.0,
        rate_hz=100.0,
        trajectory="rich",
        seed=1,
        name=f"bench-{variant}",
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--variant", default="backlash")
    ap.add_argument("--run-dir", type=Path, default=None)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    from cdcr_ctl.discrepancy import analyse
    from cdcr_ctl.discrepancy.report import write_report

    with tempfile.TemporaryDirectory() as tmp:
        run_dir = args.run_dir or make_run(args.variant, Path(tmp))
        load0 = os.getloadavg()[0]
        c0 = time.process_time()
        t0 = time.monotonic()
        res = analyse([run_dir], jobs=args.jobs, progress=True)
        write_report(res, Path(tmp) / "report")
        wall = time.monotonic() - t0
        cpu = time.process_time() - c0
        load1 = os.getloadavg()[0]
    n = len(res.runs[0].t_s)
    print(
        f"run: {run_dir.name}, {n} rows ({res.runs[0].t_s[-1]:.0f} s), "
        f"{len(res.runs[0].sim_idx)} simulated samples"
    )
    print(
        f"candidates: {', '.join(t.name for t in res.terms)} (+ pairs); "
        f"{res.simulations} forward simulations, jobs={args.jobs}"
    )
    print(
        f"verdict: {res.selection.verdict} {res.named or ''}; tip gap "
        f"{res.tip_rms_before_mm:.3f} -> {res.tip_rms_after_mm:.3f} mm "
        f"({100 * res.gap_shrink:.0f} %)"
    )
    print(
        f"wall {wall:.1f} s (limit 120 s), this process CPU {cpu:.1f} s, "
        f"load average {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores"
    )


if __name__ == "__main__":
    main()
