"""The nonlinear refit of the chosen candidate terms (step 4 of the discrepancy selection).

:func:`refit`: :func:`scipy.optimize.least_squares` of the chosen terms with a full forward
simulation per evaluation, the nuisance projected out and the secant columns as Jacobian;
confidence intervals s^2 (J^T J)^-1 inflated by N / N_eff (see
:mod:`cdcr_ctl.discrepancy.selection`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from cdcr_ctl.discrepancy.alignment import AlignedRun
from cdcr_ctl.discrepancy.design import Design, ModelFit, lag1_autocorrelation, predicted_vector
from cdcr_ctl.discrepancy.simulate import Prediction
from cdcr_ctl.model.cc_disk.effects import EffectTerm, ModelSpec

#: Refits of at most this many simulated parameters use a fresh Jacobian at every iterate.
FRESH_JACOBIAN_MAX_PARAMS = 3


@dataclass
class Refit:
    """The nonlinear refit of the chosen terms."""

    terms: tuple[EffectTerm, ...]
    values: np.ndarray
    ci95: np.ndarray  # half widths, same units as values
    names: list[str]
    units: list[str]
    predictions: list[Prediction]
    nuisance: np.ndarray
    nfev: int
    n_eff: float
    mean_square: float  # in-sample mean square of the normalised residuals (nuisance removed)


def split_values(terms: Sequence[EffectTerm], spec: ModelSpec, values: np.ndarray):
    out, o = [], 0
    for t in terms:
        n = len(t.parameters(spec))
        out.append(values[o : o + n])
        o += n
    return out


def apply_all(terms: Sequence[EffectTerm], spec: ModelSpec, values: np.ndarray) -> ModelSpec:
    for t, v in zip(terms, split_values(terms, spec, values), strict=True):
        spec = t.apply(spec, v)
    return spec


def refit(
    d: Design,
    runs: Sequence[AlignedRun],
    fit: ModelFit,
    sim: Callable[[ModelSpec, int], Prediction],
    max_nfev: int = 8,
    on_eval: Callable[[], None] | None = None,
    fresh: bool | None = None,
) -> Refit:
    """Nonlinear least squares of ``fit.terms`` with full forward simulations (see module doc),
    from ``fit.values``. ``fresh``: a forward-difference Jacobian at every iterate (True) or the
    secant columns (False); None: fresh for at most :data:`FRESH_JACOBIAN_MAX_PARAMS` simulated
    parameters."""
    terms = fit.terms
    cols = [i for i, (t, _) in enumerate(d.cols) if t in terms]
    J0 = d.G[:, cols]
    Nu = d.Nu
    Qn, _ = np.linalg.qr(Nu) if Nu.shape[1] else (np.zeros((len(d.r0), 0)), None)

    def project(x: np.ndarray) -> np.ndarray:
        return x - Qn @ (Qn.T @ x) if Qn.shape[1] else x

    Jp = project(J0) if J0.ndim == 2 else J0
    meas = []  # measured normalised values per entry
    for ri, run in enumerate(runs):
        m = d.run == ri
        rows, chans = d.row[m], d.chan[m]
        v = np.empty(m.sum())
        tip = chans < 3
        v[tip] = run.tip_mm[rows[tip], chans[tip]] / run.sigma_tip_mm
        if (~tip).any():
            v[~tip] = run.tension_N[rows[~tip], chans[~tip] - 3] / run.sigma_tension_N
        meas.append(v)
    cache: dict[bytes, tuple[np.ndarray, list[Prediction]]] = {}

    def preds(p: np.ndarray) -> tuple[np.ndarray, list[Prediction]]:
        key = np.asarray(p, dtype=float).tobytes()
        if key not in cache:
            out, ps = [], []
            for ri, run in enumerate(runs):
                spec = apply_all(terms, run.spec, p)
                pr = sim(spec, ri)
                m = d.run == ri
                out.append(meas[ri] - predicted_vector(run, pr, d.row[m], d.chan[m]))
                ps.append(pr)
            if on_eval is not None:
                on_eval()
            cache[key] = (np.concatenate(out), ps)
        return cache[key]

    def fun(p: np.ndarray) -> np.ndarray:
        return project(preds(p)[0])

    lo = np.array([d.cols[c][1].lower for c in cols])
    hi = np.array([d.cols[c][1].upper for c in cols])
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x0 = np.clip(fit.values, np.where(np.isfinite(lo), lo + 1e-9 * span, lo), hi - 1e-9 * span)
    steps = np.abs(d.steps[cols])
    needs_sim = [c for c in cols if d.cols[c][0].kind != "measurement"]
    if fresh is None:
        fresh = 0 < len(needs_sim) <= FRESH_JACOBIAN_MAX_PARAMS

    def jac(p: np.ndarray) -> np.ndarray:
        # few simulated parameters: a fresh forward-difference Jacobian at every iterate (the
        # secant from 0 can be poor for effects that change the model's character, e.g. rigid ->
        # elastic); many: the chord method with the secant columns
        if not fresh:
            return -Jp
        f0 = fun(p)
        J = np.empty((len(f0), len(p)))
        for j in range(len(p)):
            h = 0.05 * steps[j]
            if p[j] + h > hi[j]:
                h = -h
            q = p.copy()
            q[j] += h
            J[:, j] = (fun(q) - f0) / h
        return J

    sol = least_squares(
        fun,
        x0,
        jac=jac,
        bounds=(lo, hi),
        x_scale=steps,
        max_nfev=max_nfev,
        method="trf",
        ftol=1e-4,
        xtol=1e-4,
    )
    p = sol.x
    r_full, ps = preds(p)
    nuis = np.linalg.lstsq(Nu, r_full, rcond=None)[0] if Nu.shape[1] else np.zeros(0)
    res = r_full - Nu @ nuis if Nu.shape[1] else r_full
    N = len(res)
    rho = lag1_autocorrelation(res, d)
    n_eff = max(N * (1.0 - rho) / (1.0 + rho), 10.0)
    dof = max(N - len(p) - Nu.shape[1], 1)
    s2 = float(res @ res) / dof
    Jf = -jac(p)
    try:
        cov = s2 * np.linalg.pinv(Jf.T @ Jf) * (N / n_eff)
        ci = 1.96 * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        ci = np.full(len(p), np.nan)
    names = [d.cols[c][1].name for c in cols]
    units = [d.cols[c][1].unit for c in cols]
    return Refit(terms, p, ci, names, units, ps, nuis, int(sol.nfev), n_eff, float(res @ res) / N)
