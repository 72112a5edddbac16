"""Issue 18 measurements on simulated lab logs of config/three_segment_example.yaml.

    .venv/bin/python benchmarks/bench_keypoint_identify.py forward --rows 2000
        acceptance 4: forward replay of a 2000-row keypoint path, free_length_mm 0, friction on;
        prints the failures and the time per row.
    .venv/bin/python benchmarks/bench_keypoint_identify.py fit --seeds 1 --rows 300 [--tensions]
        acceptance 1 (tip only) / 2 (with load cells): simulate a keypoint log per seed (EI per
        segment, EA, pretension off nominal by 20-50 %, hole offsets 1-4 deg), identify through
        the CLI path, print held-out tip RMSE of config / fitted / true parameters, the
        identifiable parameters and whether each fitted 95 % CI contains the truth.
    .venv/bin/python benchmarks/bench_keypoint_identify.py coverage --seeds 20 --rows 200 --jobs 2
        acceptance 2: the tension-log fit of each of 20 seeds (one per worker process), and per
        fitted parameter how many of the seeds' 95 % CIs contain the truth.
    .venv/bin/python benchmarks/bench_keypoint_identify.py discrepancy --rows 2000
        acceptance 5: ``cdcr-ctl discrepancy`` on a 2000-row keypoint log of a world with the
        parameters off nominal and a hidden lost motion on every cable: verdict and wall time.

Every run prints what it measured and how; wall times depend on the machine's load.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model, loadcell_locations
from cdcr_ctl.identify.heldout import heldout_rmse
from cdcr_ctl.identify.keypoints import KeypointOptions, _load, identify_keypoint_runs
from cdcr_ctl.identify.logkind import split_by_time
from cdcr_ctl.model.forward import ForwardStepper, replay
from cdcr_ctl.model.routing import cable_displacement
from cdcr_ctl.sim.keypoint_log import make_keypoint_log, sweep_poses

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "three_segment_example.yaml"


def forward(rows: int, seed: int) -> None:
    m = build_model(load_rig_config(CONFIG))
    p = m.params
    p = dataclasses.replace(
        p, cables=tuple(dataclasses.replace(c, free_length_mm=0.0) for c in p.cables)
    )
    psi = sweep_poses(p.n_segments, rows, np.random.default_rng(seed), bend_max_rad=1.2)
    q = np.array([cable_displacement(x, p) for x in psi])
    t0 = time.perf_counter()
    c0 = time.process_time()
    rep = replay(ForwardStepper(p, m.effects), q)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    print(
        f"forward replay, {rows} keypoint rows (sweeps to 1.2 rad, seed {seed}), free_length_mm 0, "
        f"disk friction on: {len(rep.failed)} rows without a solution; "
        f"{1e3 * dt / rows:.1f} ms/row wall, {1e3 * dc / rows:.1f} ms/row CPU"
    )
    for i, why in rep.failed[:10]:
        print(f"  row {i}: {why}")


def truth_params(m, truth_json: Path):
    from cdcr_ctl.sim.keypoint_log import Truth

    d = json.loads(truth_json.read_text())
    tr = Truth(
        tuple(d["ei_factor"]),
        d["ea_factor"],
        d["pretension_factor"],
        tuple(d["hole_offset_rad"]),
    )
    return tr, tr.apply(m.params)


def fit(seeds: int, rows: int, tensions: bool, max_points: int, first_seed: int) -> None:
    cfg = load_rig_config(CONFIG)
    m = build_model(cfg)
    locs = tuple(loadcell_locations(cfg))
    ratios, inside, total = [], 0, 0
    for seed in range(first_seed, first_seed + seeds):
        with tempfile.TemporaryDirectory() as tmp:
            run, _ = make_keypoint_log(
                m.params, m.effects, Path(tmp), rows, seed, tensions=tensions, locations=locs
            )
            _, p_true = truth_params(m, Path(tmp) / "keypoints.truth.json")
            t0 = time.perf_counter()
            res = identify_keypoint_runs(cfg, [run], KeypointOptions(max_points=max_points))
            dt = time.perf_counter() - t0
            runs, _, _ = _load([run], None, m.params.n_segments)
            pts = [p for r in runs for p in r.points]
            _, held = split_by_time(pts, 0.3)
            h_true, _, _ = heldout_rmse(p_true, m.effects, runs, {(p.run, p.index) for p in held})
        h = res.heldout
        ratio = h.rmse_fitted / h_true
        ratios.append(ratio)
        print(
            f"seed {seed}: held-out tip RMSE config {h.rmse_nominal:.4f} / fitted "
            f"{h.rmse_fitted:.4f} / true {h_true:.4f} mm (fitted/true {ratio:.3f}); "
            f"reduced chi2 {res.ident.chi2_reduced:.3g}; {dt:.0f} s"
        )
        print("  identifiable and fitted: " + ", ".join(e.name for e in res.ident.estimates))
        print("  fixed: " + ", ".join(f.name for f in res.ident.fixed))
        for e in res.ident.estimates:
            true = _true_value(e.parameter, p_true)
            ok = e.ci95[0] <= true <= e.ci95[1]
            inside += ok
            total += 1
            print(
                f"  {e.name:<26} fitted {e.value:.5g} [{e.ci95[0]:.5g}, {e.ci95[1]:.5g}] "
                f"true {true:.5g} {'in' if ok else 'OUT'}"
            )
    print(
        f"{'tension' if tensions else 'tip-only'} keypoint logs, {rows} rows, {seeds} seeds: "
        f"held-out fitted/true RMSE max {max(ratios):.3f}, median {np.median(ratios):.3f}; "
        f"CIs containing the truth {inside}/{total}"
        f" ({100 * inside / max(total, 1):.0f} %)"
    )


def _true_value(fp, p_true) -> float:
    ref = fp.refs[0]
    if ref.kind == "segment":
        v = getattr(p_true.segments[ref.index], ref.field)
    else:
        v = getattr(p_true.cables[ref.index], ref.field)
    off = fp.offsets[0] if fp.offsets else 0.0
    return (float(v) - off) / fp.scales[0]


def _one_seed(args: tuple) -> dict:
    """Tension-log fit of one seed (worker process, one replay at a time inside)."""
    seed, rows, tensions, max_points = args
    cfg = load_rig_config(CONFIG)
    m = build_model(cfg)
    locs = tuple(loadcell_locations(cfg))
    with tempfile.TemporaryDirectory() as tmp:
        run, _ = make_keypoint_log(
            m.params, m.effects, Path(tmp), rows, seed, tensions=tensions, locations=locs
        )
        _, p_true = truth_params(m, Path(tmp) / "keypoints.truth.json")
        c0 = time.process_time()
        res = identify_keypoint_runs(cfg, [run], KeypointOptions(max_points=max_points, jobs=1))
        cpu = time.process_time() - c0
        runs, _, _ = _load([run], None, m.params.n_segments)
    pts = [p for r in runs for p in r.points]
    _, held = split_by_time(pts, 0.3)
    h_true, _, _ = heldout_rmse(p_true, m.effects, runs, {(p.run, p.index) for p in held})
    est = {}
    for e in res.ident.estimates:
        true = _true_value(e.parameter, p_true)
        est[e.name] = (e.value, e.ci95, true, bool(e.ci95[0] <= true <= e.ci95[1]))
    return {
        "seed": seed,
        "ratio": res.heldout.rmse_fitted / h_true,
        "chi2": res.ident.chi2_reduced,
        "est": est,
        "fixed": [f.name for f in res.ident.fixed],
        "cpu": cpu,
    }


def coverage(seeds: int, rows: int, first_seed: int, jobs: int, tip_only: bool, mp: int) -> None:
    from concurrent.futures import ProcessPoolExecutor

    t0 = time.perf_counter()
    args = [(s, rows, not tip_only, mp) for s in range(first_seed, first_seed + seeds)]
    per: dict[str, list[bool]] = {}
    outs = []
    with ProcessPoolExecutor(jobs) as pool:
        for o in pool.map(_one_seed, args):  # printed as each seed finishes, in seed order
            outs.append(o)
            bad = [n for n, v in o["est"].items() if not v[3]]
            print(
                f"seed {o['seed']}: fitted/true held-out RMSE {o['ratio']:.3f}, reduced chi2 "
                f"{o['chi2']:.3g}, {o['cpu']:.0f} s CPU; fixed: {', '.join(o['fixed']) or 'none'}; "
                f"CI misses: {', '.join(bad) or 'none'}",
                flush=True,
            )
            for n, v in o["est"].items():
                per.setdefault(n, []).append(v[3])
    print(f"per parameter, seeds whose 95 % CI contains the truth ({seeds} seeds):")
    for n, v in per.items():
        print(f"  {n:<26} {sum(v)}/{len(v)}")
    ins = sum(sum(v) for v in per.values())
    tot = sum(len(v) for v in per.values())
    ok_par = sum(sum(v) >= 0.9 * len(v) for v in per.values())
    ratios = [o["ratio"] for o in outs]
    print(
        f"{'tip-only' if tip_only else 'tension'} keypoint logs, {rows} rows, seeds "
        f"{first_seed}-{first_seed + seeds - 1}: CIs containing the truth {ins}/{tot} "
        f"({100 * ins / max(tot, 1):.1f} %); parameters covered in >= 90 % of seeds: "
        f"{ok_par}/{len(per)}; held-out fitted/true RMSE median {np.median(ratios):.3f}, "
        f"max {max(ratios):.3f}; {time.perf_counter() - t0:.0f} s wall, {jobs} processes"
    )


def discrepancy(rows: int, seed: int, backlash_mm: float) -> None:
    """The world: parameters off nominal (as ``fit``) and, hidden, ``backlash_mm`` of lost
    motion on every cable beyond the config's."""
    m = build_model(load_rig_config(CONFIG))
    p = m.params
    world = dataclasses.replace(
        p,
        cables=tuple(
            dataclasses.replace(c, backlash_mm=c.backlash_mm + backlash_mm) for c in p.cables
        ),
    )
    print(f"hidden effect: {backlash_mm} mm lost motion per cable; parameters off nominal")
    with tempfile.TemporaryDirectory() as tmp:
        run, _ = make_keypoint_log(world, m.effects, Path(tmp), rows, seed)
        t0 = time.perf_counter()
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cmd = [sys.executable, "-m", "cdcr_ctl", "discrepancy", "--rig-config", str(CONFIG)]
        out = subprocess.run([*cmd, str(run)], capture_output=True, text=True)
        dt = time.perf_counter() - t0
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)
    text = out.stdout
    print(
        text if len(text) < 6000 else text[:3000] + "\n[...]\n" + text[-2500:], out.stderr[-2000:]
    )
    print(
        f"discrepancy on a {rows}-row keypoint log: {dt:.1f} s wall, {cpu:.1f} s CPU "
        f"(exit {out.returncode})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("what", choices=("forward", "fit", "coverage", "discrepancy"))
    ap.add_argument("--rows", type=int, default=2000)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--tensions", action="store_true")
    ap.add_argument("--max-points", type=int, default=150)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--backlash-mm", type=float, default=0.4, help="discrepancy: hidden play")
    ap.add_argument("--tip-only", action="store_true", help="coverage: tip-only logs")
    a = ap.parse_args()
    if a.what == "forward":
        forward(a.rows, a.seed)
    elif a.what == "fit":
        fit(a.seeds, a.rows, a.tensions, a.max_points, a.seed)
    elif a.what == "coverage":
        coverage(a.seeds, a.rows, a.seed, a.jobs, a.tip_only, a.max_points)
    else:
        discrepancy(a.rows, a.seed, a.backlash_mm)


if __name__ == "__main__":
    main()
