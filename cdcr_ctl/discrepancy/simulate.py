"""Forward simulation of a logged run with a :class:`~cdcr_ctl.model.cc_disk.effects.ModelSpec`.

The spec's :class:`~cdcr_ctl.model.cc_disk.forward.ForwardStepper` (friction memory, transmission
effects) is stepped through the decimated input path of the run (``AlignedRun.sim_idx``); the
predictions are then interpolated to every row along the input path (:func:`path_weights`); the
tip as the run's rigid-cable kinematic tip (``AlignedRun.shape_tip_mm``, every row) plus the
interpolated difference of the model from it: that difference (stretch, friction, sag) is small
and smooth, while the tip itself turns between simulated rows on a fast multi-segment robot.
A step the model cannot solve keeps the last solution and is counted. A spec with a
``coupling_gain`` between the forward model's two switch positions is the blend of both
solutions (:class:`SegmentCoupling`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cdcr_ctl.discrepancy.alignment import AlignedRun
from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.effects import ModelSpec, rotation_from_rotvec
from cdcr_ctl.model.cc_disk.forward import ForwardStepper
from cdcr_ctl.model.cc_disk.friction_law import cable_speeds, law_stepper


@dataclass(frozen=True)
class Prediction:
    """Model outputs at every row of a run: tip (N, 3) mm as the tracker would report it,
    tensions at the load-cell locations (N, K) N, pose (N, S, 2) rad, failed steps. Once the
    tracker timing is applied (workflow): the tip's velocity (mm/s) and acceleration (mm/s^2)
    at the same instants, from the untimed series (the timed one mixes the delays of
    neighbouring rows, so its finite differences are not the tip's velocity)."""

    tip_mm: np.ndarray
    tension_N: np.ndarray
    psi: np.ndarray
    failures: int
    tip_velocity_mm_s: np.ndarray | None = None
    tip_accel_mm_s2: np.ndarray | None = None


def path_weights(q: np.ndarray, t: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every row: the simulated row before it (index into ``idx``) and the fraction u of the
    way to the next one, measured along the input path: u = (q - q_a).(q_b - q_a) / |q_b - q_a|^2
    (clipped to [0, 1]; by time when the inputs did not move). The model is a smooth function of
    q between simulated rows, so this is far better than interpolating in time."""
    n = len(t)
    seg = np.clip(np.searchsorted(idx, np.arange(n), side="right") - 1, 0, len(idx) - 2)
    if len(idx) < 2:
        return np.zeros(n, dtype=int), np.zeros(n)
    a, b = idx[seg], idx[seg + 1]
    dq = q[b] - q[a]
    den = np.einsum("ij,ij->i", dq, dq)
    num = np.einsum("ij,ij->i", q - q[a], dq)
    tt = (t - t[a]) / np.maximum(t[b] - t[a], 1e-12)
    u = np.where(den > 1e-12, num / np.maximum(den, 1e-300), tt)
    return seg, np.clip(u, 0.0, 1.0)


def _interp(seg: np.ndarray, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    if len(y) < 2:
        return np.repeat(y[:1], len(seg), axis=0)
    flat = y.reshape(len(y), -1)
    out = flat[seg] + u[:, None] * (flat[seg + 1] - flat[seg])
    return out.reshape((len(seg), *y.shape[1:]))


def _step_path(spec: ModelSpec, run: AlignedRun) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    law = spec.friction_law
    idx = run.sim_idx
    speeds = None
    if law is None or law.capstan:
        stepper = ForwardStepper(spec.params, spec.effects)
    else:
        stepper = law_stepper(spec.params, spec.effects, law)
        if law.speed_dependent:  # every row's drive speed, then the simulated rows'
            speeds = cable_speeds(run.t_s, run.q_in_mm)[idx]
    K, S = run.n_cables, spec.params.n_segments
    tip = np.empty((len(idx), 3))
    T = np.empty((len(idx), K))
    psi = np.empty((len(idx), S, 2))
    fails = 0
    last = None
    base = [loc == "robot_base" for loc in run.locations]
    for n, i in enumerate(idx):
        if speeds is not None:
            stepper.model.ft.set_speeds(speeds[n])
            stepper.model.forget_evaluation()
        try:
            last = stepper.step(run.q_in_mm[i])
        except ModelError:
            fails += 1
            if last is None:
                raise
        tip[n] = last.tip_mm
        T[n] = np.where(base, last.tension_base_N, last.tension_actuator_N)
        psi[n] = last.psi
    return tip, T, psi, fails


def model_part(spec: ModelSpec) -> ModelSpec:
    """``spec`` without its tip measurement map (what the forward simulation depends on), with
    a coupling gain of exactly 0 or 1 turned into the switch."""
    spec = replace(spec, tip_rotvec_rad=(0.0, 0.0, 0.0), tip_translation_mm=(0.0, 0.0, 0.0))
    lam = spec.coupling_gain
    if lam is not None and lam in (0.0, 1.0):
        spec = replace(spec, effects=replace(spec.effects, coupling=lam == 1.0), coupling_gain=None)
    elif lam is not None and lam == (1.0 if spec.effects.coupling else 0.0):
        spec = replace(spec, coupling_gain=None)
    return spec


def simulate_model(spec: ModelSpec, run: AlignedRun) -> Prediction:
    """Predictions of ``spec`` without its tip map (see :func:`model_part`)."""
    spec = model_part(spec)
    lam = spec.coupling_gain
    if lam is None:
        tip, T, psi, fails = _step_path(spec, run)
    else:
        a = _step_path(replace(spec, effects=replace(spec.effects, coupling=False)), run)
        b = _step_path(replace(spec, effects=replace(spec.effects, coupling=True)), run)
        tip, T, psi = ((1.0 - lam) * x + lam * y for x, y in zip(a[:3], b[:3], strict=True))
        fails = a[3] + b[3]
    seg, u = path_weights(run.q_in_mm, run.t_s, run.sim_idx)
    # the tip between simulated rows: the rigid-cable kinematic tip of every row plus the
    # interpolated (smooth, small) difference of the model from it, not the chord of the path
    shape = run.shape_tip_mm
    return Prediction(
        tip_mm=shape + _interp(seg, u, tip - shape[run.sim_idx]),
        tension_N=_interp(seg, u, T),
        psi=_interp(seg, u, psi),
        failures=fails,
    )


def with_tip_map(spec: ModelSpec, pred: Prediction) -> Prediction:
    """``pred`` (of the model part of ``spec``) as the tracker reports it (the map is rigid:
    velocity and acceleration turn with it)."""
    R = rotation_from_rotvec(spec.tip_rotvec_rad)
    v, a = pred.tip_velocity_mm_s, pred.tip_accel_mm_s2
    return replace(
        pred,
        tip_mm=spec.tip_map(pred.tip_mm),
        tip_velocity_mm_s=None if v is None else v @ R.T,
        tip_accel_mm_s2=None if a is None else a @ R.T,
    )


def simulate(spec: ModelSpec, run: AlignedRun) -> Prediction:
    """Predictions of ``spec`` at every row of ``run`` (see module doc)."""
    return with_tip_map(spec, simulate_model(spec, run))
