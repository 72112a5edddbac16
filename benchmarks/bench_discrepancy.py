"""Benchmark (not a test): runtime of ``cdcr-ctl discrepancy`` on a 60 s run at 100 Hz.

Run: ``.venv/bin/python benchmarks/bench_discrepancy.py [--variant backlash] [--jobs 2]
[--run-dir DIR]``. Without ``--run-dir`` it first makes the run with
``scripts/make_discrepancy_runs.py`` (variant ``config/sim/effects/<variant>.yaml``, 60 s at
100 Hz, trajectory ``rich``, the generator's default bend and compensation; not timed), then
times :func:`cdcr_ctl.discrepancy.analyse` with every candidate effect (and pairs), the
nonlinear refit and the report with plots.

``--daemon SIM_YAML`` records the run with the REAL processes instead: ``cdcr-ctl sim SIM_YAML``
and ``cdcr-ctl daemon`` (a per-session rig config from :func:`cdcr_ctl.cli.demo.make_session`),
the generator's 60 s ``rich`` trajectory sent over the control socket (the rig config's
compensation mode), the run directory written by the daemon's run-log writer (its loop rate,
its ``cycle`` column, its tracker port), then analysed and timed the same way. E.g.
``config/sim/effects-daemon/backlash.yaml`` (the truth has 0.4 mm of backlash the controller
does not know) or ``config/sim/effects-daemon/none.yaml``. ``--keep DIR`` keeps the run.

How measured: wall clock (``time.monotonic``) around analyse + write_report in this process,
with ``jobs`` worker processes for the forward simulations; the process CPU time
(``time.process_time``, this process only) and the 1-minute load average before and after are
printed too, because the machine is shared. The acceptance limit is 120 s.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _generator():
    spec = importlib.util.spec_from_file_location(
        "make_discrepancy_runs", ROOT / "scripts" / "make_discrepancy_runs.py"
    )
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    return mod


def make_run(variant: str, out: Path, seed: int) -> Path:
    return _generator().make_run(
        ROOT / "config" / "sim" / "effects" / f"{variant}.yaml",
        out,
        duration_s=60.0,
        rate_hz=100.0,
        trajectory="rich",
        seed=seed,
        name=f"bench-{variant}",
    )


def daemon_run(sim_yaml: Path, out: Path, seed: int, duration_s: float = 60.0) -> Path:
    """Record one run through ``cdcr-ctl sim`` + ``cdcr-ctl daemon`` (see module doc)."""
    from cdcr_ctl.cli.demo import make_session, rig_running
    from cdcr_ctl.cli.runwait import follow_run
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.config.build_model import build_cc_disk_model
    from cdcr_ctl.daemon.client import ControlClient

    work = Path(tempfile.mkdtemp(prefix="cdcr-bd-", dir="/tmp"))  # short: socket paths
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    try:
        rig_path, sim_path = make_session(sim_yaml.resolve(), work, runs)
        cfg = load_rig_config(rig_path)
        model = build_cc_disk_model(cfg)
        traj, bend, _ = _generator().trajectory_within_limits(
            cfg, model, "rich", duration_s, None, seed
        )
        sock = work / "control.sock"
        with rig_running(sim_path, rig_path, sock, out):
            res = follow_run(sock, f"{sim_yaml.stem}-daemon", traj.rows(), cfg.control.compensation)
            with ControlClient(sock) as c:
                c.call("disable")
        print(
            f"daemon run {res['log_dir']}: {res['state']} ({res['end_reason']}), bend"
            f" {bend:.3f} rad, compensation {cfg.control.compensation}, loop"
            f" {cfg.control.rate_hz:g} Hz"
        )
        return Path(res["log_dir"])
    finally:
        shutil.rmtree(work, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--variant", default="backlash")
    ap.add_argument("--run-dir", type=Path, default=None)
    ap.add_argument("--daemon", type=Path, default=None, help="simulator YAML: record via daemon")
    ap.add_argument("--keep", type=Path, default=None, help="keep the recorded run here")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    from cdcr_ctl.discrepancy import analyse
    from cdcr_ctl.discrepancy.report import write_report

    with tempfile.TemporaryDirectory() as tmp:
        out = args.keep or Path(tmp)
        if args.run_dir is not None:
            run_dir = args.run_dir
        elif args.daemon is not None:
            run_dir = daemon_run(args.daemon, out, args.seed)
        else:
            run_dir = make_run(args.variant, out, args.seed)
        load0 = os.getloadavg()[0]
        c0 = time.process_time()
        t0 = time.monotonic()
        res = analyse([run_dir], jobs=args.jobs, progress=True)
        write_report(res, Path(tmp) / "report")
        wall = time.monotonic() - t0
        cpu = time.process_time() - c0
        load1 = os.getloadavg()[0]
        report = (Path(tmp) / "report" / "report.txt").read_text()
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
        f"({100 * res.gap_shrink:.1f} %), noise floor {res.tip_noise_floor_mm:.3f} mm"
    )
    print(
        f"wall {wall:.1f} s (limit 120 s), this process CPU {cpu:.1f} s, "
        f"load average {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores"
    )
    if args.keep is not None:
        (args.keep / "report.txt").write_text(report)


if __name__ == "__main__":
    main()
