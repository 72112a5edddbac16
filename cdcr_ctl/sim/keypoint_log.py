"""Simulated lab logs: quasi-static keypoint runs and tendon-pull runs of a cc_disk rig.

What a lab without the daemon records: rows about 0.5 s apart, each with the measured
actuator positions (``cable{k}_q_act_mm``) and one tracked tip marker (``tip_{x,y,z}_mm``),
optionally the load cells (``cable{k}_tension_N``), and no commanded pose. The world is the
forward model (:class:`~cdcr_ctl.model.cc_disk.forward.ForwardStepper`, friction memory kept from
row to row) with parameters off the rig config's nominal values (:func:`perturbed_truth`); the
actuator path is the config's *nominal* inverse kinematics (eq. 4, no compensation) of out-and-back
sweeps between random poses, so the log is full of reversals and some cables go slack, as on a real
rig.

Writes ``samples.csv`` and ``run.yaml`` in the run-log format (:mod:`cdcr_ctl.runlog`), and the
world's parameters into ``truth.json`` *beside* the run directory (never read by the fit; tests
and benchmarks compare against it). Production code never imports this module.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from cdcr_ctl.model.cc_disk.effects import BacklashPlay, with_cable_play
from cdcr_ctl.model.cc_disk.forward import ForwardStepper
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams
from cdcr_ctl.model.cc_disk.routing import cable_displacement

#: Tracker noise (mm, per axis), drive position resolution (mm), load-cell noise (N).
TIP_NOISE_MM = 0.05
Q_RESOLUTION_MM = 1.0 / 1238.6
TENSION_NOISE_N = 0.02


@dataclass(frozen=True)
class Truth:
    """The world's departures from nominal: factors on EI per segment, on every cable's EA and
    pretension, and hole-angle offsets per segment (rad, added to every hole of the segment)."""

    ei_factor: tuple[float, ...]
    ea_factor: float
    pretension_factor: float
    hole_offset_rad: tuple[float, ...]

    def apply(self, params: RobotParams) -> RobotParams:
        segs = tuple(
            dataclasses.replace(s, EI_Nmm2=s.EI_Nmm2 * f)
            for s, f in zip(params.segments, self.ei_factor, strict=True)
        )
        cabs = tuple(
            dataclasses.replace(
                c,
                EA_N=c.EA_N * self.ea_factor,
                pretension_N=c.pretension_N * self.pretension_factor,
                hole_angle_rad=c.hole_angle_rad + self.hole_offset_rad[c.segment],
            )
            for c in params.cables
        )
        return dataclasses.replace(params, segments=segs, cables=cabs)


def perturbed_truth(
    n_segments: int,
    rng: np.random.Generator,
    spread: tuple[float, float] = (0.2, 0.5),
    hole_deg: tuple[float, float] = (1.0, 4.0),
) -> Truth:
    """Random departures: each factor 1 +- U(spread) (sign random), offsets +- U(hole_deg) deg."""

    def factor() -> float:
        return 1.0 + float(rng.choice((-1.0, 1.0)) * rng.uniform(*spread))

    return Truth(
        ei_factor=tuple(factor() for _ in range(n_segments)),
        ea_factor=factor(),
        pretension_factor=factor(),
        hole_offset_rad=tuple(
            math.radians(float(rng.choice((-1.0, 1.0)) * rng.uniform(*hole_deg)))
            for _ in range(n_segments)
        ),
    )


def sweep_poses(
    n_segments: int, n_rows: int, rng: np.random.Generator, bend_max_rad: float = 0.9
) -> np.ndarray:
    """(n_rows, S, 2) keypoint poses: out-and-back sweeps from the current pose to a random one
    (4-10 steps out, back 30-100 % of the way), so every cable reverses again and again."""
    x = np.zeros((n_segments, 2))  # bending vectors theta (cos phi, sin phi), rad
    rows: list[np.ndarray] = []
    while len(rows) < n_rows:
        th = rng.uniform(0.0, bend_max_rad, n_segments)
        ph = rng.uniform(-math.pi, math.pi, n_segments)
        target = np.column_stack((th * np.cos(ph), th * np.sin(ph)))
        n_out = int(rng.integers(4, 11))
        back = float(rng.uniform(0.3, 1.0))
        n_back = max(1, round(n_out * back))
        start = x
        rows += [start + (target - start) * (j / n_out) for j in range(1, n_out + 1)]
        rows += [target + (start - target) * (back * j / n_back) for j in range(1, n_back + 1)]
        x = rows[-1]
    xs = np.asarray(rows[:n_rows])
    return np.stack((np.hypot(xs[..., 0], xs[..., 1]), np.arctan2(xs[..., 1], xs[..., 0])), -1)


def pull_path(n_cables: int, steps: int, amplitude_mm: float) -> np.ndarray:
    """(n_cables * 2 * steps, K) tendon pulls: one cable at a time 0 -> amplitude -> 0, others 0."""
    rows: list[np.ndarray] = []
    ramp = np.concatenate(
        (np.linspace(0, amplitude_mm, steps + 1)[1:], np.linspace(amplitude_mm, 0, steps + 1)[1:])
    )
    for k in range(n_cables):
        for v in ramp:
            q = np.zeros(n_cables)
            q[k] = v
            rows.append(q)
    return np.asarray(rows)


def write_log(
    run_dir: Path,
    q_act_mm: np.ndarray,
    params_true: RobotParams,
    effects: Effects,
    rng: np.random.Generator,
    period_s: float = 0.5,
    tensions: bool = False,
    tip_noise_mm: float = TIP_NOISE_MM,
    locations: tuple[str, ...] = (),
) -> dict[str, int]:
    """Solve the world along ``q_act_mm`` (N, K) and write the run directory; returns counts."""
    from cdcr_ctl.model.cc_disk.forward import replay

    run_dir.mkdir(parents=True, exist_ok=True)
    q = np.round(np.asarray(q_act_mm) / Q_RESOLUTION_MM) * Q_RESOLUTION_MM
    # the world's own play (cables' backlash_mm) replaces any play built from the config
    rest = tuple(e for e in effects.actuator if not isinstance(e, BacklashPlay))
    world = with_cable_play(params_true, dataclasses.replace(effects, actuator=rest))
    rep = replay(ForwardStepper(params_true, world), q)
    N, K = q.shape
    t = np.arange(N) * period_s + rng.uniform(-0.02, 0.02, N)
    t[0] = 0.0
    tip = rep.tip_mm + rng.normal(0.0, tip_noise_mm, (N, 3))
    cols = ["t_s"] + [f"cable{k + 1}_q_act_mm" for k in range(K)]
    if tensions:
        cols += [f"cable{k + 1}_tension_N" for k in range(K)]
    cols += ["tip_x_mm", "tip_y_mm", "tip_z_mm"]
    with (run_dir / "samples.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for i in range(N):
            row = [f"{t[i]:.4f}"] + [f"{v:.5f}" for v in q[i]]
            if tensions:
                # each load cell where the rig config puts it (default: the robot base)
                at_act = np.array([loc == "actuator" for loc in locations] or [False] * K)
                T_model = np.where(at_act, rep.tension_actuator_N[i], rep.tension_base_N[i])
                T = T_model + rng.normal(0.0, TENSION_NOISE_N, K)
                row += [f"{v:.4f}" for v in T]
            row += ["" if not np.isfinite(v) else f"{v:.4f}" for v in tip[i]]
            w.writerow(row)
    meta = {
        "format": "cdcr-ctl-runlog/1",
        "name": run_dir.name,
        "source": "cdcr_ctl.sim.keypoint_log (simulated lab keypoint log)",
        "rows": int(N),
    }
    (run_dir / "run.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return {"rows": int(N), "failed": len(rep.failed)}


def make_keypoint_log(
    params_nominal: RobotParams,
    effects: Effects,
    out_dir: Path,
    n_rows: int,
    seed: int,
    tensions: bool = False,
    truth: Truth | None = None,
    name: str = "keypoints",
    locations: tuple[str, ...] = (),
) -> tuple[Path, Truth]:
    """A keypoint run of the perturbed world under ``out_dir/name``; ``truth.json`` beside it."""
    rng = np.random.default_rng(seed)
    S = params_nominal.n_segments
    tr = perturbed_truth(S, rng) if truth is None else truth
    psi = sweep_poses(S, n_rows, rng)
    q = np.array([cable_displacement(p, params_nominal) for p in psi])
    run_dir = Path(out_dir) / name
    counts = write_log(
        run_dir, q, tr.apply(params_nominal), effects, rng, tensions=tensions, locations=locations
    )
    doc = {"seed": seed, **dataclasses.asdict(tr), **counts}
    (Path(out_dir) / f"{name}.truth.json").write_text(json.dumps(doc, indent=2))
    return run_dir, tr


def make_pull_log(
    params_nominal: RobotParams,
    effects: Effects,
    out_dir: Path,
    truth: Truth,
    seed: int,
    steps: int = 6,
    amplitude_mm: float = 3.0,
    name: str = "pulls",
) -> Path:
    """A tendon-pull run (one cable at a time) of the world ``truth``, tip only."""
    rng = np.random.default_rng(seed)
    q = pull_path(params_nominal.n_cables, steps, amplitude_mm)
    run_dir = Path(out_dir) / name
    write_log(run_dir, q, truth.apply(params_nominal), effects, rng)
    return run_dir
