"""Load a logged run for discrepancy analysis: the controller's model, the inputs, the measurements.

* The model is the one the run's controller used: built from the run's ``config_effective.yaml``
  (or ``config.yaml``, or a rig config given by the user) as
  :func:`~cdcr_ctl.config.build_model.build_cc_disk_model` builds it (the switches and coupling
  gain of ``control.model_effects``, ``control.geometry``), with the switches the run records in
  ``run.yaml`` under ``extra.model_effects`` when it records any.
* The input of the simulation is the drive feedback ``q_act`` (the actuator really went there);
  logs without it fall back on the commands ``q_cmd``.
* Decimation: the quasi-static model is rate independent, so only the path of the inputs matters.
  A sample is simulated when any cable moved more than ``delta_q_mm`` since the last simulated one
  (reversals are kept to within delta_q), or ``hold_s`` passed; ``delta_q_mm`` is chosen so at most
  ``max_points`` samples are simulated. Predictions at the other rows are linear in time between
  simulated ones (exact during holds).
* Noise: from the measurements alone (no model): the robust spread of the second differences of
  the distinct tracker samples (white noise: var(d2) = 6 sigma^2), and of the tensions. Once the
  tracker timing is known (:mod:`~cdcr_ctl.discrepancy.timing`, estimated by the workflow from
  the controller model's residual) the tip noise is re-estimated from the residual's second
  differences (:func:`residual_noise_sigma`): the sampling jitter of a moving tip is not noise.
* Cycle numbers: the loop's ``cycle`` column when the log has one (a dropped row leaves a gap),
  else the row index; the tracker's beat with the loop is periodic in them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from cdcr_ctl.config.build_model import friction_law, loadcell_locations, robot_params
from cdcr_ctl.config.loader import load_rig_config, validate_mapping
from cdcr_ctl.config.registry import design_of
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.discrepancy.timing import TipTiming, no_timing
from cdcr_ctl.errors import ConfigError, RigError
from cdcr_ctl.model.cc_disk.effects import ModelSpec, with_cable_play
from cdcr_ctl.model.cc_disk.kinematics import tip_position_fast
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.model.cc_disk.routing import cable_matrix_x
from cdcr_ctl.runlog.reader import Run, load_run
from cdcr_ctl.runlog.writer import CONFIG_YAML, EFFECTIVE_CONFIG_YAML

#: Switches of :class:`Effects` a run may record under ``run.yaml`` ``extra.model_effects``.
SWITCHES = ("disk_friction", "pulley_friction", "elongation", "coupling", "gravity")
#: Smallest noise levels assumed (a noise-free log must not make every residual "significant").
MIN_TIP_SIGMA_MM = 0.01
MIN_TENSION_SIGMA_N = 0.005


@dataclass
class AlignedRun:
    """One run ready for simulation: rows with a usable input, measurements, the model.

    Arrays over the N kept rows: ``t_s``; ``q_in_mm`` (N, K) the model input; ``tip_mm`` (N, 3)
    measured (NaN where untracked); ``tension_N`` (N, K) or None; ``psi_cmd`` (N, S, 2) or None.
    ``sim_idx``: indices of the rows that are simulated. ``spec``: the controller's model.
    ``locations``: load-cell location per cable. Noise ``sigma_tip_mm``, ``sigma_tension_N``.
    ``cycle`` (N,) the loop's cycle numbers; ``timing`` when each row's tracker sample was taken
    (identity until the workflow has estimated it). ``shape_tip_mm`` (N, 3): the rigid-cable
    constant-curvature tip of every row's input (:func:`kinematic_tip`), the shape the
    simulations are interpolated along.
    """

    run_dir: Path
    name: str
    cfg: RigConfig
    spec: ModelSpec
    locations: list[str]
    t_s: np.ndarray
    q_in_mm: np.ndarray
    q_source: str
    tip_mm: np.ndarray
    tension_N: np.ndarray | None
    psi_cmd: np.ndarray | None
    sim_idx: np.ndarray
    delta_q_mm: float
    sigma_tip_mm: float
    sigma_tension_N: float
    notes: list[str] = field(default_factory=list)
    cycle: np.ndarray | None = None
    timing: TipTiming | None = None
    shape_tip_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.cycle is None:
            self.cycle = np.arange(len(self.t_s))
        if self.timing is None:
            self.timing = no_timing(self.t_s)
        if self.shape_tip_mm is None:
            self.shape_tip_mm = kinematic_tip(self.spec.params, self.q_in_mm)

    @property
    def n_cables(self) -> int:
        return self.q_in_mm.shape[1]

    @property
    def has_tensions(self) -> bool:
        return self.tension_N is not None and bool(np.isfinite(self.tension_N).any())


def run_rig_config(run: Run, rig_config: str | Path | None = None) -> tuple[RigConfig, str]:
    """The controller's rig config: ``rig_config`` if given, else the run's effective config,
    else its ``config.yaml`` (which may ``extends:`` files that are no longer there)."""
    if rig_config is not None:
        return load_rig_config(rig_config), str(rig_config)
    eff = run.run_dir / EFFECTIVE_CONFIG_YAML
    if eff.is_file():
        data = yaml.safe_load(eff.read_text(encoding="utf-8"))
        return validate_mapping(data, RigConfig, str(eff)), str(eff)
    cfg = run.run_dir / CONFIG_YAML
    if cfg.is_file():
        return load_rig_config(cfg), str(cfg)
    raise RigError(f"{run.run_dir}: no {EFFECTIVE_CONFIG_YAML} or {CONFIG_YAML}; give -c/--config")


def model_switches(
    run: Run, override: dict[str, bool] | None = None, cfg: RigConfig | None = None
) -> tuple[dict, str]:
    """The controller model's effect switches: the rig config's ``control.model_effects`` (all
    on without ``cfg``), then ``run.yaml`` ``extra.model_effects``, then ``override``. Returns
    (switches, where they came from)."""
    if cfg is None:
        sw = {k: True for k in SWITCHES}
        src = "defaults (every effect on)"
    else:
        me = cfg.control.model_effects
        sw = {k: bool(getattr(me, k)) for k in SWITCHES}
        src = "the rig config's control.model_effects"
    extra = run.metadata.get("extra") or {}
    rec = extra.get("model_effects") if isinstance(extra, dict) else None
    if isinstance(rec, dict):
        for k, v in rec.items():
            if k in sw and isinstance(v, bool):
                sw[k] = v
        src = f"{run.run_dir.name}/run.yaml extra.model_effects"
    if override:
        for k, v in override.items():
            if k not in sw:
                raise ConfigError("--model-effects", k, f"not one of {', '.join(SWITCHES)}")
            sw[k] = bool(v)
        src += " + command line"
    return sw, src


def kinematic_tip(params, q_mm: np.ndarray) -> np.ndarray:
    """Tip (N, 3) mm, base frame, of rigid cables on constant-curvature segments for the cable
    displacements ``q_mm`` (N, K): bending vectors x = B^+ q (Qi et al. 2023 eq. 4, linear in x;
    least squares over the cables), tip by eq. 1-3. No statics, no elongation, no friction: a
    cheap, smooth function of q that differs from the full model by a smooth correction."""
    B = cable_matrix_x(params)
    X = np.asarray(q_mm, dtype=float) @ np.linalg.pinv(B).T
    L = [s.length_mm for s in params.segments]
    return np.array([tip_position_fast(x.tolist(), L) for x in X]).reshape(len(X), 3)


def noise_sigma(x: np.ndarray, floor: float) -> float:
    """Noise standard deviation of a sampled signal (..., C) from its distinct samples.

    sigma = 1.4826 * MAD(d2) / sqrt(6), d2 the second differences of the samples that changed
    (a sample-and-hold sensor repeats values); robust to the smooth motion and to outliers.
    """
    return residual_noise_sigma(x, np.zeros_like(x), floor)


def residual_noise_sigma(meas: np.ndarray, pred: np.ndarray, floor: float) -> float:
    """Noise standard deviation of a sensor from its residual against a model (..., C): the
    robust spread of the second differences of ``meas - pred`` over the rows where the sensor
    delivered a new sample (a sample-and-hold sensor repeats values), divided by sqrt(6).
    The model's own error is smooth and drops out of the second differences."""
    out = []
    for c in range(meas.shape[1]):
        v, p = meas[:, c], pred[:, c]
        ok = np.isfinite(v) & np.isfinite(p)
        v, p = v[ok], p[ok]
        if v.size < 10:
            continue
        keep = np.concatenate(([True], np.diff(v) != 0.0))
        r = (v - p)[keep]
        if r.size < 10:
            continue
        d2 = r[2:] - 2 * r[1:-1] + r[:-2]
        out.append(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))
    return max(float(np.median(out)) if out else floor, floor)


def decimate(
    q: np.ndarray, t: np.ndarray, max_points: int, hold_s: float
) -> tuple[np.ndarray, float]:
    """Indices of the rows to simulate and the movement threshold used (mm); see module doc."""
    n = len(q)
    if n <= max_points:
        return np.arange(n), 0.0
    path = float(np.sum(np.max(np.abs(np.diff(q, axis=0)), axis=1)))
    delta = max(path / max(max_points - int(t[-1] - t[0]) // max(hold_s, 1e-9) - 2, 10), 1e-6)
    for _ in range(20):
        idx = _select(q, t, delta, hold_s)
        if len(idx) <= max_points:
            return idx, delta
        delta *= 1.25
    return idx, delta


def turning_points(q: np.ndarray, eps_mm: float) -> np.ndarray:
    """Rows where some cable reverses: the extreme row once the cable is ``eps_mm`` back from it.

    Per cable, a running extreme in the current direction; a move of more than ``eps_mm`` the
    other way marks the extreme as a turning point (hysteresis against encoder noise).
    """
    out: set[int] = set()
    for k in range(q.shape[1]):
        v = q[:, k]
        ext_i, direction = 0, 0
        for i in range(1, len(v)):
            if (direction >= 0 and v[i] >= v[ext_i]) or (direction <= 0 and v[i] <= v[ext_i]):
                if direction == 0 and abs(v[i] - v[0]) > eps_mm:
                    direction = 1 if v[i] > v[0] else -1
                if direction != 0:
                    ext_i = i
            elif abs(v[i] - v[ext_i]) > eps_mm:
                out.add(ext_i)
                direction, ext_i = -direction, i
    return np.array(sorted(out), dtype=int)


def _select(q: np.ndarray, t: np.ndarray, delta: float, hold_s: float) -> np.ndarray:
    """Rows every ``delta`` mm of travel (a third of that within 3 delta after a reversal, where
    stick makes the model kink), every ``hold_s``, and at every turning point."""
    turns = turning_points(q, delta / 5.0)
    is_turn = np.zeros(len(q), dtype=bool)
    is_turn[turns] = True
    keep = [0]
    last_q = q[0]
    last_t = t[0]
    last_turn_q = q[0]  # the run starts from rest: friction mobilises as after a reversal
    for i in range(1, len(q)):
        near = last_turn_q is not None and np.max(np.abs(q[i] - last_turn_q)) < 3.0 * delta
        step = delta / 3.0 if near else delta
        if is_turn[i] or np.max(np.abs(q[i] - last_q)) >= step or t[i] - last_t >= hold_s:
            keep.append(i)
            last_q = q[i]
            last_t = t[i]
        if is_turn[i]:
            last_turn_q = q[i]
    if keep[-1] != len(q) - 1:
        keep.append(len(q) - 1)
    return np.asarray(keep)


def align_run(
    run_dir: str | Path,
    rig_config: str | Path | None = None,
    model_effects: dict[str, bool] | None = None,
    max_points: int = 700,
    hold_s: float = 0.5,
) -> AlignedRun:
    """Load ``run_dir`` and prepare it (see module doc). Raises :class:`RigError` for runs that
    cannot be analysed (no tracker and no tensions, no input columns, not a cc_disk rig)."""
    run = load_run(run_dir)
    cfg, cfg_src = run_rig_config(run, rig_config)
    notes = [f"controller's rig config: {cfg_src}"]
    if not design_of(cfg.design).identify:
        raise RigError(
            f"{run.run_dir}: design {cfg.design}: the discrepancy library needs a design"
            " registered with identify=True (cc_disk)"
        )
    sw, sw_src = model_switches(run, model_effects, cfg)
    off = [k for k, v in sw.items() if not v]
    notes.append(
        f"controller's model switches from {sw_src}: "
        + (f"off: {', '.join(off)}" if off else "all on")
    )
    params = robot_params(cfg.robot)
    # The controller's model as build_model makes it: the cables' lost motion included.
    gain = cfg.control.model_effects.coupling_gain
    eff = Effects(geometry=cfg.control.geometry, coupling_gain=gain, **sw)
    spec = ModelSpec(params, with_cable_play(params, eff), friction_law=friction_law(cfg.robot))
    if spec.friction_law is not None:
        notes.append(f"controller's disk friction law (robot.friction_law): {spec.friction_law}")
    if run.has("q_act"):
        q = run.q_act()
        q_src = "q_act"
    elif run.has("q_cmd"):
        q = run.q_cmd()
        q_src = "q_cmd"
        notes.append("no drive feedback (q_act): the model is driven by the commands q_cmd")
    else:
        raise RigError(f"{run.samples_path}: neither q_act nor q_cmd columns: nothing to simulate")
    if q.shape[1] != params.n_cables:
        raise RigError(
            f"{run.samples_path}: {q.shape[1]} cable columns, the config has {params.n_cables}"
        )
    ok = np.all(np.isfinite(q), axis=1)
    if not ok.all():
        notes.append(f"{int((~ok).sum())} rows without input dropped")
    t = run.t_s[ok]
    q = q[ok]
    tip = run.tip()[ok] if run.has("tip") else np.full((len(t), 3), np.nan)
    tens = run.tension()[ok] if run.has("tension") else None
    if tens is not None and not np.isfinite(tens).any():
        tens = None
    if tens is None:
        notes.append("no tension columns: effects that need tensions are skipped")
    if not np.isfinite(tip).any() and tens is None:
        raise RigError(f"{run.samples_path}: neither tracker nor tension columns to compare with")
    if not np.isfinite(tip).any():
        notes.append("no tracker columns: only tensions are compared")
    psi = run.psi_cmd()[ok] if run.has("psi_cmd") else None
    cycle = np.arange(len(ok))[ok]
    if "cycle" in run.data:
        c = np.asarray(run.column("cycle"), dtype=float)[ok]
        if np.all(np.isfinite(c)) and np.all(np.diff(c) > 0):
            cycle = c.astype(np.int64)
    idx, dq = decimate(q, t, max_points, hold_s)
    notes.append(
        f"{len(t)} rows, {len(idx)} simulated (a sample per {dq:.3f} mm of cable travel or"
        f" {hold_s:g} s)"
    )
    s_tip = noise_sigma(tip, MIN_TIP_SIGMA_MM)
    s_T = noise_sigma(tens, MIN_TENSION_SIGMA_N) if tens is not None else MIN_TENSION_SIGMA_N
    return AlignedRun(
        run_dir=run.run_dir,
        name=run.run_dir.name,
        cfg=cfg,
        spec=spec,
        locations=list(loadcell_locations(cfg)),
        t_s=t,
        q_in_mm=q,
        q_source=q_src,
        tip_mm=tip,
        tension_N=tens,
        psi_cmd=psi,
        sim_idx=idx,
        delta_q_mm=dq,
        sigma_tip_mm=s_tip,
        sigma_tension_N=s_T,
        notes=notes,
        cycle=cycle,
    )
