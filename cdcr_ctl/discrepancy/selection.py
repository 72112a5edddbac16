"""Which candidate effect explains the disagreement: linearised fits, blocked CV, AIC/BIC, refit.

Residuals are normalised by the measurement noise (tip: sigma_tip per axis, tensions: sigma_T),
so a model that is right up to noise has a mean squared residual of about 1.

1. Sensitivities, once: for every parameter j of every candidate term, the secant column
   G_j = (y(h_j e_j) - y(0)) / h_j of the run's predictions (one forward simulation per parameter;
   measurement-side terms need none). Nuisance columns common to every model, the baseline
   included: a tracker lag per run (-dy_tip/dt, and a_tip / 2 for its second-order term) and a
   load-cell zero offset per cable and run.
2. Every candidate and every pair of candidates is fitted to the baseline residual in this
   linearised form with :func:`scipy.optimize.lsq_linear` (the terms' bounds hold), on the full
   data and in blocked cross-validation: each run is cut into ``folds`` contiguous time blocks;
   block f of every run is held out, the rest fitted. The held-out sum of squares (CV-SSE) ranks
   the models; AIC and BIC use an effective sample size from the lag-1 autocorrelation of the
   residuals (N_eff = N (1 - rho) / (1 + rho)), since model errors are smooth in time.
3. Significance: nothing significant is missing when no candidate beats the baseline out of
   sample by a margin larger than the noise: the held-out mean square (in noise variances) must
   drop by more than ``noise_margin`` (1: the removed systematic part is larger than the noise),
   consistently (better in every held-out block, or a paired t > 2.13 over the blocks, 95 %
   one-sided with 4 dof for 5 folds, or better in every block where the baseline's held-out
   mean square exceeds the noise by more than ``noise_margin``: a block of holds that the
   baseline fits to the noise tells no model from another), and the baseline's own held-out
   excess over the noise is within ``noise_margin``. A candidate that beats the baseline but
   explains less than ``min_explained`` of the held-out excess over noise, or a baseline that
   misses by more than the noise with no candidate beating it, is reported as "no effect in the
   library explains this". A pair wins over its best single only if it removes a further
   ``pair_gain`` of the excess in held-out data.
4. The winner is refitted with the full nonlinear model (a forward simulation per evaluation)
   by :func:`scipy.optimize.least_squares` (the nuisance projected out), with the secant
   columns as Jacobian. Confidence intervals: s^2 (J^T J)^-1 inflated by N / N_eff, 95 % normal.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear

from cdcr_ctl.discrepancy.design import (
    Design,
    ModelFit,
    active_terms,
    build_design,
    entry_vector,
    lag1_autocorrelation,
    measurement_vector,
    predicted_vector,
)
from cdcr_ctl.discrepancy.nonlinear_refit import (
    FRESH_JACOBIAN_MAX_PARAMS,
    Refit,
    apply_all,
    refit,
    split_values,
)
from cdcr_ctl.model.cc_disk.effects import EffectTerm

__all__ = [
    "FRESH_JACOBIAN_MAX_PARAMS",
    "T_CRIT_5FOLDS",
    "Design",
    "ModelFit",
    "Refit",
    "Selection",
    "_Grams",
    "_bounds",
    "_residual",
    "active_terms",
    "apply_all",
    "build_design",
    "entry_vector",
    "fit_linear",
    "lag1_autocorrelation",
    "measurement_vector",
    "predicted_vector",
    "refit",
    "select",
    "split_values",
]

T_CRIT_5FOLDS = 2.132  # one-sided 95 % quantile of Student's t with 4 degrees of freedom


@dataclass
class Selection:
    """Outcome of the model comparison."""

    fits: list[ModelFit]
    baseline: ModelFit
    best: ModelFit
    chosen: ModelFit | None
    pair: ModelFit | None  # a pair that beats ``chosen`` in linearised CV, to check nonlinearly
    pair_gain: float
    verdict: str  # "named" | "nothing_missing" | "unexplained"
    explained_cv: float
    fold_t: float
    folds_better: int
    n_entries: int
    n_eff: float
    baseline_ms: float
    reasons: list[str] = field(default_factory=list)
    #: Effects the run cannot tell apart (a refinement and its base), the first written.
    tie: tuple[str, ...] = ()


class _Grams:
    """Per-fold Gram matrices of [G Nu] and r0: every linear fit and held-out SSE from them."""

    def __init__(self, d: Design, folds: int) -> None:
        A = np.hstack((d.G, d.Nu))
        self.P = d.G.shape[1]
        self.folds = folds
        self.AtA = []
        self.Atr = []
        self.rr = []
        for f in range(folds):
            m = d.fold == f
            Af, rf = A[m], d.r0[m]
            self.AtA.append(Af.T @ Af)
            self.Atr.append(Af.T @ rf)
            self.rr.append(float(rf @ rf))
        self.tAtA = sum(self.AtA)
        self.tAtr = sum(self.Atr)
        self.trr = sum(self.rr)

    @staticmethod
    def solve(AtA, Atr, lo, hi):
        n = AtA.shape[0]
        if n == 0:
            return np.zeros(0)
        ridge = 1e-10 * max(float(np.trace(AtA)) / n, 1e-12)
        R = np.linalg.cholesky(AtA + ridge * np.eye(n)).T
        b = np.linalg.solve(R.T, Atr)
        if np.all(np.isinf(lo)) and np.all(np.isinf(hi)):
            return np.linalg.solve(R, b)
        return lsq_linear(R, b, bounds=(lo, hi), method="bvls").x

    @staticmethod
    def sse(AtA, Atr, rr, p):
        return float(rr - 2.0 * p @ Atr + p @ AtA @ p)


def _bounds(d: Design, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo = [d.cols[c][1].lower for c in cols] + [-np.inf] * d.Nu.shape[1]
    hi = [d.cols[c][1].upper for c in cols] + [np.inf] * d.Nu.shape[1]
    return np.asarray(lo), np.asarray(hi)


def fit_linear(d: Design, g: _Grams, terms: tuple[EffectTerm, ...]) -> ModelFit:
    """Full-data and blocked-CV linearised fit of ``terms`` (plus the nuisance)."""
    cols = np.array([i for i, (t, _) in enumerate(d.cols) if t in terms], dtype=int)
    sel = np.concatenate((cols, g.P + np.arange(d.Nu.shape[1]))).astype(int)
    lo, hi = _bounds(d, cols)
    sub = np.ix_(sel, sel)
    p = g.solve(g.tAtA[sub], g.tAtr[sel], lo, hi)
    sse = g.sse(g.tAtA[sub], g.tAtr[sel], g.trr, p)
    cv = np.empty(g.folds)
    for f in range(g.folds):
        trA = g.tAtA[sub] - g.AtA[f][sub]
        trb = g.tAtr[sel] - g.Atr[f][sel]
        pf = g.solve(trA, trb, lo, hi)
        cv[f] = g.sse(g.AtA[f][sub], g.Atr[f][sel], g.rr[f], pf)
    return ModelFit(terms, p[: len(cols)], sse, float(cv.sum()), cv, len(cols))


def select(
    d: Design,
    terms: Sequence[EffectTerm],
    folds: int,
    pairs: bool = True,
    noise_margin: float = 1.0,
    min_explained: float = 0.5,
    pair_gain: float = 0.1,
) -> Selection:
    """Fit the baseline, every term and every pair; decide (see module doc)."""
    g = _Grams(d, folds)
    sets: list[tuple[EffectTerm, ...]] = [()] + [(t,) for t in terms]
    if pairs:
        sets += list(itertools.combinations(terms, 2))
    fits = [fit_linear(d, g, s) for s in sets]
    N = len(d.r0)
    base = fits[0]
    # effective sample size from the best fit's residuals (smooth model errors are correlated)
    best_single = min(fits[1 : 1 + len(terms)], key=lambda f: f.cv_sse, default=base)
    res = _residual(d, best_single)
    rho = lag1_autocorrelation(res, d)
    n_eff = max(N * (1.0 - rho) / (1.0 + rho), 10.0)
    for f in fits:
        k = f.n_params + d.Nu.shape[1]
        ll = n_eff * math.log(max(f.sse / N, 1e-300))
        f.aic = ll + 2 * k
        f.bic = ll + k * math.log(n_eff)
    ms = base.cv_sse / N
    excess = base.cv_sse - N
    reasons = [f"baseline held-out mean square {ms:.2f} (in noise variances; 1 = noise alone)"]
    best = min(fits[1:], key=lambda f: f.cv_sse, default=base)
    singles = [f for f in fits if len(f.terms) == 1]
    pair = None
    if len(best.terms) == 2:
        # decided after the nonlinear refit of the single (see workflow): a pair whose gain over
        # its best member is within the linearisation error must not win
        alt = min((f for f in singles if f.terms[0] in best.terms), key=lambda f: f.cv_sse)
        if alt.cv_sse - best.cv_sse >= pair_gain * max(excess, 1e-12):
            pair = best
        best = alt
    diff = base.cv_fold_sse - best.cv_fold_sse
    sd = float(np.std(diff, ddof=1)) if folds > 1 else 0.0
    if sd > 0:
        t_stat = float(np.mean(diff) / (sd / math.sqrt(folds)))
    else:
        t_stat = math.copysign(math.inf, float(np.mean(diff))) if np.any(diff) else 0.0
    better = int((diff > 0).sum())
    gain_ms = (base.cv_sse - best.cv_sse) / N
    explained = (base.cv_sse - best.cv_sse) / excess if excess > 0 else 0.0
    # a block the baseline already fits to within the noise (a hold) cannot tell models apart:
    # better in every block where the baseline misses by more than the noise also counts
    block_ms = base.cv_fold_sse / np.maximum(np.bincount(d.fold, minlength=folds), 1)
    telling = block_ms - 1.0 > noise_margin
    consistent = better == folds or t_stat > T_CRIT_5FOLDS
    consistent = consistent or bool(telling.any() and np.all(diff[telling] > 0))
    if (gain_ms <= noise_margin or not consistent) and ms - 1.0 > noise_margin:
        # the baseline itself misses by more than the noise (the noise level is measured apart,
        # from the second differences) and no candidate removes it: something is missing, but
        # not one of the library's effects (or one that was skipped for this log)
        verdict, chosen = "unexplained", None
        reasons.append(
            f"the baseline misses by {ms - 1.0:.1f} noise variances beyond the noise (more than"
            f" {noise_margin:g}), but no candidate beats it out of sample by more than the noise"
            f" (best: {best.name}, down by {gain_ms:.2f}; better in {better}/{folds} blocks):"
            " no effect in the library explains this"
        )
    elif gain_ms <= noise_margin or not consistent:
        verdict, chosen = "nothing_missing", None
        reasons.append(
            f"no candidate beats the baseline out of sample by more than the noise (best:"
            f" {best.name}, held-out mean square down by {gain_ms:.2f} noise variances, needs"
            f" > {noise_margin:g}; better in {better}/{folds} blocks), and the baseline's own"
            f" excess over the noise ({ms - 1.0:.2f}) is within it"
        )
    elif explained >= min_explained:
        verdict, chosen = "named", best
        reasons.append(
            f"{best.name}: better in {better}/{folds} held-out blocks (paired t = {t_stat:.1f};"
            f" in {int((diff[telling] > 0).sum())}/{int(telling.sum())} where the baseline"
            " misses beyond the noise),"
            f" held-out mean square down by {gain_ms:.1f} noise variances, explains"
            f" {explained:.0%} of the held-out excess over noise"
        )
    else:
        verdict, chosen = "unexplained", None
        reasons.append(
            f"best candidate {best.name} explains only {explained:.0%} of the held-out excess"
            f" over noise (needs {min_explained:.0%}): no effect in the library explains this"
        )
    return Selection(
        fits=fits,
        baseline=base,
        best=best,
        chosen=chosen,
        pair=pair if chosen is not None else None,
        pair_gain=pair_gain,
        verdict=verdict,
        explained_cv=float(explained),
        fold_t=t_stat,
        folds_better=better,
        n_entries=N,
        n_eff=n_eff,
        baseline_ms=ms,
        reasons=reasons,
    )


def _residual(d: Design, fit: ModelFit) -> np.ndarray:
    cols = [i for i, (t, _) in enumerate(d.cols) if t in fit.terms]
    A = np.hstack((d.G[:, cols], d.Nu))
    lo = np.r_[[d.cols[c][1].lower for c in cols], -np.inf * np.ones(d.Nu.shape[1])]
    hi = np.r_[[d.cols[c][1].upper for c in cols], np.inf * np.ones(d.Nu.shape[1])]
    p = _Grams.solve(A.T @ A, A.T @ d.r0, lo, hi)
    return d.r0 - A @ p


def split_refinements(terms: Sequence[EffectTerm]) -> tuple[list[EffectTerm], list[EffectTerm]]:
    """``terms`` as (compared first, held back): a term that refines another of ``terms``
    (``EffectTerm.refines``, e.g. ``friction_law`` of ``disk_friction``) waits for
    :func:`refinements`; one whose base is not among them is compared with the rest."""
    names = {t.name for t in terms}
    later = [t for t in terms if t.refines is not None and t.refines in names]
    return [t for t in terms if t not in later], later


def refinements(later: Sequence[EffectTerm], sel: Selection) -> list[EffectTerm]:
    """The held-back terms that refine an effect of the best fit of the first comparison, when
    it found something missing (their columns cost simulations that a run whose gap is
    elsewhere, or within the noise, does not need)."""
    if sel.verdict == "nothing_missing":
        return []
    lead = {t.name for t in sel.best.terms}
    return [t for t in later if t.refines in lead]


def far_wanted(terms: Sequence[EffectTerm], sel: Selection) -> bool:
    """Whether the first comparison calls for the far secant steps of some of ``terms``: it
    found something missing and its best fit, or the pair that beat it, holds an effect of a
    term's ``far_when`` (a gravity term for ``gravity_direction``: a sag the config's direction
    does not give)."""
    if sel.verdict == "nothing_missing":
        return False
    lead = {t.name for f in (sel.best, sel.pair) if f is not None for t in f.terms}
    return any(lead & set(t.far_when) for t in terms)


def compare(
    runs, terms, baselines, folds: int, pairs: bool, sim, far: bool = False
) -> tuple[Design, Selection]:
    """Every column simulation of ``terms`` up front (``sim.many``: in parallel when the
    workflow's simulator has workers; cached), then the design and the model comparison;
    ``far``: with the terms' far secant steps too (:func:`far_wanted`)."""
    items = []
    for ri, r in enumerate(runs):
        for t in terms:
            if t.kind == "measurement":
                continue
            params = t.parameters(r.spec)
            steps = t.far_steps(r.spec) if far else tuple(() for _ in params)
            for j, p in enumerate(params):
                for h in (p.step, *steps[j]):
                    v = np.zeros(len(params))
                    v[j] = h
                    items.append((t.apply(r.spec, v), ri))
    sim.many(items)
    design = build_design(runs, terms, baselines, folds, sim, far)
    return design, select(design, terms, folds, pairs=pairs)
