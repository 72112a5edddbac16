"""Synthetic calibration runs for the identification tests (imported as ``synth``).

The simulated world is a :class:`~cdcr_ctl.model.ForwardStepper` with the truth parameters of
``config/sim/qi2023-truth.yaml`` (tests may read the truth; the library may not). It is driven
through the calibration sweep with the controller's own commands (nominal model, compensation
off by default), and the run directory is written with the project's run-log writer: commanded
pose, q_nominal, q_cmd, q_act (= q_cmd: ideal drives), load-cell tensions at the config's
location with Gaussian noise, tracker tip with Gaussian noise.

Only the dwells are sampled densely (``samples_per_dwell`` rows each); each move between dwells
gets ``move_rows`` rows (the quasi-static world is rate independent, so the truth only needs the
path, not 250 Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model, loadcell_locations, robot_params
from cdcr_ctl.control.trajectory import Trajectory
from cdcr_ctl.identify.sweep import CalibrationSweep
from cdcr_ctl.model import Effects, ForwardStepper
from cdcr_ctl.model.cc_disk.params import RobotParams
from cdcr_ctl.runlog import RunLogWriter, RunMetadata, sample_columns
from cdcr_ctl.sim.friction_law import use_friction_law
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[2]
RIG_CONFIG = ROOT / "config" / "qi2023.yaml"
SIM_CONFIG = ROOT / "config" / "sim" / "qi2023-truth.yaml"


@dataclass(frozen=True)
class World:
    """The truth: parameters and effects of the simulated robot; ``wrap_exponent``: disk
    friction of the simulator's ``wrap_power`` law with this exponent (None: the capstan law)."""

    params: RobotParams
    effects: Effects
    wrap_exponent: float | None = None


def truth_world(sim_config: Path = SIM_CONFIG) -> World:
    """Truth parameters and effects as the simulator builds them (cdcr_ctl.sim.truth)."""
    loaded = load_sim_config(sim_config)
    eff = loaded.sim.effects
    effects = Effects(
        disk_friction=eff.disk_friction,
        pulley_friction=eff.pulley_friction,
        elongation=eff.elongation,
        coupling=eff.coupling,
        gravity=eff.gravity,
        geometry=eff.geometry,
    )
    return World(robot_params(loaded.truth), effects)


def perturbed_world(
    seed: int, spread: tuple[float, float] = (0.2, 0.35), pulleys: bool = True
) -> World:
    """A truth the tests make up: every cable's mu and EA, the backbone EI, the pretensions and
    the pulley alpha (unless ``pulleys`` is false) of the nominal config scaled by random
    factors 1 +- U(spread) (seeded),
    with the effects the simulator uses by default (chord geometry, everything on)."""
    from cdcr_ctl.model.cc_disk.identification import ParamRef, get_value, with_values

    nominal = robot_params(load_rig_config(RIG_CONFIG).robot)
    rng = np.random.default_rng(seed)
    refs = [ParamRef("segment", 0, "EI_Nmm2"), ParamRef("pulley", "guide_a", "alpha")]
    refs += [ParamRef("pulley", "guide_b", "alpha")]
    for k in range(nominal.n_cables):
        refs += [ParamRef("cable", k, f) for f in ("mu_disk", "EA_N")]
    values = []
    for ref in refs:
        f = 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(*spread)
        if ref.kind == "pulley" and not pulleys:
            values.append(get_value(nominal, ref))
            continue
        if ref.kind == "pulley" and ref.index == "guide_b":
            values.append(values[-1])  # the two guide pulleys stay alike
            continue
        values.append(get_value(nominal, ref) * f)
    for k in range(nominal.n_cables):
        refs.append(ParamRef("cable", k, "pretension_N"))
        values.append(get_value(nominal, refs[-1]) * (1.0 + rng.uniform(-0.1, 0.1)))
    return World(with_values(nominal, refs, values), Effects(geometry="chord"))


def with_play(params: RobotParams, play_mm: tuple[float, ...]) -> RobotParams:
    """``params`` with each cable's lost motion (mm) set."""
    from dataclasses import replace

    cables = tuple(replace(c, backlash_mm=b) for c, b in zip(params.cables, play_mm, strict=True))
    return replace(params, cables=cables)


def write_run(
    run_dir: Path,
    sweep: CalibrationSweep | Trajectory,
    world: World,
    rig_config: Path = RIG_CONFIG,
    *,
    tension_noise_N: float = 0.02,
    tip_noise_mm: float = 0.05,
    samples_per_dwell: int = 20,
    move_rows: int = 2,
    compensation: str = "off",
    seed: int = 1,
) -> Path:
    """Drive the truth through ``sweep`` with the controller's commands; write a run dir."""
    cfg = load_rig_config(rig_config)
    model = build_model(cfg)
    locs = loadcell_locations(cfg)
    traj = sweep.trajectory if isinstance(sweep, CalibrationSweep) else sweep
    S, K = model.n_segments, model.n_cables
    rng = np.random.default_rng(seed)
    stepper = ForwardStepper(world.params, world.effects)
    if world.wrap_exponent is not None:
        use_friction_law(stepper, "wrap_power", exponent=world.wrap_exponent)
    state = model.new_state()
    times = _row_times(traj, samples_per_dwell, move_rows)
    writer = RunLogWriter(
        run_dir,
        sample_columns(S, K),
        RunMetadata(
            name="calibration_sweep",
            rig=cfg.name,
            design=cfg.design,
            compensation=compensation,
            trajectory=traj.name,
        ),
        config_text=rig_config.read_text(),
        config_source=str(rig_config),
    )
    last_q = None
    res = None
    with writer:
        for t in times:
            psi = traj.sample(float(t))
            q_nom = model.q_nominal(psi)
            q_cmd = model.q_command(psi, q_nom, state, compensation, None)
            if last_q is None or np.any(q_cmd != last_q):
                res = stepper.step(q_cmd)
                last_q = q_cmd.copy()
            T = np.array([res.tension_at(loc)[k] for k, loc in enumerate(locs)])
            T = T + tension_noise_N * rng.standard_normal(K)
            tip = res.tip_mm + tip_noise_mm * rng.standard_normal(3)
            row = {"t_s": float(t)}
            for i in range(S):
                row[f"seg{i + 1}_theta_cmd_rad"] = float(psi[i, 0])
                row[f"seg{i + 1}_phi_cmd_rad"] = float(psi[i, 1])
            for k in range(K):
                row[f"cable{k + 1}_q_nominal_mm"] = float(q_nom[k])
                row[f"cable{k + 1}_q_cmd_mm"] = float(q_cmd[k])
                row[f"cable{k + 1}_q_act_mm"] = float(q_cmd[k])
                row[f"cable{k + 1}_tension_N"] = float(T[k])
            row["tip_x_mm"], row["tip_y_mm"], row["tip_z_mm"] = (float(v) for v in tip)
            writer.write(row)
    return run_dir


def _row_times(traj: Trajectory, per_dwell: int, move_rows: int) -> np.ndarray:
    """Row times: ``per_dwell`` rows inside every constant stretch, ``move_rows`` inside moves."""
    t = traj.t_s
    x = traj.x.reshape(len(t), -1)
    out = []
    for n in range(len(t) - 1):
        a, b = float(t[n]), float(t[n + 1])
        still = bool(np.all(x[n] == x[n + 1]))
        m = per_dwell if still else move_rows
        out += (
            list(a + (b - a) * np.arange(m) / m)
            if still
            else list(a + (b - a) * (np.arange(m) + 1) / (m + 1))
        )
        if still:
            out.append(b - 1e-6 * (b - a))
    out.append(float(t[-1]))
    return np.array(sorted(set(out)))


def mean_tip_error(world: World, commands: list[np.ndarray], targets: list[np.ndarray]) -> float:
    """Mean |tip - target| (mm) when the truth is driven through ``commands`` in order."""
    stepper = ForwardStepper(world.params, world.effects)
    errs = [
        float(np.linalg.norm(stepper.step(q).tip_mm - tgt))
        for q, tgt in zip(commands, targets, strict=True)
    ]
    return float(np.mean(errs))


def angle(deg: float) -> float:
    return math.radians(deg)
