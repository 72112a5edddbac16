"""The misfit gate: a fit that does not explain its data writes no parameters.

A least-squares fit always returns numbers. Whether they mean anything depends on whether the
model explains the data to within its noise. The residuals of :mod:`.estimator` are divided by
their standard deviations (the spread of each dwell's samples, with floors), so for a model
that holds the reduced chi-square is about 1 (1 +- 0.1 for the ~1000 residuals of a sweep), and
its square root is the ratio of the residual RMS to the noise.

Rules (:func:`judge_fit`), each a sign that the model lacks an effect the rig has:

1. ``sqrt(chi2_reduced) > MISFIT_FACTOR``: the weighted residual RMS is more than 5 x the noise,
   i.e. more than 96 % of the residual power is not noise. Why 5: the noise estimates are
   themselves uncertain (standard errors from 8-40 samples of a dwell, floors), and a correct
   model with small neglected effects (a few degrees of mount tilt, the chord vs arc geometry,
   the 200 Hz truth stepping) lands between 1 and ~3 x (chi2 1-10, measured on the simulated
   worlds: 1.5-2.5 x on the default world with its 20 deg mount tilt fitted, 5.2 x when the
   fit had no tilt parameter, issue #17). 5 x leaves that margin and
   still refuses a model that misses lost motion (~80 x, chi2 ~7000, issue #17).
2. A residual kind whose RMS after the fit is more than ``WORSE_FACTOR`` times its RMS with the
   nominal parameters, and above its noise floor: the fit traded one measurement for another,
   soaking up an effect it does not have in parameters that do something else.

Pure: numbers in, a :class:`FitVerdict` out; the command decides what to write. Any fit that
reports a reduced chi-square and per-kind RMS (identification from sweeps, from tip-only logs)
can use it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from cdcr_ctl.errors import RigError
from cdcr_ctl.identify.dwell import DwellPoint
from cdcr_ctl.identify.estimator import FitOptions, Identification

#: Largest accepted ratio of the weighted residual RMS to the noise (module docstring).
MISFIT_FACTOR = 5.0
#: Largest accepted growth of one residual kind's RMS through the fit (module docstring).
WORSE_FACTOR = 2.0
#: What to run when the gate refuses ({run}: a logged run, {config}: the rig config).
NEXT_STEP = (
    "name the missing effect with `cdcr-ctl --config {config} discrepancy {run}` (it fits "
    "every effect the model can have; `--apply` writes the one that explains the gap)"
)


class MisfitError(RigError):
    """A fit does not explain its data; nothing was written (the message says what to run)."""


@dataclass(frozen=True)
class FitVerdict:
    """Whether a fit explains its data; ``reasons`` say why not (empty when it does)."""

    ok: bool
    misfit_ratio: float
    reasons: list[str] = field(default_factory=list)

    def message(self, run: str = "RUN_DIR", config: str = "RIG") -> str:
        """One line for the operator; ``run``/``config`` fill in the next step."""
        if self.ok:
            return f"fit explains the data: residual RMS {self.misfit_ratio:.2g} x the noise"
        return (
            "the fit does not explain the data: "
            + "; ".join(self.reasons)
            + ". No parameters written. Next: "
            + NEXT_STEP.format(run=run, config=config)
        )


def judge_fit(
    chi2_reduced: float,
    rms_before: Mapping[str, float],
    rms_after: Mapping[str, float],
    noise_floor: Mapping[str, float] | None = None,
    factor: float = MISFIT_FACTOR,
    worse_factor: float = WORSE_FACTOR,
) -> FitVerdict:
    """Judge a fit by its reduced chi-square and per-kind residual RMS (see module docstring).

    ``rms_before``/``rms_after``: RMS per residual kind (its own unit) with the nominal and the
    fitted parameters; ``noise_floor``: per kind, an RMS below which a growth does not count
    (defaults to 0). A non-finite chi-square is a misfit.
    """
    ratio = math.sqrt(chi2_reduced) if chi2_reduced >= 0 else math.nan
    reasons: list[str] = []
    if not math.isfinite(ratio):
        reasons.append(f"reduced chi^2 is {chi2_reduced}")
    elif ratio > factor:
        reasons.append(
            f"residual RMS {ratio:.3g} x the noise (reduced chi^2 {chi2_reduced:.4g}; "
            f"accepted up to {factor:g} x)"
        )
    floors = noise_floor or {}
    for kind, after in rms_after.items():
        before = rms_before.get(kind, math.nan)
        if not (math.isfinite(after) and math.isfinite(before)):
            continue
        if after > worse_factor * before and after > floors.get(kind, 0.0):
            reasons.append(
                f"{kind} residual grew from {before:.3g} to {after:.3g} through the fit "
                f"(more than {worse_factor:g} x)"
            )
    return FitVerdict(ok=not reasons, misfit_ratio=ratio, reasons=reasons)


def kind_noise(
    points: Sequence[DwellPoint],
    tip_floor_mm: float = 0.0,
    tension_floor_N: float = 0.0,
    q_floor_mm: float = 0.0,
) -> dict[str, float]:
    """RMS noise of each residual kind of a dwell fit (its unit): the standard errors of the
    dwell means (tracker per axis, load cells, drive positions), each at least its floor.
    The moment balance has no measured noise of its own (0)."""

    def rms(values: list[float]) -> float:
        v = [x for x in values if math.isfinite(x)]
        return math.sqrt(sum(x * x for x in v) / len(v)) if v else 0.0

    return {
        "tip": rms([max(p.tip_se_mm, tip_floor_mm) for p in points if p.has_tip]),
        "cell": rms([max(float(s), tension_floor_N) for p in points for s in p.tension_se_N]),
        "compat": rms([max(float(s), q_floor_mm) for p in points for s in p.q_act_se_mm]),
        "moment": 0.0,
    }


def judge_identification(ident: Identification, options: FitOptions | None = None) -> FitVerdict:
    """:func:`judge_fit` of a dwell fit; a kind's growth counts only above 3 x its noise
    (:func:`kind_noise` with the fit's floors)."""
    opt = FitOptions() if options is None else options
    noise = kind_noise(ident.points, opt.tip_floor_mm, opt.tension_floor_N, opt.q_floor_mm)
    return judge_fit(
        ident.chi2_reduced,
        ident.rms_before,
        ident.rms_after,
        {k: 3.0 * v for k, v in noise.items()},
    )
