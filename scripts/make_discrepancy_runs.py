#!/usr/bin/env python3
"""Logged runs of the simulated rig with one effect hidden from the controller's model.

For the model-discrepancy workflow. Each run: the truth of a simulator YAML (e.g.
``config/sim/effects/disk_friction.yaml``) is driven through a trajectory by the controller's
commands, and the run directory is written with the project's run-log writer in the loop's format
(``config.yaml``, ``config_effective.yaml``, ``run.yaml``, ``samples.csv``).

The world is :class:`cdcr_ctl.sim.truth.TruthModel` (the simulator's physics, with its backlash
and counts-per-mm error), stepped once per control cycle, offline (the quasi-static truth is rate
independent, so a 60 s run takes seconds). What the controller would measure is made the way the
simulated devices make it: the command is the control loop's (the controller's model,
``q_command`` in the rig config's compensation mode as the daemon runs it, unless the supervisor
would halt that run: :func:`compensation_mode`), drives follow the command one cycle late and
report whole counts (converted with the controller's counts_per_mm), load cells read the truth
tensions at their location with Gaussian noise, the tracker samples the truth at its rate with
its latency and noise and reports through the true tracker alignment
(``effects.tracker_offset``) read back with the controller's ``base_from_tracker``.

Which effect is hidden: the simulator YAML's stem names it (``disk_friction``, ``cable_elongation``,
``pulley_losses``, ``gravity_sag``, ``coupling``, ``backlash``, ``actuator_scale``,
``tracker_offset``, ``none``) or ``--hidden``. For the effects the model can switch
(friction, elongation, pulley friction, gravity, coupling) the controller's model has the switch
off, and the run says so in ``run.yaml`` (``extra.model_effects``: what a controller built with
those switches records); the other three live only in the truth.

How far it bends: by default up to 90 deg per segment (Qi et al. 2023's experiments) within
the rig's own limits (:func:`trajectory_within_limits`); the friction, elongation and gravity
effects all grow with the bend, so a timid trajectory hides them.

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
from cdcr_ctl.errors import ModelError  # noqa: E402
from cdcr_ctl.model.cc_disk.compensation import MODES  # noqa: E402
from cdcr_ctl.model.cc_disk.effects import rotation_from_rotvec  # noqa: E402
from cdcr_ctl.model.cc_disk.params import Effects  # noqa: E402
from cdcr_ctl.runlog.columns import group_of, sample_columns  # noqa: E402
from cdcr_ctl.runlog.writer import EFFECTIVE_CONFIG_YAML, RunLogWriter, RunMetadata  # noqa: E402
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
HIDDEN = (
    "none",
    *SWITCH_OF,
    "backlash",
    "actuator_scale",
    "tracker_offset",
    "gravity_direction",  # the truth's mount is tilted against the config's gravity vector
    "friction_law",  # the truth's disk friction follows another law (cdcr_ctl.sim.friction_law)
)
TRAJECTORIES = ("rich", "random", "circle", "planar")
#: Column groups a partial log may lack (``--drop``).
DROPPABLE = ("tension", "q_act", "tip")
#: Largest bend (rad, per segment) of a generated trajectory when none is given: Qi et al. 2023
#: section 5 bend their robot from 0 to 90 deg (planar experiment, the one whose uncompensated
#: 3.03 mm mean error the compensation halves) and identify the disk friction over 40-90 deg. A
#: smaller range under-samples exactly the poses where friction matters: the capstan factor
#: exp(mu theta) and the tension that bends the robot both grow with theta.
PAPER_BEND_RAD = math.pi / 2
#: Share of the rig's own limits (``limits.bend_rad``, ``limits.cable_displacement_mm``) a
#: generated trajectory may use: the daemon's supervisor refuses commands at the limits, so a
#: logged run never reaches them (10 % is left for the compensation and the margin).
LIMIT_SHARE = 0.9
#: Rate of the bending vector (rad/s): 11 % above Qi et al. 2023's pi/10 rad/s
#: (:data:`~cdcr_ctl.control.trajectory.QI2023_BEND_RATE_RAD_S`), so 60 s hold more reversals.
BEND_RATE_RAD_S = 0.35


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


def circle_trajectory(S: int, duration_s: float, theta_rad: float, rate_rad_s: float, seed: int):
    """Spatial circles at a fixed bend ``theta_rad`` (every segment, direction phi of segment i
    offset by a seeded angle): lead-in along phi0, one turn forward, one turn back (so that every
    cable reverses), repeated until ``duration_s``, then back to straight. The bending vector moves
    at ``rate_rad_s`` (phi rate = rate / theta)."""
    rng = np.random.default_rng(seed)
    phi0 = rng.uniform(0, 2 * math.pi, S)
    lead = theta_rad / rate_rad_s
    turn_s = 2 * math.pi * theta_rad / rate_rad_s
    t = [0.0, lead]
    phi_rel = [0.0, 0.0]
    th = [0.0, theta_rad]
    sign = 1.0
    while t[-1] + turn_s + lead <= duration_s + 1e-9:
        for _ in range(72):
            t.append(t[-1] + turn_s / 72)
            phi_rel.append(phi_rel[-1] + sign * 2 * math.pi / 72)
            th.append(theta_rad)
        sign = -sign
    t.append(t[-1] + lead)
    phi_rel.append(phi_rel[-1])
    th.append(0.0)
    th_a = np.array(th)[:, None] * np.ones(S)
    phi = np.array(phi_rel)[:, None] + phi0
    psi = np.stack((th_a, phi), axis=-1)
    return Trajectory(np.array(t), psi, f"circle_theta{theta_rad:g}_seed{seed}", "<circle>")


def planar_trajectory(S: int, duration_s: float, bend_rad: float, rate_rad_s: float, seed: int):
    """Qi et al. 2023's planar experiment: every segment bends in one plane (direction phi0,
    seeded) from straight to ``bend_rad`` and back, with partial reversals (to 45 % and 85 %)
    and short holds, at ``rate_rad_s`` (x0.6-1.0, seeded), until ``duration_s``."""
    rng = np.random.default_rng(seed)
    phi0 = rng.uniform(0, 2 * math.pi)
    t, th = [0.0], [0.0]
    while t[-1] < duration_s:
        for target in (1.0, 0.45, 0.85, 0.0):
            sp = rate_rad_s * rng.uniform(0.6, 1.0)
            t.append(t[-1] + abs(target * bend_rad - th[-1]) / sp)
            th.append(target * bend_rad)
            t.append(t[-1] + 0.3)
            th.append(th[-1])
    th_a = np.array(th)[:, None] * np.ones(S)
    psi = np.stack((th_a, np.full_like(th_a, phi0)), axis=-1)
    return Trajectory(np.array(t), psi, f"planar_seed{seed}", "<planar>")


def make_trajectory(kind: str, S: int, duration_s: float, bend_rad: float, seed: int):
    """``rich`` (reversals, holds, every direction, a circle, a random tail), ``random`` (seeded
    random smooth within ``bend_rad``), ``circle`` (turns back and forth at theta = bend_rad) or
    ``planar`` (go-and-returns in one plane with partial reversals)."""
    rate = BEND_RATE_RAD_S
    if kind == "planar":
        return planar_trajectory(S, duration_s, bend_rad, rate, seed)
    if kind == "rich":
        return rich_trajectory(S, duration_s, bend_rad, rate, seed)
    if kind == "random":
        return random_smooth(S, duration_s, bend_rad, rate, seed=seed, bandwidth_hz=0.3)
    if kind == "circle":
        return circle_trajectory(S, duration_s, bend_rad, rate, seed)
    raise SystemExit(f"unknown trajectory {kind!r} ({', '.join(TRAJECTORIES)})")


def trajectory_within_limits(
    cfg, model, kind: str, duration_s: float, bend_rad: float | None, seed: int
) -> tuple[Trajectory, float, str]:
    """The trajectory of ``kind`` and the bend it was made with (rad), and how it was chosen.

    ``bend_rad`` given: used as is. Otherwise :data:`PAPER_BEND_RAD`, capped by
    :data:`LIMIT_SHARE` of the rig's ``limits.bend_rad``, then reduced until the nominal cable
    displacements stay within :data:`LIMIT_SHARE` of ``limits.cable_displacement_mm`` (a
    multi-segment robot's distal cables add up every segment's bend).
    """
    S = model.n_segments
    if bend_rad is not None:
        return make_trajectory(kind, S, duration_s, bend_rad, seed), bend_rad, "given"
    bend = min(PAPER_BEND_RAD, LIMIT_SHARE * cfg.limits.bend_rad)
    q_lim = LIMIT_SHARE * min(abs(v) for v in cfg.limits.cable_displacement_mm)
    how = f"min(pi/2, {LIMIT_SHARE:g} x limits.bend_rad)"
    for _ in range(10):
        traj = make_trajectory(kind, S, duration_s, bend, seed)
        t = np.arange(0.0, traj.duration_s, 0.05)
        q_max = max(float(np.max(np.abs(model.q_nominal(traj.sample(ti))))) for ti in t)
        if q_max <= q_lim:
            return traj, bend, how
        bend *= 0.97 * q_lim / q_max
        how = f"reduced to keep the cables within {q_lim:g} mm"
    return traj, bend, how


def compensation_mode(
    cfg, model, traj: Trajectory, rate_hz: float, compensation: str | None
) -> tuple[str, str]:
    """The loop's compensation mode for the run, and why.

    Given: used as is. Otherwise the rig config's ``control.compensation`` (what the daemon
    runs) if its commands along ``traj`` stay within ``limits.cable_velocity_mm_s`` at every
    cycle; if not (the inverse model steps a cable by its friction dead zone at a reversal, e.g.
    ~1.5 mm in one cycle on a three-segment robot bent 80 deg per segment), the daemon's
    supervisor would HALT that run at the first such cycle, so a lab would log it uncompensated:
    ``off``. ``measured`` is checked as ``model`` (no readings before the run).
    """
    if compensation is not None:
        if compensation not in MODES:
            raise SystemExit(f"compensation {compensation!r}: choose off, model or measured")
        return compensation, "given"
    mode = cfg.control.compensation
    if mode == "off":
        return mode, "rig config"
    state = model.new_state()
    dt = 1.0 / rate_hz
    v_max = cfg.limits.cable_velocity_mm_s
    q_prev = None
    for i in range(round(traj.duration_s / dt) + 1):
        psi = traj.sample(i * dt)
        try:
            q = model.q_command(psi, model.q_nominal(psi), state, "model", None)
        except ModelError:
            continue
        if q_prev is not None and float(np.max(np.abs(q - q_prev))) > v_max * dt:
            return "off", (
                f"rig config's {mode!r} would step a cable faster than {v_max:g} mm/s at"
                f" t = {i * dt:.2f} s (the supervisor halts such a run): off"
            )
        q_prev = q
    return mode, "rig config"


def hidden_of(sim_path: Path, hidden: str | None) -> str:
    """``hidden``, else the simulator YAML's stem up to its first ``-`` (``gravity_direction-
    oblique.yaml`` hides ``gravity_direction``)."""
    name = hidden or sim_path.stem.split("-")[0]
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
    bend_rad: float | None = None,
    seed: int = 1,
    name: str | None = None,
    progress: bool = False,
    tracker_noise_mm: float | None = None,
    tracker_rate_hz: float | None = None,
    tracker_dropout: float = 0.0,
    drop: tuple[str, ...] = (),
    compensation: str | None = None,
) -> Path:
    """Write one run directory below ``out_dir`` and return it.

    ``bend_rad``: largest bend per segment (rad; default :func:`trajectory_within_limits`).
    ``compensation``: the loop's mode (``off``, ``model``, ``measured``; default
    :func:`compensation_mode`: the rig config's, what the daemon runs, unless the supervisor
    would halt it): the command is ``q_command(psi, q_nominal, ...)`` of the controller's model,
    as in the control loop.
    ``tracker_noise_mm``/``tracker_rate_hz`` override the simulator YAML's; ``tracker_dropout``
    is the probability that a tracker frame is lost (the row keeps the last frame, as the loop's
    latest-sample port does); ``drop`` lists column groups the log leaves out (``tension``,
    ``q_act``, ``tip``: a partial log).
    """
    loaded = load_sim_config(sim_path)
    cfg = loaded.rig
    hid = hidden_of(sim_path, hidden)
    bad = set(drop) - set(DROPPABLE)
    if bad:
        raise SystemExit(f"cannot drop {sorted(bad)}: choose from {DROPPABLE}")
    truth = TruthModel(loaded)
    truth.step_period_s = 1.0 / rate_hz  # stepped once per control cycle
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
    traj, bend, bend_how = trajectory_within_limits(
        cfg, model, trajectory, duration_s, bend_rad, seed
    )
    comp, comp_how = compensation_mode(cfg, model, traj, rate_hz, compensation)
    comp_state = model.new_state()
    rng = np.random.default_rng(seed + 1000)
    noise = loaded.sim.noise
    sigma_tip = noise.tracker_mm if tracker_noise_mm is None else tracker_noise_mm
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
    columns = [
        c for c in sample_columns(S, K, ("cycle",)) if not any(group_of(c) == g for g in drop)
    ]
    writer = RunLogWriter(
        run_dir,
        columns,
        RunMetadata(
            name=run_name,
            rig=cfg.name,
            design=cfg.design,
            compensation=comp,
            rate_hz=rate_hz,
            trajectory=traj.name,
            extra={
                "model_effects": {k: v for k, v in switches.items()},
                "generator": "scripts/make_discrepancy_runs.py (offline truth stepping)",
                "hidden_effect": hid,
                "sim_config": str(sim_path),
                "bend_rad": round(float(bend), 4),
                "bend_rule": bend_how,
                "compensation_rule": comp_how,
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
    frame_dt = 1.0 / (tracker_rate_hz or trk.rate_hz)
    # The tracker runs on its own clock: frame k is exposed at phase + k * frame_dt (a seeded
    # phase, so frame and loop instants do not coincide) and arrives latency_s later.
    phase_s = float(np.random.default_rng(seed + 2000).uniform(0.0, frame_dt))
    k_frame = 0
    last_frame: np.ndarray | None = None
    q_cmd_last: np.ndarray | None = None
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
            # frames exposed at t_c show the world of the last physics step at or before t_c
            while phase_s + k_frame * frame_dt + trk.latency_s <= t:
                tc = phase_s + k_frame * frame_dt
                k_frame += 1
                if tracker_dropout > 0 and rng.random() < tracker_dropout:
                    continue
                p = next(tp for tt, tp in reversed(tips) if tt <= tc)
                last_frame = R_o.T @ (p - t_o) + sigma_tip * rng.standard_normal(3)
            tens = truth.cell_tensions()
            measured = np.full(K, np.nan)  # load-cell readings in cable order (NaN: no cell)
            for k, j in cells.items():
                measured[k] = tens[j] + noise.load_cell_N * rng.standard_normal()
            # the loop's command: the controller's model, its compensation mode, the readings
            # of this cycle; a pose the model cannot reach holds the last command (as the loop)
            try:
                q_cmd = model.q_command(
                    psi, q_nom, comp_state, comp, measured if comp == "measured" else None
                )
            except ModelError:
                q_cmd = q_cmd_last if q_cmd_last is not None else q_nom
            q_cmd_last = q_cmd
            row = {"t_s": t, "cycle": i}
            for s in range(S):
                row[f"seg{s + 1}_theta_cmd_rad"] = float(psi[s, 0])
                row[f"seg{s + 1}_phi_cmd_rad"] = float(psi[s, 1])
            for k in range(K):
                row[f"cable{k + 1}_q_nominal_mm"] = float(q_nom[k])
                row[f"cable{k + 1}_q_cmd_mm"] = float(q_cmd[k])
                if "q_act" not in drop:
                    row[f"cable{k + 1}_q_act_mm"] = float(q_act[k])
                if k in cells and "tension" not in drop:
                    row[f"cable{k + 1}_tension_N"] = float(measured[k])
            if last_frame is not None and "tip" not in drop:
                row["tip_x_mm"], row["tip_y_mm"], row["tip_z_mm"] = (float(v) for v in last_frame)
            writer.write(row)
            counts = np.round(q_cmd * cpm)
            if len(tips) > 64:
                tips = tips[-32:]
    return run_dir


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sim", type=Path, action="append", help="simulator YAML (repeatable)")
    ap.add_argument(
        "--sim-dir",
        type=Path,
        default=EFFECTS_DIR,
        help="directory of variants when no --sim is given (default config/sim/effects)",
    )
    ap.add_argument("--hidden", choices=HIDDEN, default=None)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--trajectory", default="rich", choices=TRAJECTORIES)
    ap.add_argument(
        "--bend-rad",
        type=float,
        default=None,
        help="bend limit (rich, random) or circle theta, rad [default: pi/2 within the rig's"
        " limits, see trajectory_within_limits]",
    )
    ap.add_argument(
        "--compensation",
        choices=MODES,
        default=None,
        help="the loop's compensation mode [default: the rig config's control.compensation]",
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--tracker-noise-mm", type=float, default=None, help="override the YAML's")
    ap.add_argument("--tracker-rate-hz", type=float, default=None, help="override the YAML's")
    ap.add_argument("--tracker-dropout", type=float, default=0.0, help="lost frame probability")
    ap.add_argument(
        "--drop",
        default="",
        help=f"comma-separated column groups to leave out (partial log): {', '.join(DROPPABLE)}",
    )
    args = ap.parse_args(argv)
    sims = args.sim or sorted(p for p in args.sim_dir.glob("*.yaml"))
    drop = tuple(d.strip() for d in args.drop.split(",") if d.strip())
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
            tracker_noise_mm=args.tracker_noise_mm,
            tracker_rate_hz=args.tracker_rate_hz,
            tracker_dropout=args.tracker_dropout,
            drop=drop,
            compensation=args.compensation,
        )
        print(d)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
