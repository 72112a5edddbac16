"""After the nonlinear refit of the winner: a refinement against its base, a pair against a single.

Both are decided on refitted models (a forward simulation per evaluation), not on the linearised
held-out comparison, where a law with several strongly nonlinear parameters (the friction law's
speed dependence) extrapolates badly from the training blocks when the motion sits in a few of
them.

* :func:`choose_refinement`: a term that refines another (``EffectTerm.refines``: ``friction_law``
  contains ``disk_friction`` at zero) and its base, when the winner is either, are both refitted.
  Mean squares in noise variances per residual, ms_b (base) and ms_r (refinement), k extra
  parameters, N_eff the refits' effective sample size (:mod:`~cdcr_ctl.discrepancy.selection`):

  - the refinement is named when it is significant, N_eff ln(ms_b / ms_r) above the 99 %
    quantile of chi^2 with k degrees of freedom (the likelihood ratio of nested Gaussian models),
    and removes at least :data:`REFINE_SHARE` of what the base leaves above the noise,
    ms_b - ms_r >= REFINE_SHARE (ms_b - 1);
  - the base is named when the refinement is not significant (a coefficient change explains the
    run as well as the other law) or the base leaves nothing above the noise;
  - otherwise (significant, but less than that share) the run cannot tell the law from a
    coefficient change: a tie, reported with both names; the base's values are written.

  The refinement's refit (chord method: the secant columns from zero as Jacobian) can stop short
  on a law far from the model's; when it leaves the verdict short of the refinement although the
  linearised fit in sample finds the refinement significant (a tie or the refinement by the same
  rule), it is refitted again from where it stopped with a fresh Jacobian at every iterate.
* :func:`maybe_pair`: a pair that beat the single in linearised CV is kept only if, refitted, it
  removes a further ``pair_gain`` of the baseline's excess over noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

from scipy.stats import chi2

from cdcr_ctl.discrepancy.design import Design, ModelFit
from cdcr_ctl.discrepancy.nonlinear_refit import Refit, refit

#: Share of the excess over noise the base leaves that a refinement must remove to be named.
REFINE_SHARE = 0.5
#: Level of the likelihood-ratio test of a refinement against its base.
REFINE_ALPHA = 0.01


def refinement_verdict(ms_base: float, ms_ref: float, n_eff: float, k_extra: int) -> str:
    """``"refinement"``, ``"base"`` or ``"tie"`` from the refitted mean squares (see module doc)."""
    if not (ms_ref > 0 and ms_base > ms_ref) or k_extra < 1:
        return "base"
    if n_eff * math.log(ms_base / ms_ref) <= chi2.ppf(1.0 - REFINE_ALPHA, k_extra):
        return "base"
    excess = ms_base - 1.0
    if excess <= 0:
        return "base"
    return "refinement" if ms_base - ms_ref >= REFINE_SHARE * excess else "tie"


def _pair_of(sel, d: Design) -> tuple[ModelFit, ModelFit] | None:
    """(base fit, refinement fit) when the chosen single is one of a compared refinement pair."""
    if sel.chosen is None or len(sel.chosen.terms) != 1:
        return None
    term = sel.chosen.terms[0]
    terms = {t.name: t for t, _ in d.cols}
    if term.refines in terms:
        base, ref = terms[term.refines], term
    else:
        ref = next((t for t in terms.values() if t.refines == term.name), None)
        base = term
    singles = {f.terms[0]: f for f in sel.fits if len(f.terms) == 1}
    if ref is None or base not in singles or ref not in singles:
        return None
    return singles[base], singles[ref]


def choose_refinement(d: Design, runs, sel, rf: Refit, sim, evals: int) -> Refit:
    """The refit of the effect to name, base or refinement (see module doc); sets
    ``sel.chosen`` and, for a tie, ``sel.tie``."""
    pair = _pair_of(sel, d)
    if pair is None:
        return rf
    fb, fr = pair
    rb = rf if sel.chosen is fb else refit(d, runs, fb, sim, max_nfev=evals)
    rr = rf if sel.chosen is fr else refit(d, runs, fr, sim, max_nfev=evals)
    k = fr.n_params - fb.n_params
    n_eff = min(rb.n_eff, rr.n_eff)
    v = refinement_verdict(rb.mean_square, rr.mean_square, n_eff, k)
    lin = refinement_verdict(fb.sse / sel.n_entries, fr.sse / sel.n_entries, sel.n_eff, k)
    if v != "refinement" and lin != "base":
        again = refit(d, runs, replace(fr, values=rr.values), sim, max_nfev=evals, fresh=True)
        if again.mean_square < rr.mean_square:
            rr = again
            v = refinement_verdict(rb.mean_square, rr.mean_square, n_eff, k)
    b, r = fb.name, fr.name
    left = rb.mean_square - 1.0
    lr = max(n_eff * math.log(rb.mean_square / rr.mean_square), 0.0) if rr.mean_square > 0 else 0.0
    how = (
        f"refitted, {b} leaves {left:.3f} noise variances above the noise ({rb.mean_square:.3f});"
        f" {r} ({k} more parameters) {rr.mean_square:.3f}, likelihood ratio {lr:.0f} (99 %"
        f" quantile {chi2.ppf(1.0 - REFINE_ALPHA, k):.1f})"
    )
    if v == "refinement":
        sel.reasons.append(f"{how}: {r} removes at least {REFINE_SHARE:.0%} of it: {r} named")
        sel.chosen = fr
        return rr
    sel.chosen = fb
    if v == "tie":
        sel.tie = (b, r)
        sel.reasons.append(
            f"TIE {b} / {r}: {how}: {r} is significant but removes less than"
            f" {REFINE_SHARE:.0%} of it: this run cannot tell the other law from a changed"
            f" coefficient; {b}'s values are written (the simpler)"
        )
    else:
        sel.reasons.append(f"{how}: {r} adds nothing beyond the noise: {b} named")
    return rb


def maybe_pair(d: Design, runs: Sequence, sel, rf: Refit, sim, evals: int) -> Refit:
    """Refit the pair that beat the single in linearised CV; keep it only if, refitted, it
    removes a further ``pair_gain`` of the excess over noise (in noise variances per residual)."""
    pair = sel.pair
    if pair is None:
        return rf
    N = sel.n_entries
    margin = sel.pair_gain * max(sel.baseline.cv_sse / N - 1.0, 0.0)
    if pair.cv_sse / N >= rf.mean_square - margin:
        sel.reasons.append(
            f"pair {pair.name} not better than the refitted {sel.chosen.name}"
            f" ({rf.mean_square:.2f} noise variances): the single effect is kept"
        )
        return rf
    rp = refit(d, runs, pair, sim, max_nfev=evals)
    if rp.mean_square < rf.mean_square - margin:
        sel.reasons.append(
            f"the pair {pair.name} (refitted mean square {rp.mean_square:.2f}) beats the single"
            f" {sel.chosen.name} ({rf.mean_square:.2f}) by more than {margin:.2f}: both are missing"
        )
        sel.chosen = pair
        sel.tie = ()
        return rp
    sel.reasons.append(
        f"pair {pair.name} refitted ({rp.mean_square:.2f}) is not better than {sel.chosen.name}"
        f" ({rf.mean_square:.2f}) by {margin:.2f}: the single effect is kept"
    )
    return rf
