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
    .venv/bin/python benchmarks/bench_keypoint_identify.py worlds --rows 1600 --seed-list 1 2 3
        acceptance 1 of the tip-only issue: a tip-only keypoint log of the hardest independent
        world (cdcr_ctl.sim.keypoint_world.hard_world: chain of rigid links, curvature not
        constant, routing offsets, per-segment friction and play, gravity sag, registration
        error, 1 mm tracker noise) per seed, then ``cdcr-ctl identify --from-run`` with its
        defaults as a lab types it: wall and CPU time, rows chosen and their spread, held-out
        tip RMSE config -> fitted, gate, intervals; prints the machine's load average.
    .venv/bin/python benchmarks/bench_keypoint_identify.py make-log --world hard --rows 1600 \
        --seed 1 --out runs/hard1
        writes one such log (``--world hard``, a hidden-effect name or ``gravity-sideways``:
        the gravity world on the sideways mount) for the commands above.
    .venv/bin/python benchmarks/bench_keypoint_identify.py jacobian --run runs/hard1 --rows 100
        the fit's Jacobian on ``--rows`` rows of a keypoint log chosen as identify chooses them,
        CPU time of: one plain replay of them, the sensitivity replay (every candidate), and
        forward differences (one replay per candidate); and how far the two Jacobians differ.
    .venv/bin/python benchmarks/bench_keypoint_identify.py discrepancy-worlds --rows 1600
        acceptance 3: one keypoint log per hidden-effect world (hidden_effect_worlds; the
        gravity world also as ``gravity-sideways``, against tip_only_side_rig.yaml), then
        ``cdcr-ctl discrepancy`` with its defaults: the effect named and its held-out shrink.
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
from cdcr_ctl.model.cc_disk.forward import ForwardStepper, replay
from cdcr_ctl.model.cc_disk.routing import cable_displacement
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


def _cli(args: list[str]) -> tuple[subprocess.CompletedProcess, float, float]:
    """Run ``cdcr-ctl ARGS`` as installed; (result, wall s, CPU s of it and its workers)."""
    t0 = time.perf_counter()
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run([sys.executable, "-m", "cdcr_ctl", *args], capture_output=True, text=True)
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)
    return out, time.perf_counter() - t0, cpu


def make_log(world: str, rows: int, seed: int, out: Path, bend_max_rad: float | None) -> None:
    """Write one keypoint log of an independent world (``hard`` or a hidden-effect name) along
    :func:`~cdcr_ctl.sim.keypoint_world.lab_path` with segment bends up to ``bend_max_rad``
    (None: the world's own, ``WorldSpec.path_bend_max_rad``)."""
    from cdcr_ctl.sim.keypoint_world import (
        hard_world,
        hidden_effect_worlds,
        lab_path,
        make_world_log,
    )

    if world == "hard":
        spec, rig = hard_world(seed), CONFIG
    else:
        spec, rig = hidden_effect_worlds(seed)[world.split("-")[0]], hidden_rig(world)
    m = build_model(load_rig_config(rig))
    t0 = time.perf_counter()
    if bend_max_rad is None:
        bend_max_rad = spec.path_bend_max_rad
    path = lab_path(m.params, rows, spec.seed, bend_max_rad=bend_max_rad)
    run = make_world_log(m.params, spec, out.parent, rows, name=out.name, path=path)
    print(
        f"{run}: {rows} keypoint rows of the {world} world (seed {seed}, bends up to "
        f"{bend_max_rad:g} rad per segment), tip only, "
        f"{time.perf_counter() - t0:.0f} s; controller config: {rig.relative_to(ROOT)}"
    )


def hidden_rig(effect: str) -> Path:
    """The controller config of a hidden-effect world: the tip-only robot without friction,
    upright (gravity along -z), or mounted sideways for ``gravity-sideways`` (gravity along
    -x: a heavier arm droops at every pose instead of bending further where it is bent)."""
    name = "tip_only_side_rig.yaml" if effect == "gravity-sideways" else "tip_only_rig.yaml"
    return ROOT / "tests" / "discrepancy" / name


def worlds(rows: int, seeds: list[int]) -> None:
    import os

    from cdcr_ctl.sim.keypoint_world import hard_world, make_world_log

    m = build_model(load_rig_config(CONFIG))
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            run = make_world_log(m.params, hard_world(seed), Path(tmp), rows, name=f"hard{seed}")
            gen = time.perf_counter() - t0
            load0 = os.getloadavg()[0]
            out, dt, cpu = _cli(
                ["-c", str(CONFIG), "identify", "--from-run", str(run), "--out", f"{tmp}/id"]
            )
            load1 = os.getloadavg()[0]
            rep = json.loads(Path(f"{tmp}/id/identification.json").read_text())["keypoint_fit"]
        h = rep["heldout"]
        gain = 100 * (1 - h["rmse_fitted"] / h["rmse_nominal"])
        print(f"seed {seed}: world {rows} rows generated in {gen:.0f} s")
        for ln in out.stderr.splitlines():
            if not ln.startswith("[") or "fitting" in ln or "config replay" in ln:
                print("  | " + ln)
        print(
            f"seed {seed}: identify (defaults) {dt:.1f} s wall, {cpu:.1f} s CPU of its "
            f"processes, exit {out.returncode}; {rep['n_fit']} rows fitted; held-out tip RMSE "
            f"{h['rmse_nominal']:.3f} -> {h['rmse_fitted']:.3f} mm ({gain:.1f} % less); "
            f"load average {load0:.1f} -> {load1:.1f} on {os.cpu_count()} CPUs"
        )


def discrepancy_worlds(rows: int, seed: int, effects: list[str] | None) -> None:
    import os

    from cdcr_ctl.sim.keypoint_world import hidden_effect_worlds, make_world_log

    specs = hidden_effect_worlds(seed)
    specs["gravity-sideways"] = specs["gravity"]
    for name in effects or list(specs):
        rig = hidden_rig(name)
        m = build_model(load_rig_config(rig))
        with tempfile.TemporaryDirectory() as tmp:
            run = make_world_log(m.params, specs[name], Path(tmp), rows, name=name)
            out, dt, cpu = _cli(["--json", "-c", str(rig), "discrepancy", "--no-plots", str(run)])
        try:
            res = json.loads(out.stdout)
        except json.JSONDecodeError:
            print(f"{name}: exit {out.returncode}\n{out.stderr[-2000:]}")
            continue
        named = res["effect"]["name"] if res["effect"] else None
        shrink = {c["name"]: c["shrink_percent"] for c in res["candidates"]}
        effect = name.split("-")[0]
        print(
            f"hidden {name} ({rig.name}): named {named} "
            f"({'right' if named == effect else 'WRONG'}); held-out "
            f"shrink of the hidden effect {shrink.get(effect, float('nan')):.1f} %; all: "
            + ", ".join(f"{k} {v:.0f} %" for k, v in sorted(shrink.items(), key=lambda x: -x[1]))
            + f"; {dt:.0f} s wall, {cpu:.0f} s CPU, load {os.getloadavg()[0]:.1f}"
        )


def jacobian(run: Path, rows: int) -> None:
    from cdcr_ctl.identify import replay_fit
    from cdcr_ctl.identify.keypoints import _choose_rows, candidates

    cfg = load_rig_config(CONFIG)
    m = build_model(cfg)
    runs, _, _ = _load([run], None, m.params.n_segments)
    pts = [p for r in runs for p in r.points]
    fit_pts, _ = split_by_time(pts, 0.3)
    rr, _ = _choose_rows(runs, {(p.run, p.index) for p in fit_pts}, rows, len(fit_pts))
    prob = replay_fit.ReplayProblem(m.params, m.effects, tuple(rr), (), 1.0, 0.02)
    fps = candidates(m.params)
    x0 = np.array([fp.to_var(fp.nominal) for fp in fps])
    hi = np.array([fp.var_bounds()[1] for fp in fps])
    with replay_fit.Evaluator(prob, jobs=1) as ev:
        c0 = ev.cpu_s
        f0 = ev.map_params([prob.params_of(fps, x0)])[0]
        c1 = ev.cpu_s
        J_s = ev.jacobian(fps, x0, f0, hi)
        c2 = ev.cpu_s
        J_d = ev.jacobian(fps, x0, f0, hi, analytic=False)
        c3 = ev.cpu_s
    rel = np.linalg.norm(J_s - J_d, axis=0) / np.linalg.norm(J_d, axis=0)
    n = sum(len(r.q_path) for r in rr)
    print(
        f"{len(fit_pts)} rows before the cut, {sum(len(r.rows) for r in rr)} chosen "
        f"({n} replayed with their predecessors), {len(fps)} candidates, one process, CPU time "
        f"(time.process_time): plain replay {c1 - c0:.2f} s; sensitivity replay (Jacobian) "
        f"{c2 - c1:.2f} s ({(c2 - c1) / (c1 - c0):.2f} replays); forward differences "
        f"{c3 - c2:.2f} s ({(c3 - c2) / (c1 - c0):.2f} replays); column difference "
        f"|J_sens - J_fd| / |J_fd| median {np.median(rel):.2g}, max {rel.max():.2g} "
        f"(forward differences err by O(h) = 1e-4 relative and jump where a cable's mode "
        f"changes within the step)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument(
        "what",
        choices=(
            "forward",
            "fit",
            "coverage",
            "discrepancy",
            "worlds",
            "discrepancy-worlds",
            "make-log",
            "jacobian",
        ),
    )
    ap.add_argument("--run", type=Path, default=Path("runs/hard1"), help="jacobian: a log")
    ap.add_argument("--world", default="hard", help="make-log: hard or a hidden-effect name")
    ap.add_argument("--out", type=Path, default=Path("runs/keypoints"), help="make-log: run dir")
    ap.add_argument(
        "--bend-max",
        type=float,
        default=None,
        help="make-log: largest bend per segment, rad (default: the world's own path)",
    )
    ap.add_argument("--seed-list", type=int, nargs="*", default=[1], help="worlds: seeds")
    ap.add_argument("--effects", nargs="*", default=None, help="discrepancy-worlds: subset")
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
    elif a.what == "jacobian":
        jacobian(a.run, a.rows)
    elif a.what == "make-log":
        make_log(a.world, a.rows, a.seed, a.out, a.bend_max)
    elif a.what == "worlds":
        worlds(a.rows, a.seed_list)
    elif a.what == "discrepancy-worlds":
        discrepancy_worlds(a.rows, a.seed, a.effects)
    elif a.what == "coverage":
        coverage(a.seeds, a.rows, a.seed, a.jobs, a.tip_only, a.max_points)
    else:
        discrepancy(a.rows, a.seed, a.backlash_mm)


if __name__ == "__main__":
    main()
