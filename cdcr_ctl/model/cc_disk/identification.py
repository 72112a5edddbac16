"""Parameter identification by non-linear least squares (Qi et al. 2023 eq. 38 and beyond).

Eq. 38 fits the friction of the force-transfer model to load-cell tensions over a bending sweep
(beta = 0, 120, 240 deg; theta = 40-90 deg in 5 deg steps; both motion directions; Table 1). The
paper calls it linear; with mu inside exp(s mu eta) it is not, so it is solved here with
:func:`scipy.optimize.least_squares`. The machinery is generic:

* :class:`ParamRef` names one scalar of :class:`~cdcr_ctl.model.cc_disk.params.RobotParams`
  (mu per cable, EA per cable, pretension, EI per segment, pulley alpha and n, ...), optionally
  fitted in log space; :func:`with_values` maps a parameter vector back to model parameters.
* residual builders stack weighted residuals: :func:`tension_residuals` (modelled minus measured
  tensions at the load cells, for given poses and friction states) and :func:`tip_residuals`
  (forward-model tip minus tracker tip for a replayed sequence of actuator displacements).
* :func:`fit` solves and returns values with standard errors and 95 % confidence intervals from
  the Jacobian at the solution: cov = s^2 (J^T J)^-1, s^2 = SSR/(m - p), Student t quantile.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import t as student_t

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.compensation import Compensator
from cdcr_ctl.model.cc_disk.forward import ForwardStepper
from cdcr_ctl.model.cc_disk.params import Effects, Location, RobotParams

ResidualFn = Callable[[RobotParams], np.ndarray]


@dataclass(frozen=True)
class ParamRef:
    """One fitted scalar: ``kind`` in {"cable", "segment", "pulley"}, ``index`` the cable or
    segment index (or the pulley name), ``field`` the dataclass field (``mu_disk``, ``EA_N``,
    ``pretension_N``, ``EI_Nmm2``, ``alpha``, ``n``, ...). ``log`` fits ln(value)."""

    kind: str
    index: int | str
    field: str
    lower: float = -math.inf
    upper: float = math.inf
    log: bool = False

    @property
    def name(self) -> str:
        idx = f"[{self.index}]" if isinstance(self.index, int) else f"[{self.index!r}]"
        return f"{self.kind}{idx}.{self.field}"


def get_value(params: RobotParams, ref: ParamRef) -> float:
    """Current value of ``ref`` in ``params`` (a pulley's value from its first use)."""
    if ref.kind == "cable":
        return float(getattr(params.cables[int(ref.index)], ref.field))
    if ref.kind == "segment":
        return float(getattr(params.segments[int(ref.index)], ref.field))
    if ref.kind == "pulley":
        for c in params.cables:
            for p in c.pulleys:
                if p.name == ref.index:
                    return float(getattr(p, ref.field))
        raise ModelError(f"no pulley named {ref.index!r}")
    raise ModelError(f"unknown parameter kind {ref.kind!r}")


def with_values(params: RobotParams, refs: Sequence[ParamRef], values: Sequence[float]):
    """A copy of ``params`` with every ``refs[j]`` set to ``values[j]`` (natural units)."""
    cables = list(params.cables)
    segments = list(params.segments)
    for ref, v in zip(refs, values, strict=True):
        v = float(v)
        if ref.kind == "cable":
            k = int(ref.index)
            cables[k] = dataclasses.replace(cables[k], **{ref.field: v})
        elif ref.kind == "segment":
            i = int(ref.index)
            segments[i] = dataclasses.replace(segments[i], **{ref.field: v})
        elif ref.kind == "pulley":
            for k, c in enumerate(cables):
                pul = tuple(
                    dataclasses.replace(p, **{ref.field: v}) if p.name == ref.index else p
                    for p in c.pulleys
                )
                cables[k] = dataclasses.replace(c, pulleys=pul)
        else:
            raise ModelError(f"unknown parameter kind {ref.kind!r}")
    return dataclasses.replace(params, cables=tuple(cables), segments=tuple(segments))


@dataclass(frozen=True)
class FitResult:
    """Fitted values with standard errors and 95 % confidence intervals (natural units)."""

    refs: tuple[ParamRef, ...]
    values: np.ndarray
    std: np.ndarray
    ci95: np.ndarray  # (p, 2) lower, upper
    cov: np.ndarray  # covariance of the fitted variables (log space where ref.log)
    residual_rms: float
    n_residuals: int
    success: bool
    message: str
    params: RobotParams

    def table(self) -> str:
        """Human-readable summary, one parameter per line."""
        lines = [f"{'parameter':<28}{'value':>12}{'std':>12}{'95% CI':>26}"]
        for j, ref in enumerate(self.refs):
            lo, hi = self.ci95[j]
            lines.append(
                f"{ref.name:<28}{self.values[j]:>12.5g}{self.std[j]:>12.3g}"
                f"{f'[{lo:.5g}, {hi:.5g}]':>26}"
            )
        lines.append(f"rms residual {self.residual_rms:.4g} over {self.n_residuals} residuals")
        return "\n".join(lines)


def fit(
    params: RobotParams,
    refs: Sequence[ParamRef],
    residuals: ResidualFn,
    x0: Sequence[float] | None = None,
    **least_squares_kw,
) -> FitResult:
    """Least-squares fit of ``refs`` so that ``residuals(params)`` is smallest.

    ``residuals`` maps model parameters to a stacked, weighted residual vector (the builders
    below make them). ``x0`` (natural units) defaults to the values in ``params``.
    """
    refs = tuple(refs)
    start = [get_value(params, r) for r in refs] if x0 is None else [float(v) for v in x0]
    to_var = [math.log(v) if r.log else v for r, v in zip(refs, start, strict=True)]
    lo = [(math.log(r.lower) if r.lower > 0 else -math.inf) if r.log else r.lower for r in refs]
    hi = [
        (math.log(r.upper) if math.isfinite(r.upper) else math.inf) if r.log else r.upper
        for r in refs
    ]

    def natural(var: np.ndarray) -> list[float]:
        return [math.exp(v) if r.log else float(v) for r, v in zip(refs, var, strict=True)]

    def fun(var: np.ndarray) -> np.ndarray:
        return np.asarray(residuals(with_values(params, refs, natural(var))), dtype=float)

    kw = {"x_scale": "jac", "method": "trf"}
    kw.update(least_squares_kw)
    sol = least_squares(fun, np.asarray(to_var, dtype=float), bounds=(lo, hi), **kw)
    m, p = sol.fun.size, len(refs)
    dof = max(m - p, 1)
    s2 = float(sol.fun @ sol.fun) / dof
    JtJ = sol.jac.T @ sol.jac
    try:
        cov = s2 * np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        cov = s2 * np.linalg.pinv(JtJ)
    sd_var = np.sqrt(np.maximum(np.diag(cov), 0.0))
    tq = float(student_t.ppf(0.975, dof))
    vals = np.array(natural(sol.x))
    std = np.empty(p)
    ci = np.empty((p, 2))
    for j, r in enumerate(refs):
        if r.log:
            std[j] = vals[j] * sd_var[j]
            ci[j] = [math.exp(sol.x[j] - tq * sd_var[j]), math.exp(sol.x[j] + tq * sd_var[j])]
        else:
            std[j] = sd_var[j]
            ci[j] = [vals[j] - tq * sd_var[j], vals[j] + tq * sd_var[j]]
    return FitResult(
        refs=refs,
        values=vals,
        std=std,
        ci95=ci,
        cov=cov,
        residual_rms=math.sqrt(float(sol.fun @ sol.fun) / m),
        n_residuals=m,
        success=bool(sol.success),
        message=str(sol.message),
        params=with_values(params, refs, vals),
    )


# --------------------------------------------------------------------------- tension data
@dataclass(frozen=True)
class TensionSample:
    """Load-cell tensions (N, NaN where not measured) at pose ``psi`` with friction state ``s``."""

    psi: np.ndarray
    s: tuple[float, ...]
    tension_N: np.ndarray


def paper_sweep(
    params: RobotParams,
    segment: int = 0,
    betas_deg: Sequence[float] = (0.0, 120.0, 240.0),
    thetas_deg: Sequence[float] = tuple(range(40, 91, 5)),
    effects: Effects | None = None,
) -> list[tuple[np.ndarray, tuple[float, ...]]]:
    """The eq. 38 sweep: per beta, theta up then down (both motion directions); other segments
    straight. Returns (psi, s) pairs, s from the stateful direction rule along the path."""
    comp = Compensator(params, effects)
    out: list[tuple[np.ndarray, tuple[float, ...]]] = []
    S = params.n_segments
    up = [math.radians(v) for v in thetas_deg]
    for beta in betas_deg:
        state = comp.new_state()
        path = [0.0, *up, *reversed(up[:-1])]
        for j, th in enumerate(path):
            psi = np.zeros((S, 2))
            psi[segment] = [th, math.radians(beta)]
            comp.step(psi, state)
            if j > 0:
                out.append((psi, tuple(state.s)))
    return out


def tension_residuals(
    samples: Sequence[TensionSample],
    locations: Sequence[Location],
    effects: Effects | None = None,
    relative: bool = True,
) -> ResidualFn:
    """Residual builder: modelled minus measured tensions at the load cells (eq. 38).

    ``relative``: residuals (T_model - T_meas)/T_meas (suits a noise proportional to the load);
    else in N. Missing readings (NaN) are skipped.
    """
    locs = list(locations)

    def fn(params: RobotParams) -> np.ndarray:
        comp = Compensator(params, effects, locs)
        out = []
        for smp in samples:
            tr = comp.compensate(smp.psi, smp.s)
            for k, loc in enumerate(locs):
                meas = float(smp.tension_N[k])
                if math.isnan(meas):
                    continue
                model = tr.T_at(k, loc)
                out.append((model - meas) / meas if relative else model - meas)
        return np.asarray(out)

    return fn


def synthetic_tensions(
    params: RobotParams,
    sweep: Sequence[tuple[np.ndarray, tuple[float, ...]]],
    locations: Sequence[Location],
    noise_rel: float = 0.0,
    rng: np.random.Generator | None = None,
    effects: Effects | None = None,
) -> list[TensionSample]:
    """Model tensions at the load cells over a sweep, with multiplicative Gaussian noise."""
    comp = Compensator(params, effects, list(locations))
    gen = np.random.default_rng(0) if rng is None else rng
    out = []
    for psi, s in sweep:
        tr = comp.compensate(psi, s)
        T = np.array([tr.T_at(k, loc) for k, loc in enumerate(locations)])
        if noise_rel > 0.0:
            T = T * (1.0 + noise_rel * gen.standard_normal(T.size))
        out.append(TensionSample(psi=np.asarray(psi), s=tuple(s), tension_N=T))
    return out


def fit_friction(
    params: RobotParams,
    samples: Sequence[TensionSample],
    locations: Sequence[Location],
    effects: Effects | None = None,
    cables: Sequence[int] | None = None,
    mu0: float | None = None,
) -> FitResult:
    """Eq. 38: mu_disk per cable from load-cell tensions over a sweep (log-space, mu > 0)."""
    ks = range(params.n_cables) if cables is None else cables
    refs = [ParamRef("cable", k, "mu_disk", lower=1e-6, upper=5.0, log=True) for k in ks]
    x0 = None if mu0 is None else [mu0] * len(refs)
    return fit(params, refs, tension_residuals(samples, locations, effects), x0=x0)


# --------------------------------------------------------------------------- tip data
@dataclass(frozen=True)
class TipSample:
    """Tracker tip (mm, base frame) after commanding ``q_act_mm`` (samples replayed in order)."""

    q_act_mm: np.ndarray
    tip_mm: np.ndarray


def tip_residuals(samples: Sequence[TipSample], effects: Effects | None = None) -> ResidualFn:
    """Residual builder: forward-model tip minus tracker tip (mm), replaying the commands in
    order through a fresh :class:`~cdcr_ctl.model.cc_disk.forward.ForwardStepper` (hysteresis
    kept)."""

    def fn(params: RobotParams) -> np.ndarray:
        stepper = ForwardStepper(params, effects)
        out = []
        for smp in samples:
            res = stepper.step(smp.q_act_mm)
            out.extend((res.tip_mm - np.asarray(smp.tip_mm)).tolist())
        return np.asarray(out)

    return fn


def stack(*fns: ResidualFn, weights: Sequence[float] | None = None) -> ResidualFn:
    """Concatenate residual builders (e.g. tensions and tips), each times its weight."""
    w = [1.0] * len(fns) if weights is None else list(weights)

    def fn(params: RobotParams) -> np.ndarray:
        return np.concatenate([wi * f(params) for wi, f in zip(w, fns, strict=True)])

    return fn
