"""Joint least-squares identification from dwell points, with the poses as nuisance unknowns.

Why not replay the forward model: the forward model (:class:`~cdcr_ctl.model.ForwardStepper`)
costs ~2-4 ms per pose, so a fit by replaying the sweep through it needs minutes. And why not
eq. 38 as printed (the inverse model's tensions against the load cells): the inverse model
closes the statics with the pretension rule (the least-tensioned cable keeps T0), which holds for
a compensated command but not for what an uncompensated sweep does to the passive cables (they
go nearly slack). Instead every equation of the model is written at the *measured* state of each
dwell, which holds whatever the command was (errors-in-variables least squares):

unknowns per dwell j: the bending vectors x_j (2S, rad), the anchor tensions T_j (K, N) and, where
the friction state is not certain (:mod:`.dwell`), the mobilised fractions s_jk in [-1, 1];
global unknowns: the :class:`~.parameters.FitParameter` s (μ, EI, EA, T0, lost motion b,
mount tilt, pulley α/n).

residuals per dwell, each divided by its standard deviation:

* tip:     p(x_j) - p_tracker                                    (eq. 1-3; 3 rows, mm)
* cell:    T_cell(x_j, T_j, s_j) - T_load cell                    (eq. 23, 29-32; N)
  (the tension entering the base hole, T_j exp(s μ Σ η), or beyond the pulleys at the actuator)
* moment:  Σ_k T_jk F̄_k(s, μ) a_k(x_j) - m_req(x_j; EI, gravity) (eq. 8-15; 2S rows, N mm)
* compat:  q_geom(x_j) + δ_in + δ_out + d_jk b_k/2 - q_act        (eq. 4, 33-37; mm)
  (b_k the cable's lost motion, d_jk = ±1 the direction of its last motion: the drive stands
  half the play ahead of the cable, Yang et al. 2022 eq. 13-17,
  :mod:`cdcr_ctl.model.shared.deadzone`) dropped for a cable whose measured tension is below
  ``slack_N`` (a slack cable is longer than its path)

The standard deviations come from the spread of each dwell's samples (:mod:`.dwell`) with floors
(:class:`FitOptions`); the moment equations are the model's own and get the tension noise times
the routing radius.

Stages (each a bounded trust-region least squares; the next starts where the last ended):
0. nuisance only, nominal parameters, without compatibility: poses and tensions that fit tip,
   load cells and moment balance;
1. + μ, EI, mount tilt (and pulley α, n when cells sit at the actuator): the force side;
2. + compatibility, EA, T0 (and pulley α with cells at the base): the length side, force side fixed;
3. everything jointly. The 95 % confidence intervals come from its Jacobian:
   cov = s² (JᵀJ)⁻¹ over all free unknowns (nuisance included, those on a bound excluded),
   s² = SSR/(m - n), Student t quantile; log-fitted parameters get exp of the interval.

This module runs the stages and the intervals (:func:`identify`); the residuals and Jacobian are
:mod:`.problem`, the options and result types :mod:`.fit_types`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy.stats import t as student_t

from cdcr_ctl.errors import RigError
from cdcr_ctl.identify.dwell import DwellPoint, with_play
from cdcr_ctl.identify.fit_types import RESIDUAL_KINDS, Estimate, FitOptions, Identification
from cdcr_ctl.identify.parameters import FORCE_KINDS, TILT_CI_DEG, FitParameter, NotIdentified
from cdcr_ctl.identify.problem import _Problem, _rms, initial_nuisance
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.params import Effects, Location, RobotParams

__all__ = [
    "RESIDUAL_KINDS",
    "Estimate",
    "FitOptions",
    "Identification",
    "_Problem",
    "_estimates",
    "_exp",
    "_rms",
    "identify",
    "initial_nuisance",
]


def identify(
    params: RobotParams,
    effects: Effects,
    points: Sequence[DwellPoint],
    locations: Sequence[Location],
    fit_params: Sequence[FitParameter],
    fixed: Sequence[NotIdentified] = (),
    options: FitOptions | None = None,
    friction_law: FrictionLawShape | None = None,
) -> Identification:
    """Fit ``fit_params`` to the dwell ``points`` in the stages of the module docstring.

    ``params`` are the controller's nominal parameters (the start and the values of everything
    not fitted); ``effects`` the controller's model effects; ``locations`` the load-cell
    location per cable; ``friction_law`` the controller's disk friction law
    (:func:`cdcr_ctl.config.build_model.friction_law`; None: the capstan law), under which the
    friction coefficients are fitted (:func:`.problem.dwell_transfer`). Raises :class:`RigError`
    when there is nothing to fit from.

    The friction states of the points are assigned for the configured play of each cable
    (:func:`.dwell.with_play`); when the fitted play changes them (a play wider than the
    sweep's step between dwells keeps the cable in its gap for more than one dwell after a
    reversal), the fit runs once more with the states of the fitted play.
    """
    opt = FitOptions() if options is None else options
    if not points:
        raise RigError("identification: no dwell points")
    widths = opt.play_mm or tuple(c.backlash_mm for c in params.cables)
    pts = with_play(points, widths) if any(b > 0 for b in widths) else list(points)
    res = _identify(params, effects, pts, locations, fit_params, fixed, opt, friction_law)
    fitted = tuple(c.backlash_mm for c in res.fitted.cables)
    if opt.play_mm is None and any(b > 0 for b in fitted):
        again = with_play(pts, fitted)
        if any((a.s, a.s_known) != (b.s, b.s_known) for a, b in zip(again, pts, strict=True)):
            res2 = _identify(
                params,
                effects,
                again,
                locations,
                fit_params,
                fixed,
                replace(opt, play_mm=fitted),
                friction_law,
            )
            res2.stages.insert(
                0,
                "friction states re-assigned for the fitted play "
                + ", ".join(f"{b:.3g}" for b in fitted)
                + f" mm (first fit: reduced chi^2 {res.chi2_reduced:.3g})",
            )
            return res2
    return res


def _identify(
    params: RobotParams,
    effects: Effects,
    pts: list[DwellPoint],
    locations: Sequence[Location],
    fit_params: Sequence[FitParameter],
    fixed: Sequence[NotIdentified],
    opt: FitOptions,
    friction_law: FrictionLawShape | None = None,
) -> Identification:
    """One fit of :func:`identify` with the points' friction states as they are."""
    fps = list(fit_params)
    fixed = list(fixed)
    warnings: list[str] = []
    stages: list[str] = []
    while True:
        prob = _Problem(params, effects, pts, locations, fps, opt, friction_law)
        nuis = initial_nuisance(params, effects, pts, locations, prob.unc, friction_law)
        force = [j for j, f in enumerate(fps) if f.kind in FORCE_KINDS]
        pulley_force = [
            j
            for j, f in enumerate(fps)
            if f.kind.startswith("pulley") and any(loc == "actuator" for loc in locations)
        ]
        first = force + pulley_force
        rest = [j for j in range(len(fps)) if j not in first]
        # stage 0: nuisance only
        prob.set_stage([], ("tip", "cell", "moment"))
        nuis, sol = prob.solve(nuis, opt.max_nfev)
        stages.append(f"stage 0 (poses, tensions): cost {sol.cost:.4g}, {sol.nfev} evaluations")
        prob.set_stage([], RESIDUAL_KINDS)
        before = prob.kind_residuals(prob.pack(nuis))
        if first:
            prob.set_stage(first, ("tip", "cell", "moment"))
            nuis, sol = prob.solve(nuis, opt.max_nfev)
            stages.append(f"stage 1 (force side): cost {sol.cost:.4g}, {sol.nfev} evaluations")
        if rest:
            prob.set_stage(rest, RESIDUAL_KINDS)
            nuis, sol = prob.solve(nuis, opt.max_nfev)
            stages.append(f"stage 2 (length side): cost {sol.cost:.4g}, {sol.nfev} evaluations")
        prob.set_stage(list(range(len(fps))), RESIDUAL_KINDS)
        nuis, sol = prob.solve(nuis, opt.max_nfev)
        stages.append(
            f"stage 3 (joint): cost {sol.cost:.4g}, {sol.nfev} evaluations, {sol.message}"
        )
        estimates, chi2, m, n = _estimates(prob, sol.x)
        # A pulley parameter fitted only through the stretch may be too poorly determined.
        weak = [
            e
            for e in estimates
            if e.parameter.kind.startswith("pulley")
            and not any(loc == "actuator" for loc in locations)
            and not e.rel_halfwidth <= opt.max_rel_ci
        ]
        if not weak:
            break
        for e in weak:
            fps.remove(e.parameter)
            fixed.append(
                NotIdentified(
                    e.name,
                    e.nominal,
                    f"too weakly determined with load cells at the robot base "
                    f"(fitted {e.value:.4g}, 95 % CI ±{100 * e.rel_halfwidth:.0f} %)",
                )
            )
        stages.append("refit without " + ", ".join(e.name for e in weak))
    for e in estimates:
        if e.parameter.kind == "gravity_tilt":
            half = 0.5 * (e.ci95[1] - e.ci95[0])
            if not half <= TILT_CI_DEG:
                warnings.append(f"{e.name}: poorly identified (95 % CI ±{half:.2g} deg)")
        elif not e.rel_halfwidth <= opt.max_rel_ci:
            warnings.append(f"{e.name}: poorly identified (95 % CI ±{100 * e.rel_halfwidth:.0f} %)")
        if e.at_bound:
            warnings.append(f"{e.name}: fitted value {e.value:.4g} is on its bound")
    after = prob.kind_residuals(sol.x)
    _, nuis_final = prob.unpack(sol.x)
    S = params.n_segments
    poses = np.array(
        [nuis_final[prob.offsets[j] : prob.offsets[j] + 2 * S] for j in range(len(pts))]
    )
    s_fit = np.array(
        [
            prob.split_block(j, nuis_final[prob.offsets[j] : prob.offsets[j + 1]])[2]
            for j in range(len(pts))
        ]
    )
    return Identification(
        nominal=params,
        fitted=prob.params_of(prob.g_all),
        estimates=estimates,
        fixed=fixed,
        points=pts,
        rms_before=_rms(before),
        rms_after=_rms(after),
        residuals_before=before,
        residuals_after=after,
        poses=poses,
        s=s_fit,
        chi2_reduced=chi2,
        n_residuals=m,
        n_unknowns=n,
        stages=stages,
        warnings=warnings,
        friction_law=friction_law,
    )


def _exp(v: float) -> float:
    """exp(v), inf above the float range (v > 709.78), nan for nan."""
    return math.inf if v > 709.0 else math.exp(v)


def _estimates(prob: _Problem, z: np.ndarray) -> tuple[list[Estimate], float, int, int]:
    """Values, standard errors and 95 % intervals of the free globals at the solution ``z``."""
    lo, hi = prob.bounds()
    J = prob.jacobian(z, lo, hi)
    r = prob.residuals(z)
    span = np.maximum(hi - lo, 1e-300)
    on_bound = (np.abs(z - lo) <= 1e-9 * np.maximum(1.0, np.abs(lo))) | (
        np.abs(hi - z) <= 1e-9 * np.maximum(1.0, np.abs(hi))
    )
    on_bound &= np.isfinite(span)
    keep = ~on_bound
    Jk = J[:, keep]
    m, n = r.size, int(keep.sum())
    dof = max(m - n, 1)
    s2 = float(r @ r) / dof
    JtJ = Jk.T @ Jk  # BLAS on one thread: cdcr_ctl/blas.py
    try:
        cov = s2 * np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        cov = s2 * np.linalg.pinv(JtJ)
    idx = np.cumsum(keep) - 1  # column of each kept unknown in cov
    tq = float(student_t.ppf(0.975, dof))
    out = []
    for c, j in enumerate(prob.free):
        fp = prob.fps[j]
        v = fp.from_var(float(z[c]))
        sd = math.sqrt(max(float(cov[idx[c], idx[c]]), 0.0)) if keep[c] else math.nan
        if fp.log:
            std = v * sd
            # exp of a huge interval (a fit that does not explain its data) saturates at inf
            ci = (_exp(z[c] - tq * sd), _exp(z[c] + tq * sd))
        else:
            std = sd
            ci = (v - tq * sd, v + tq * sd)
        out.append(Estimate(fp, v, std, ci, at_bound=bool(on_bound[c])))
    return out, s2, m, n
