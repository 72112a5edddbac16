"""What ``identify`` prints and writes for a tip-only or keypoint fit
(:func:`cdcr_ctl.identify.keypoints.identify_keypoint_runs`): the rows chosen and their spread,
what was fitted and what stayed at the config (and why), the intervals, the misfit gate
(:mod:`.keypoint_gate`) and every warning.
"""

from __future__ import annotations

import math
from typing import Any

from cdcr_ctl.identify.keypoints import KeypointIdentification
from cdcr_ctl.identify.observability import _fmt


def report_lines(res: KeypointIdentification) -> list[str]:
    """Plain-text report (module docstring)."""
    from cdcr_ctl.identify.pipeline import summary_table

    out = [f"log kind: {k}" for k in res.kinds.values()]
    out.append(
        f"{res.n_points} rows with a tip; {res.n_candidates} before the hold-out cut (the first "
        f"{100 * (1 - res.holdout):.0f} % of each run by time), {res.heldout.n_rows} held out"
    )
    out.append(f"rows fitted: {res.n_fit} ({res.rows_why})")
    for sp in res.spreads:
        out += ["  " + ln.strip() for ln in sp.lines()]
    out.append(f"tip residual weight: {res.tip_noise_mm:.3g} mm per axis")
    ob = res.observability
    out.append("observability (singular values of the scaled sensitivity at the config):")
    for s, d in zip(ob.singular_values, ob.directions, strict=True):
        out.append(f"  s = {s:10.4g}  along {' + '.join(d)}")
    fitted = {e.name for e in res.ident.estimates}
    for n, h, u, fp in zip(ob.names, ob.halfwidth, ob.tolerance, res.candidates, strict=True):
        state = "fitted" if n in fitted else "fixed at the config"
        out.append(
            f"  {n:<26} 95 % half-width {_fmt(h * u, fp)} at the config "
            f"(tolerance {_fmt(u, fp)}): {state}"
        )
    out.append("fitted: " + (", ".join(e.name for e in res.ident.estimates) or "none"))
    out.append("fixed at the config: " + (", ".join(f.name for f in res.ident.fixed) or "none"))
    out.append(summary_table(res.ident))
    out.append(
        f"reduced chi^2 {res.ident.chi2_reduced:.4g} over {res.ident.n_residuals} residuals "
        f"(weighted by {res.tip_noise_mm:.3g} mm per axis); {res.ident.stages[-1]}"
    )
    h = res.heldout
    if res.verdict is not None:
        out += res.verdict.lines()
    out.append(
        f"rows before the cut (fitted or not), tip RMSE: config {h.rmse_fit_rows_nominal:.4g}"
        f" mm -> fitted {h.rmse_fit_rows_fitted:.4g} mm"
    )
    out.append(f"rows with no static solution: {len(h.failed)}")
    out += [f"  {f}" for f in h.failed[:20]]
    out.append(f"identification took {res.fit_time_s:.1f} s")
    out += [f"warning: {w}" for w in res.warnings]
    return out


def keypoint_report(res: KeypointIdentification) -> dict[str, Any]:
    """JSON-ready report of a keypoint/tip fit (everything :func:`report_lines` prints)."""
    ob = res.observability
    return {
        "log_kinds": res.kinds,
        "rows": {
            "with_tip": res.n_points,
            "before_cut": res.n_candidates,
            "held_out": res.heldout.n_rows,
            "fitted": res.n_fit,
            "why": res.rows_why,
            "spread": [sp.lines()[1].strip() for sp in res.spreads],
        },
        "tip_noise_mm": res.tip_noise_mm,
        "observability": {
            "singular_values": list(ob.singular_values),
            "directions": [list(d) for d in ob.directions],
            "halfwidth_over_tolerance": dict(zip(ob.names, ob.halfwidth, strict=True)),
            "tolerance": dict(zip(ob.names, ob.tolerance, strict=True)),
        },
        "fitted": [
            {
                "name": e.name,
                "value": e.value,
                "ci95": list(e.ci95),
                "nominal": e.nominal,
                "on_bound": e.at_bound,
                "ci_clipped_at_bound": e.ci_at_bound,
                "bounds": [e.parameter.lower, e.parameter.upper],
            }
            for e in res.ident.estimates
        ],
        "fixed": [
            {"name": f.name, "nominal": f.nominal, "reason": f.reason} for f in res.ident.fixed
        ],
        "chi2_reduced": res.ident.chi2_reduced,
        "n_residuals": res.ident.n_residuals,
        "heldout": vars(res.heldout),
        "gate": None if res.verdict is None else res.verdict.as_dict(),
        "n_points": res.n_points,
        "n_fit": res.n_fit,
        "fit_time_s": res.fit_time_s,
        "warnings": list(res.warnings),
    }


def interval_span(lo: float, hi: float) -> float:
    """hi / lo for a positive interval, inf otherwise (for the 1e3x check of the tests)."""
    return hi / lo if lo > 0 and math.isfinite(hi) else math.inf
