"""Where a big trajectory's parsing runs, and what is left in the loop's process (issue #21).

Writes a ROWS-row CSV trajectory (default 10^6) and times, on CLOCK_MONOTONIC:

1. the sample-by-sample path (``trajectory.load_trajectory``): what the daemon's own process would
   spend holding the interpreter if it parsed the file itself;
2. the intake worker's path (numpy's reader + vectorised checks), run in its process;
3. what the daemon's process still does: map the prepared arrays and plan the lead-in.

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_intake.py [ROWS]``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon import intake
from cdcr_ctl.daemon.planning import plan_lead_in

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    rows = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    tmp = Path(tempfile.mkdtemp(prefix="cdcr-intake-bench-"))
    path = tmp / "t.csv"
    t = np.arange(rows) * 1e-3
    theta = 0.3 * (1 - np.cos(2 * np.pi * t / t[-1])) / 2
    np.savetxt(
        path,
        np.column_stack((t, theta, np.zeros(rows))),
        delimiter=",",
        header="t_s,seg1_theta_rad,seg1_phi_rad",
        comments="",
        fmt="%.6f",
    )
    cfg = load_rig_config(ROOT / "config" / "qi2023-sim.yaml")
    model = build_model(cfg)
    bend = cfg.limits.bend_rad

    t0 = time.monotonic()
    tj.load_trajectory(path, n_segments=1, bend_limit_rad=bend)
    t_slow = time.monotonic() - t0

    it = intake.Intake(1, bend).start()
    try:
        t0 = time.monotonic()
        prepared = it.prepare_file(str(path))
        t_worker = time.monotonic() - t0
        t0 = time.monotonic()
        traj = it.load(prepared, "bench")
        t_map = time.monotonic() - t0
        t0 = time.monotonic()
        plan_lead_in(model, np.array([[0.5, 0.2]]), None, traj, "model", 40.0)
        t_plan = time.monotonic() - t0
    finally:
        it.close()
    print(f"{rows} rows, {path.stat().st_size / 1e6:.1f} MB CSV")
    print(f"  sample-by-sample parse + validate (in-process path): {t_slow:7.2f} s")
    print(f"  intake worker (other process, niced):                 {t_worker:7.2f} s")
    print(f"  daemon's process: map prepared arrays:                {t_map:7.3f} s")
    print(f"  daemon's process: plan the lead-in (chained):         {t_plan:7.3f} s")


if __name__ == "__main__":
    main()
