"""Which parameters a log identifies: singular values of the sensitivity matrix, and intervals.

J is the weighted sensitivity of the data to the candidate parameters g (EI, EA, T0, hole
offsets, ...): for keypoint logs the forward differences of the forward replay's residuals
(:mod:`.replay_fit`; every residual divided by its noise standard deviation), so the poses and
tensions are the model's own and no nuisance unknown is left to absorb anything. (Where a
problem carries per-point nuisance unknowns, J must first have them projected out.)

Each column is scaled by the parameter's tolerance u (a relative change ``max_rel`` for the
log-fitted positive parameters, ``max_offset_rad`` for angle offsets), so one unit of every
column is "as much change as we would accept as an error". Then

* the singular values of J say how many independent directions the log resolves and how
  well (a singular value s means: moving one tolerance along its direction changes the weighted
  residuals by s noise standard deviations); the right singular vector names the parameters
  that make the direction;
* cov = (Jᵀ J)⁻¹ (in tolerance units, noise variance 1 because every residual is
  divided by its noise standard deviation) gives each parameter's 95 % half-width
  h_j = 1.96 sqrt(cov_jj); the parameter is *identifiable* when h_j <= 1 (its 95 % interval is
  inside its tolerance).

:func:`select` drops the worst-determined parameter until every remaining one is identifiable;
the dropped ones stay at the config with the reason (their half-width and the direction they
share with the others).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.identify.parameters import FitParameter

Z95 = 1.959964  # two-sided 95 % quantile of the normal distribution


@dataclass(frozen=True)
class Observability:
    """Singular-value analysis of one set of candidate parameters (module docstring).

    ``singular_values`` descending; ``directions[i]`` the names of the parameters with the two
    largest components of the i-th right singular vector; ``halfwidth`` per parameter: 95 %
    half-width in tolerance units (<= 1: identifiable); ``tolerance`` per parameter (relative
    for log-fitted, natural units otherwise).
    """

    names: tuple[str, ...]
    singular_values: tuple[float, ...]
    directions: tuple[tuple[str, ...], ...]
    halfwidth: tuple[float, ...]
    tolerance: tuple[float, ...]

    def identifiable(self, name: str) -> bool:
        return self.halfwidth[self.names.index(name)] <= 1.0

    def lines(self) -> list[str]:
        out = ["observability (singular values of the scaled sensitivity, 95 % half-widths):"]
        for s, d in zip(self.singular_values, self.directions, strict=True):
            out.append(f"  s = {s:10.4g}  along {' + '.join(d)}")
        for n, h, u in zip(self.names, self.halfwidth, self.tolerance, strict=True):
            verdict = "identifiable" if h <= 1.0 else "NOT identifiable"
            out.append(f"  {n:<26} +-{h * u:.3g} (tolerance {u:.3g}): {verdict}")
        return out


def tolerance(fp: FitParameter, max_rel: float, max_offset_rad: float) -> float:
    """Scale of a parameter's column: relative for log-fitted ones, absolute otherwise."""
    if fp.log:
        return max_rel
    if fp.kind == "hole_offset":
        return max_offset_rad
    return max_rel * max(abs(fp.nominal), abs(fp.upper - fp.lower) * 0.05)


def analyse(
    J: np.ndarray, fps: Sequence[FitParameter], scales: Sequence[float], s2: float = 1.0
) -> Observability:
    """Singular values, directions and 95 % half-widths of ``fps`` from ``J`` (columns in
    the fit variables: ln value for log-fitted parameters) scaled by ``scales``; ``s2`` the
    variance factor (1 when the residual weights are the noise, else the reduced chi^2)."""
    names = tuple(fp.name for fp in fps)
    if not fps:
        return Observability((), (), (), (), ())
    A = J * np.asarray(scales, dtype=float)[None, :]
    U, sv, Vt = np.linalg.svd(A, full_matrices=False)
    del U
    dirs = []
    for v in Vt:
        top = np.argsort(-np.abs(v))[:2]
        dirs.append(tuple(names[i] for i in top if abs(v[i]) > 0.2))
    cov = np.linalg.pinv(A.T @ A)
    hw = Z95 * np.sqrt(np.maximum(np.diag(cov), 0.0) * s2)
    # a direction with no singular value at all (rank-deficient): infinite half-width
    tiny = sv < 1e-9 * max(float(sv[0]), 1e-300)
    for i in np.flatnonzero(tiny):
        for j in np.flatnonzero(np.abs(Vt[i]) > 0.2):
            hw[j] = math.inf
    return Observability(
        names, tuple(float(s) for s in sv), tuple(dirs), tuple(float(h) for h in hw), tuple(scales)
    )


def select(
    J: np.ndarray,
    fps: Sequence[FitParameter],
    scales: Sequence[float],
    s2: float = 1.0,
) -> tuple[list[int], list[tuple[int, str]], Observability]:
    """Indices of ``fps`` to fit, (index, reason) of those left out, the final analysis.

    Drops the worst-determined parameter (largest 95 % half-width in tolerance units) until every
    remaining one is identifiable.
    """
    keep = list(range(len(fps)))
    dropped: list[tuple[int, str]] = []
    full = analyse(J, fps, scales, s2)
    while keep:
        sub = analyse(J[:, keep], [fps[i] for i in keep], [scales[i] for i in keep], s2)
        worst = int(np.argmax(sub.halfwidth))
        if sub.halfwidth[worst] <= 1.0:
            break
        i = keep.pop(worst)
        partners = [d for d in sub.directions[-1] if d != fps[i].name]
        why = (
            f"not identifiable from this log: 95 % half-width "
            f"{_fmt(sub.halfwidth[worst] * scales[i], fps[i])} > tolerance "
            f"{_fmt(scales[i], fps[i])}"
        )
        if partners and sub.halfwidth[worst] < math.inf:
            why += f" (weakest direction shared with {', '.join(partners)})"
        dropped.append((i, why))
    return keep, dropped, full


def _fmt(v: float, fp: FitParameter) -> str:
    if not math.isfinite(v):
        return "inf"
    if fp.log:
        return f"{100 * v:.3g} %"
    if fp.kind == "hole_offset":
        return f"{math.degrees(v):.3g} deg"
    return f"{v:.3g}"
