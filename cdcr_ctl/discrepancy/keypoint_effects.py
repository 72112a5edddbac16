"""The effects ``discrepancy`` searches on tip-only keypoint logs, each fitted alone on top of
the config's forward replay and judged on the held-out rows.

Real multi-segment robots depart from the constant-curvature, nominal-geometry model in a few
recurring ways; each is a candidate here, with the parameters that describe it:

* ``curvature`` -- **curvature that is not constant along a segment** (a backbone stiffer at
  one end, friction that decays along the length): per segment i a linear profile
  kappa(s) = (theta_i / L_i) (1 + c_i (1 - 2 s / L_i)), c_i in [-0.9, 0.9]. The total bend
  theta_i and the plane phi_i are the replay's (so is the end frame's rotation, Qi et al. 2023
  eq. 1); only the segment's end point moves: in the bending plane
  u = int_0^L sin(alpha(s)) ds, w = int_0^L cos(alpha(s)) ds with
  alpha(s) = (theta/L)(s + c (s - s^2/L)) (12-point Gauss-Legendre; c = 0 gives eq. 2 exactly).
  Kinematic: no new replay. 3 parameters.
* ``registration`` -- **base/registration error**: the tracker's tip is R p + t with a small
  rotation (rotation vector, rad) and a translation (mm), fitted in closed form (Kabsch, no
  scale) on the fitted rows. Kinematic. 6 parameters.
* ``routing`` -- **tendon routing offsets**: hole-angle offset per segment and the routing
  radius (shared scale), fitted through the replay (:mod:`cdcr_ctl.identify.replay_fit`).
* ``hysteresis`` -- **hysteresis per segment**: a lost motion (play, mm) per segment shared by
  its cables (Yang et al. 2022 eq. 13-17), fitted through the replay.
* ``gravity`` -- **gravity sag of the whole arm**: one scale on every disk mass (the arm is
  heavier along its length than the config says: cables, glue) and a mass at the tip (a
  marker, a tool: the config's ``robot.tip_load.payload_kg``, whose weight acts at the tip,
  Qi et al. 2023 eq. 7-9 external load), fitted through the replay. The tip mass loads every
  segment with a moment that grows with the distance from it to the tip, the disk masses each
  segment with its own and the distal ones: a sag whose share between the segments no
  routing change makes.

Every candidate is fitted on the rows before the hold-out cut and scored by the held-out tip
RMSE (the shrink 1 - RMSE_effect / RMSE_config); the held-out rows never enter a fit.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from cdcr_ctl.identify import replay_fit
from cdcr_ctl.identify.keypoints import candidates
from cdcr_ctl.identify.observability import tolerance
from cdcr_ctl.identify.parameters import FitParameter
from cdcr_ctl.identify.replay_fit import Evaluator, ReplayProblem, RunRows
from cdcr_ctl.model.cc_disk.forward import replay
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.identification import ParamRef
from cdcr_ctl.model.cc_disk.kinematics import rotation
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams

EFFECTS = ("curvature", "registration", "routing", "hysteresis", "gravity")
TITLES = {
    "curvature": "curvature not constant along the segments",
    "registration": "base/registration error of the tracker",
    "routing": "tendon routing offsets (hole angles, radius)",
    "hysteresis": "hysteresis per segment (lost motion)",
    "gravity": "gravity sag of the whole arm (heavier than the config)",
}
_GL_X, _GL_W = np.polynomial.legendre.leggauss(12)


@dataclass
class EffectFit:
    """One candidate's fit: parameter names, values, held-out tip RMSE (mm) and shrink;
    ``err2_heldout``: the squared tip error (mm^2) of every held-out row in time order (NaN
    where no solution), for paired comparisons between candidates."""

    name: str
    names: list[str]
    values: list[float]
    rmse_heldout: float
    shrink: float
    seconds: float
    params: RobotParams | None = None  # for replay effects: the fitted parameters
    err2_heldout: np.ndarray | None = None
    #: for replay effects: the fitted replay's tips (N, 3) mm at every row of each run's path
    tips_full: list[np.ndarray] | None = None

    @property
    def title(self) -> str:
        return " + ".join(TITLES[n] for n in self.name.split("+"))


def segment_tip(x: np.ndarray, lengths: Sequence[float], c: Sequence[float]) -> np.ndarray:
    """Tips (N, 3) mm of bending vectors ``x`` (N, 2S) rad with curvature profiles ``c`` (S,)
    (module docstring); c = 0 is the constant-curvature chain."""
    N = len(x)
    p = np.zeros((N, 3))
    R = np.tile(np.eye(3), (N, 1, 1))
    for i, L in enumerate(lengths):
        bx, by = x[:, 2 * i], x[:, 2 * i + 1]
        th = np.hypot(bx, by)
        ph = np.arctan2(by, bx)
        s = 0.5 * L * (_GL_X + 1.0)  # (G,)
        alpha = (th[:, None] / L) * (s + c[i] * (s - s * s / L))
        u = 0.5 * L * np.sum(_GL_W * np.sin(alpha), axis=1)
        w = 0.5 * L * np.sum(_GL_W * np.cos(alpha), axis=1)
        local = np.column_stack([u * np.cos(ph), u * np.sin(ph), w])
        p = p + np.einsum("nab,nb->na", R, local)
        Ri = np.array([rotation(float(t), float(f)) for t, f in zip(th, ph, strict=True)])
        R = R @ Ri
    return p


def kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) minimising sum |R a_i + t - b_i|^2 (rotation, no scale)."""
    ca, cb = a.mean(0), b.mean(0)
    H = (a - ca).T @ (b - cb)
    U, _, Vt = np.linalg.svd(H)
    dfix = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, dfix]) @ U.T
    return R, cb - R @ ca


def _rmse(d: np.ndarray) -> float:
    e = np.sum(d * d, axis=1)
    e = e[np.isfinite(e)]
    return math.sqrt(float(e.mean())) if e.size else math.nan


def kinematic_fits(
    x: np.ndarray,
    tip_model: np.ndarray,
    tip: np.ndarray,
    fit: np.ndarray,
    held: np.ndarray,
    lengths: Sequence[float],
    base_rmse: float,
) -> list[EffectFit]:
    """The ``curvature`` and ``registration`` candidates from the config's replay (poses ``x``,
    tips ``tip_model``) against the measured ``tip``; ``fit``/``held``: boolean row masks."""
    out: list[EffectFit] = []
    ok = np.all(np.isfinite(tip_model), axis=1)
    f = fit & ok
    t0 = time.monotonic()
    S = len(lengths)

    def res(c: np.ndarray) -> np.ndarray:
        return (segment_tip(x[f], lengths, c) - tip[f]).ravel()

    sol = least_squares(res, np.zeros(S), bounds=(-0.9, 0.9), max_nfev=50)
    d_c = segment_tip(np.where(ok[:, None], x, 0.0)[held], lengths, sol.x) - tip[held]
    d_c[~ok[held]] = np.nan
    rm = _rmse(d_c)
    out.append(
        EffectFit(
            "curvature",
            [f"segment {i + 1} curvature slope c" for i in range(S)],
            [float(v) for v in sol.x],
            rm,
            1 - rm / base_rmse,
            time.monotonic() - t0,
            err2_heldout=np.sum(d_c * d_c, axis=1),
        )
    )
    t0 = time.monotonic()
    R, t = kabsch(tip_model[f], tip[f])
    d_r = tip_model[held] @ R.T + t - tip[held]
    rm = _rmse(d_r)
    ang = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2)))
    out.append(
        EffectFit(
            "registration",
            ["rotation_deg", "t_x_mm", "t_y_mm", "t_z_mm"],
            [math.degrees(ang), *(float(v) for v in t)],
            rm,
            1 - rm / base_rmse,
            time.monotonic() - t0,
            err2_heldout=np.sum(d_r * d_r, axis=1),
        )
    )
    return out


def replay_candidates(params: RobotParams, name: str) -> list[FitParameter]:
    """The replay-fitted parameters of candidate ``name`` (module docstring)."""
    if name == "routing":
        return [fp for fp in candidates(params) if fp.kind in ("hole_offset", "routing_radius")]
    if name == "hysteresis":
        out = []
        for i, seg in enumerate(params.segments):
            ks = params.cables_of(i)
            out.append(
                FitParameter(
                    f"{seg.name}.backlash_mm",
                    "backlash",
                    i,
                    tuple(ParamRef("cable", k, "backlash_mm") for k in ks),
                    (1.0,) * len(ks),
                    0.0,
                    0.0,
                    3.0,
                    log=False,
                    offsets=tuple(params.cables[k].backlash_mm for k in ks),
                )
            )
        return out
    if name == "gravity":
        m0 = params.segments[0].disk_mass_g or 1.0
        refs = tuple(ParamRef("segment", i, "disk_mass_g") for i in range(params.n_segments))
        sc = tuple((s.disk_mass_g or m0) / m0 for s in params.segments)
        t0 = params.tip_mass_g
        return [
            FitParameter("segments.disk_mass_g", "gravity", -1, refs, sc, m0, m0 / 2, m0 * 200),
            FitParameter(
                "tip_load.mass_g", TIP_MASS, -1, (), (), t0, 0.0, t0 + TIP_MASS_MAX_G, log=False
            ),
        ]
    raise KeyError(name)


#: Kind of the tip-mass parameter of the ``gravity`` candidate (set by :class:`EffectProblem`).
TIP_MASS = "tip_mass"
#: Largest tip mass (g) the ``gravity`` candidate adds to the config's.
TIP_MASS_MAX_G = 200.0


@dataclass(frozen=True)
class EffectProblem(ReplayProblem):
    """:class:`~cdcr_ctl.identify.replay_fit.ReplayProblem` that also sets the robot's tip mass
    (``RobotParams.tip_mass_g``) from a parameter of kind :data:`TIP_MASS`."""

    def params_of(self, fps: Sequence[FitParameter], x: Sequence[float]) -> RobotParams:
        pairs = list(zip(fps, x, strict=True))
        rest = [(fp, v) for fp, v in pairs if fp.kind != TIP_MASS]
        out = super().params_of([fp for fp, _ in rest], [v for _, v in rest])
        for fp, v in pairs:
            if fp.kind == TIP_MASS:
                out = dataclasses.replace(out, tip_mass_g=max(0.0, float(fp.from_var(v))))
        return out


def replay_fit_effect(
    ev: Evaluator,
    params: RobotParams,
    effects: Effects,
    name: str,
    runs_full: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
    cpu_budget_s: float,
    base_rmse: float,
    say: Callable[[str], None],
) -> EffectFit:
    """Fit candidate ``name`` through the replay of the problem in ``ev`` (the chosen rows);
    score it on the held-out rows of ``runs_full`` ((q_path, tip (N, 3), held mask) per run).
    ``name`` "a+b": the parameters of both replayed candidates fitted together."""
    t0 = time.monotonic()
    fps = [fp for part in name.split("+") for fp in replay_candidates(params, part)]
    scales = [tolerance(fp, 0.25, math.radians(1.0)) for fp in fps]
    sol = replay_fit.fit(ev, fps, scales, 20, None, progress=say, cpu_budget_s=cpu_budget_s)
    fitted = ev.prob.params_of(fps, sol.x)
    d_all, reps = [], []
    for q, tip, held in runs_full:
        rep = replay(replay_fit.stepper(fitted, effects, ev.prob.friction_law), q)
        d_all.append((rep.tip_mm - tip)[held])
        reps.append(rep.tip_mm)
    d = np.vstack(d_all)
    rm = _rmse(d)
    return EffectFit(
        name,
        [fp.name for fp in fps],
        [e.value for e in sol.estimates],
        rm,
        1 - rm / base_rmse,
        time.monotonic() - t0,
        fitted,
        np.sum(d * d, axis=1),
        reps,
    )


def problem_of(
    params: RobotParams,
    effects: Effects,
    rows: Sequence[RunRows],
    noise_mm: float,
    law: FrictionLawShape | None = None,
) -> EffectProblem:
    """The replay fit of the candidates on ``rows``, tips only, under the disk friction's
    ``law`` (the config's ``robot.friction_law``; None: capstan)."""
    return EffectProblem(params, effects, tuple(rows), (), noise_mm, 0.02, law)


def registered_on(
    fitted: EffectFit,
    runs_full: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
    base_rmse: float,
) -> EffectFit:
    """The ``registration`` candidate on top of a replayed one: the replay of ``fitted``'s
    parameters (kept from its fit, ``tips_full``), its tips registered to the logged ones
    (Kabsch) on the rows before the cut, scored on the held-out rows (the joint fit of the two,
    "<name>+registration")."""
    t0 = time.monotonic()
    assert fitted.params is not None and fitted.tips_full is not None
    reps, fit_rows = [], []
    for tips, (_, tip, held) in zip(fitted.tips_full, runs_full, strict=True):
        reps.append(tips)
        ok = np.all(np.isfinite(tip), axis=1) & np.all(np.isfinite(tips), axis=1)
        fit_rows.append(ok & ~held)
    a = np.vstack([r[f] for r, f in zip(reps, fit_rows, strict=True)])
    b = np.vstack([t[f] for (_, t, _), f in zip(runs_full, fit_rows, strict=True)])
    R, t = kabsch(a, b)
    d = np.vstack(
        [(r @ R.T + t - tip)[held] for r, (_, tip, held) in zip(reps, runs_full, strict=True)]
    )
    rm = _rmse(d)
    ang = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2)))
    return EffectFit(
        f"{fitted.name}+registration",
        [*fitted.names, "rotation_deg", "t_x_mm", "t_y_mm", "t_z_mm"],
        [*fitted.values, math.degrees(ang), *(float(v) for v in t)],
        rm,
        1 - rm / base_rmse,
        fitted.seconds + time.monotonic() - t0,
        fitted.params,
        np.sum(d * d, axis=1),
        [r @ R.T + t for r in reps],
    )
