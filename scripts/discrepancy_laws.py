#!/usr/bin/env python3
"""Hidden effects of other laws than the model's: generate the runs, name them, print the table.

For every world in ``config/sim/effects-laws/`` (friction laws other than the controller's
capstan law, gravity along other directions than the config's; the file's stem up to its first
``-`` names the hidden effect) and every trajectory of ``--trajectories`` (default Qi et al.
2023's two experiments, ``planar`` and ``circle``), one logged run is made by
``scripts/make_discrepancy_runs.py`` (the simulator's truth stepped offline through the
controller's commands) and the installed command analyses it::

    cdcr-ctl discrepancy RUN --json --no-plots --no-progress --out RUN/discrepancy

Per run it prints the world's hidden effect, the effect the workflow named (a tie names both:
the run cannot tell them apart), the tip gap before and after the refit and its shrink (the RMS
of the tip error averaged over the command's ``tip_gap_window_s``, 0.2 s: the model's error,
with the tracker's white noise divided by the square root of the rows averaged), the same per
sample (the raw RMS, noise included), the shrink of the per-sample gap above the tracker's
noise floor, the tracker lag the run's timing carries and any "suspect lag" note, and the
seconds the command took. A run counts as named right when the named effect is the hidden one
itself, not tied with another, and the gap's shrink is at least ``--min-shrink`` percent; the
last lines are the count, and the count with the per-sample shrink instead. Exit 0 when at
least ``--need`` runs (default all) are named right.

Usage::

    .venv/bin/python scripts/discrepancy_laws.py --out /tmp/laws
    .venv/bin/python scripts/discrepancy_laws.py --out /tmp/laws --worlds friction_law-stribeck
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from make_discrepancy_runs import hidden_of, make_run  # noqa: E402

WORLDS_DIR = ROOT / "config" / "sim" / "effects-laws"


def cdcr_ctl() -> list[str]:
    """The installed command (next to this interpreter), else ``python -m cdcr_ctl``."""
    exe = Path(sys.executable).with_name("cdcr-ctl")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "cdcr_ctl"]


def analyse(run: Path, jobs: int, max_points: int) -> tuple[dict, float]:
    """The discrepancy command's JSON answer for ``run`` and its wall time (s)."""
    cmd = [
        *cdcr_ctl(),
        "discrepancy",
        str(run),
        "--json",
        "--no-plots",
        "--no-progress",
        "--jobs",
        str(jobs),
        "--max-points",
        str(max_points),
        "--out",
        str(run / "discrepancy"),
    ]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=os.environ.copy())
    dt = time.perf_counter() - t0
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return json.loads(out.stdout), dt


def suspect_lag(run: Path) -> str:
    """The report's "SUSPECT LAG" line of ``run``, '' when there is none."""
    rep = run / "discrepancy" / "report.txt"
    if not rep.exists():
        return ""
    return next((ln.strip() for ln in rep.read_text().splitlines() if "SUSPECT LAG" in ln), "")


def lag_ms(run: Path) -> str:
    rep = run / "discrepancy" / "report.txt"
    text = rep.read_text() if rep.exists() else ""
    for ln in text.splitlines():
        if "tracker lag" in ln and " ms" in ln:
            return ln.split("tracker lag", 1)[1].split("ms")[0].strip()
    return "-"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="directory for the runs (new)")
    ap.add_argument("--worlds", default="", help="comma-separated stems (default: every world)")
    ap.add_argument("--trajectories", default="planar,circle")
    ap.add_argument("--duration-s", type=float, default=30.0)
    ap.add_argument("--rate-hz", type=float, default=50.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2, help="worker processes of each analysis")
    ap.add_argument(
        "--max-points", type=int, default=700, help="simulated samples per run (the command's)"
    )
    ap.add_argument("--min-shrink", type=float, default=70.0, help="percent, of the tip gap")
    ap.add_argument("--need", type=int, default=None, help="runs named right to exit 0")
    args = ap.parse_args(argv)
    want = [w.strip() for w in args.worlds.split(",") if w.strip()]
    worlds = sorted(WORLDS_DIR.glob("*.yaml"))
    if want:
        by = {w.stem: w for w in worlds}
        missing = [w for w in want if w not in by]
        if missing:
            raise SystemExit(f"no world {missing} in {WORLDS_DIR} ({', '.join(sorted(by))})")
        worlds = [by[w] for w in want]
    trajs = [t.strip() for t in args.trajectories.split(",") if t.strip()]
    args.out.mkdir(parents=True, exist_ok=True)
    head = (
        f"{'world':<26} {'traj':<7} {'hidden':<18} {'named':<30} {'gap mm':>12}"
        f" {'shrink':>7} {'per-sample mm':>13} {'shrink':>7} {'>noise':>7} {'lag ms':>7} {'s':>5}"
    )
    print(
        f"{len(worlds) * len(trajs)} runs: {args.duration_s:g} s at {args.rate_hz:g} Hz, seed"
        f" {args.seed}; named right = the hidden effect itself, no tie, with >="
        f" {args.min_shrink:g} % gap shrink (gap: RMS of the tip error averaged over the"
        " command's window; per sample: the raw RMS)"
    )
    print(head)
    right = right_raw = total = 0
    notes = []
    for w in worlds:
        hidden = hidden_of(w, None)
        for tr in trajs:
            run = make_run(
                w,
                args.out,
                duration_s=args.duration_s,
                rate_hz=args.rate_hz,
                trajectory=tr,
                seed=args.seed,
                name=f"{w.stem}-{tr}",
            )
            res, dt = analyse(run, args.jobs, args.max_points)
            named = res.get("effect") or "-"
            tie = res.get("tie") or []
            shown = " / ".join(tie) + " (tie)" if tie else named
            gb, ga, _ = res["tip_gap_mm"]
            shrink = res.get("tip_gap_shrink_percent")
            raw = res.get("gap_shrink_percent")
            above = res.get("gap_above_noise_shrink_percent")
            hit = named == hidden and not tie
            ok = hit and shrink is not None and shrink >= args.min_shrink
            total += 1
            right += ok
            right_raw += hit and raw is not None and raw >= args.min_shrink
            gap = f"{gb:.3f}->{ga:.3f}"
            gap_raw = f"{res['tip_rms_before_mm']:.3f}->{res['tip_rms_after_mm']:.3f}"
            print(
                f"{w.stem:<26} {tr:<7} {hidden:<18} {shown:<30} {gap:>12} {_pct(shrink):>7}"
                f" {gap_raw:>13} {_pct(raw):>7} {_pct(above):>7} {lag_ms(run):>7} {dt:5.1f}"
                f"{'' if ok else '  MISS'}",
                flush=True,
            )
            s = suspect_lag(run)
            if s:
                notes.append(s)
    for n in notes:
        print(n)
    print(f"named right with >= {args.min_shrink:g} % gap shrink: {right} of {total}")
    print(
        f"named right with >= {args.min_shrink:g} % per-sample (raw) gap shrink:"
        f" {right_raw} of {total}"
    )
    need = total if args.need is None else args.need
    return 0 if right >= need else 1


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}%"


if __name__ == "__main__":
    raise SystemExit(main())
