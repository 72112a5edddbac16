#!/usr/bin/env python3
"""Logged runs of the simulated rig with one effect hidden from the controller's model.

For issue 9 (model-discrepancy workflow). Each run: the truth of a simulator YAML (e.g.
``config/sim/effects/disk_friction.yaml``) is driven through a trajectory by the controller's
commands, and the run directory is written with the project's run-log writer in the loop's format
(``config.yaml``, ``config_effective.yaml``, ``run.yaml``, ``samples.csv``).

The world is :class:`cdcr_ctl.sim.truth.TruthModel` (the simulator's physics, with its backlash
and counts-per-mm error), stepped once per control cycle, offline (the quasi-static truth is rate
independent, so a 60 s run takes seconds). What the controller would measure is made the way the
simulated devices make it: drives follow the command one cycle late and report whole counts
(converted with the controller's counts_per_mm), load cells read the truth tensions at their
location with Gaussian noise, the tracker samples the truth at its rate with its latency and noise
and reports through the true tracker alignment (``effects.tracker_offset``) read back with the
controller's ``base_from_tracker``.

Which effect is hidden: the simulator YAML's stem names it (``disk_friction``, ``cable_elongation``,
``pulley_losses``, ``gravity_sag``, ``coupling``, ``backlash``, ``actuator_scale``,
``tracker_offset``, ``none``) or ``--hidden``. For the effects the model can switch
(friction, elongation, pulley friction, gravity, coupling) the controller's model has the switch
off, and the run says so in ``run.yaml`` (``extra.model_effects``: what a controller built with
those switches records); the other three live only in the truth.

Usage::

    .venv/bin/python scripts/make_discrepancy_runs.py --out /tmp/disc-runs            # all variants
    .venv/bin/python scripts/make_discrepancy_runs.py --sim config/sim/effects/backlash.yaml \
        --duration-s 60 --rate-hz 100 --trajectory rich --seed 3 --out /tmp/disc-runs
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from cdcr_ctl.config.build_model import build_cc_disk_model  # noqa: E402
from cdcr_ctl.control.trajectory import Trajectory, psi_from_vectors, random_smooth  # noqa: E402
from cdcr_ctl.model.effects import rotation_from_rotvec  # noqa: E402
from cdcr_ctl.model.params import Effects  # noqa: E402
from cdcr_ctl.runlog import RunLogWriter, RunMetadata, sample_columns  # noqa: E402
from cdcr_ctl.runlog.writer import EFFECTIVE_CONFIG_YAML  # noqa: E402
from cdcr_ctl.sim.simconfig import load_sim_config  # noqa: E402
from cdcr_ctl.sim.truth import TruthModel  # noqa: E402

EFFECTS_DIR = ROOT / "config" / "sim" / "effects"
#: Hidden effect -> the Effects switch the controller's model has off.
SWITCH_OF = {
    "disk_friction": "disk_friction",
    "cable_elongation": "elongation",
    "pulley_losses": "pulley_friction",
    "gravity_sag": "gravity",
    "coupling": "coupling",
}
HIDDEN = ("none", *SWITCH_OF, "backlash", "actuator_scale", "tracker_offset")


def rich_trajectory(S: int, duration_s: float, bend_rad: float, rate_rad_s: float, seed: int):
    """Planar go-and-returns in several directions with partial reversals and holds, then a
    circle, then a seeded random smooth tail: reversals at different amplitudes and speeds, holds,
    every bending direction. Bending vectors piecewise linear (x = theta (cos phi, sin phi))."""
    rng = np.random.default_rng(seed)
    knots_t = [0.0]
    knots_x = [np.zeros((S, 2))]

    def go(x_to: np.ndarray, speed: float, hold: float = 0.0) -> None:
        d = float(np.max(np.linalg.norm(x_to - knots_x[-1], axis=-1)))
        knots_t.append(knots_t[-1] + max(d / speed, 0.05))
        knots_x.append(x_to)
        if hold > 0:
            knots_t.append(knots_t[-1] + hold)
            knots_x.append(x_to)

    def vec(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        return np.stack((theta * np.cos(phi), theta * np.sin(phi)), axis=-1)

    budget = 0.55 * duration_s
    n_dir = 0
    while knots_t[-1] < budget:
        phi = rng.uniform(0, 2 * math.pi, S) if n_dir >= 3 else np.full(S, 2 * math.pi * n_dir / 3)
        th = bend_rad * rng.uniform(0.6, 1.0, S)
        sp = rate_rad_s * rng.uniform(0.4, 1.0)
        go(vec(th, phi), sp, hold=rng.uniform(0.3, 1.0))
        go(vec(0.45 * th, phi), sp * rng.uniform(0.5, 1.5), hold=rng.uniform(0.2, 0.8))
        go(vec(0.85 * th, phi), sp, hold=0.3)
        go(np.zeros((S, 2)), sp * rng.uniform(0.6, 1.2), hold=0.5)
        n_dir += 1
    # circle at a fixed bend (one turn), entered along phi = 0
    th = 0.6 * bend_rad
    turn_s = max(2 * math.pi * th / rate_rad_s * 1.5, 4.0)
    go(vec(np.full(S, th), np.zeros(S)), rate_rad_s)
    t_c0 = knots_t[-1]
    for u in np.linspace(0, 1, 73)[1:]:
        knots_t.append(t_c0 + u * turn_s)
        knots_x.append(vec(np.full(S, th), np.full(S, 2 * math.pi * u)))
    go(np.zeros((S, 2)), rate_rad_s, hold=0.5)
    t = np.array(knots_t)
    x = np.array(knots_x)
    rest = duration_s - t[-1]
    if rest > 4.0:
        tail = random_smooth(S, rest, bend_rad, rate_rad_s, seed=seed + 1)
        t = np.concatenate((t, t[-1] + tail.t_s[1:]))
        xt = tail.x.reshape(len(tail.t_s), S, 2)
        x = np.concatenate((x, xt[1:]))
    psi = psi_from_vectors(x)
    return Trajectory(t, psi, f"rich_seed{seed}", "<make_discrepancy_runs rich>")


def make_trajectory(kind: str, S: int, duration_s: float, bend_rad: float, seed: int):
    rate = 0.35  # rad/s of the bending vector
    if kind == "rich":
        return rich_trajectory(S, duration_s, bend_rad, rate, seed)
    if kind == "random":
        return random_smooth(S, duration_s, bend_rad, rate, seed=seed, bandwidth_hz=0.3)
    raise SystemExit(f"unknown trajectory {kind!r} (rich, random)")


def hidden_of(sim_path: Path, hidden: str | None) -> str:
    name = hidden or sim_path.stem
    if name not in HIDDEN:
        raise SystemExit(f"cannot tell the hidden effect of {sim_path}: pass --hidden ({HIDDEN})")
    return name


def make_run(
    sim_path: Path,
    out_dir: Path,
    *,
    hidden: str | None = None,
    duration_s: float = 60.0,
    rate_hz: float = 100.0,
    trajectory: str = "rich",
    bend_rad: float = 1.0,
    seed: int = 1,
    name: str | None = None,
    progress: bool = False,
) -> Path:
    """Write one run directory below ``out_dir`` and return it."""
    loaded = load_sim_config(sim_path)
    cfg = loaded.rig
    hid = hidden_of(sim_path, hidden)
    truth = TruthModel(loaded)
    eff = loaded.sim.effects
    switches = {
        "disk_friction": eff.disk_friction,
        "pulley_friction": eff.pulley_friction,
        "elongation": eff.elongation,
        "coupling": eff.coupling,
        "gravity": eff.gravity,
    }
    if hid in SWITCH_OF:
        switches[SWITCH_OF[hid]] = False
    model = build_cc_disk_model(cfg, Effects(geometry=cfg.control.geometry, **switches))
    S, K = model.n_segments, model.n_cables
    traj = make_trajectory(trajectory, S, duration_s, bend_rad, seed)
    rng = np.random.default_rng(seed + 1000)
    noise = loaded.sim.noise
    trk = loaded.sim.tracker
    R_o = rotation_from_rotvec(eff.tracker_offset.rotvec_rad)
    t_o = np.asarray(eff.tracker_offset.translation_mm, dtype=float)
    cpm = np.array(
        [{d.cable: d for d in cfg.drives}[c.name].counts_per_mm for c in cfg.robot.cables]
    )
    cells = {}
    if cfg.sensors.load_cells is not None:
        names = [c.name for c in cfg.robot.cables]
        for j, cell in enumerate(cfg.sensors.load_cells.cells):
            cells[names.index(cell.cable)] = j
    run_name = name or f"{hid}-{trajectory}-s{seed}"
    run_dir = out_dir / run_name
    if run_dir.exists():
        raise SystemExit(f"{run_dir} exists")
    rig_text = loaded.rig_path.read_text()
    effective = yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)
    writer = RunLogWriter(
        run_dir,
        sample_columns(S, K, ("cycle",)),
        RunMetadata(
            name=run_name,
            rig=cfg.name,
            design=cfg.design,
            compensation="off",
            rate_hz=rate_hz,
            trajectory=traj.name,
            extra={
                "model_effects": {k: v for k, v in switches.items()},
                "generator": "scripts/make_discrepancy_runs.py (offline truth stepping)",
            },
        ),
        config_text=rig_text,
        config_source=str(loaded.rig_path),
        extra_files={EFFECTIVE_CONFIG_YAML: effective},
    )
    dt = 1.0 / rate_hz
    n = round(duration_s / dt) + 1
    counts = np.zeros(K)
    tips: list[tuple[float, np.ndarray]] = []  # (time, true tip) per physics step
    frame_dt = 1.0 / trk.rate_hz
    next_frame = 0.0
    last_frame: np.ndarray | None = None
    frames: list[tuple[float, np.ndarray]] = []
    it = range(n)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc=run_name, unit="cycle", leave=False)
    with writer:
        for i in it:
            t = i * dt
            psi = traj.sample(t)
            q_nom = model.q_nominal(psi)
            # the drive reaches last cycle's command (csp), reported in whole counts
            q_act = counts / cpm
            state = truth.step(counts.astype(int).tolist())
            tips.append((t, state.tip_mm.copy()))
            # tracker frames captured at its own rate, delivered after the latency
            while next_frame <= t - trk.latency_s + 1e-12:
                tc = next_frame
                p = next(tp for tt, tp in reversed(tips) if tt <= tc + 1e-12)
                logged = R_o.T @ (p - t_o) + noise.tracker_mm * rng.standard_normal(3)
                frames.append((tc, logged))
                next_frame += frame_dt
            if frames:
                last_frame = frames[-1][1]
                frames = frames[-2:]
            tens = truth.cell_tensions()
            row = {"t_s": t, "cycle": i}
            for s in range(S):
                row[f"seg{s + 1}_theta_cmd_rad"] = float(psi[s, 0])
                row[f"seg{s + 1}_phi_cmd_rad"] = float(psi[s, 1])
            for k in range(K):
                row[f"cable{k + 1}_q_nominal_mm"] = float(q_nom[k])
                row[f"cable{k + 1}_q_cmd_mm"] = float(q_nom[k])
                row[f"cable{k + 1}_q_act_mm"] = float(q_act[k])
                if k in cells:
                    v = tens[cells[k]] + noise.load_cell_N * rng.standard_normal()
                    row[f"cable{k + 1}_tension_N"] = float(v)
            if last_frame is not None:
                row["tip_x_mm"], row["tip_y_mm"], row["tip_z_mm"] = (float(v) for v in last_frame)
            writer.write(row)
            counts = np.round(q_nom * cpm)
            if len(tips) > 64:
                tips = tips[-32:]
    return run_dir


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sim", type=Path, action="append", help="simulator YAML (repeatable)")
    ap.add_argument("--hidden", choices=HIDDEN, default=None)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--trajectory", default="rich", choices=("rich", "random"))
    ap.add_argument("--bend-rad", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    sims = args.sim or sorted(EFFECTS_DIR.glob("*.yaml"))
    args.out.mkdir(parents=True, exist_ok=True)
    for sim in sims:
        d = make_run(
            sim,
            args.out,
            hidden=args.hidden,
            duration_s=args.duration_s,
            rate_hz=args.rate_hz,
            trajectory=args.trajectory,
            bend_rad=args.bend_rad,
            seed=args.seed,
            name=f"{sim.stem}-{args.trajectory}-s{args.seed}",
            progress=True,
        )
        print(d)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
