"""The misfit gate of tip-only and keypoint fits, stated from the data.

Two numbers decide what ``identify`` may write:

1. **The tracker noise, from the log itself** (:func:`tracker_noise`). Where three consecutive
   rows step the actuators along a straight line in the same direction (the second difference
   of q below ``LINEAR_TOL`` of the step), the tip's second difference
   D_i = p_{i+1} - 2 p_i + p_{i-1} is the noise (variance 6 sigma^2 per axis for independent
   noise of sigma per axis) plus the curvature of the tip map over two steps, which only adds.
   |D|^2 / (6 sigma^2) is then chi-square with 3 degrees of freedom, median 2.366, so
   sigma_hat = sqrt(median |D|^2 / (6 x 2.366)) is an *upper bound* on the noise per axis
   (robust to a few outliers). The misfit ratio R = (fitted tip residual RMS per axis) /
   sigma_hat is therefore a *lower bound* on how far the residual is above the noise:
   R > ``MISFIT_FACTOR`` (5: more than 96 % of the residual power is not noise, as for the
   load-cell gate of :mod:`.gate`) means model error: the model lacks an effect the robot has,
   and more rows or a longer fit will not remove it.
2. **Whether the held-out rows improved beyond their noise** (:func:`heldout_gain`): per
   held-out row the drop of the squared tip error, config -> fitted, averaged in blocks of
   ``BLOCK`` consecutive rows (neighbouring keypoints share their errors; fewer than 40 rows:
   4 blocks); the gain counts when
   its mean exceeds twice its standard error over the blocks (a one-sided ~97.5 % test) and
   the held-out RMSE dropped by at least ``MIN_GAIN`` (1 %).

An overlay is written only when (2) holds; a misfit that still improves the held-out rows is
written with the misfit stated in its header; otherwise nothing is written and the command
exits non-zero naming ``--accept-misfit``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Second difference of q, relative to the step, below which three rows count as one line.
LINEAR_TOL = 0.1
#: Median of the chi-square distribution with 3 degrees of freedom.
CHI2_3_MEDIAN = 2.365974
#: Misfit ratio above which the residual is model error (module docstring).
MISFIT_FACTOR = 5.0
#: Consecutive held-out rows per block of :func:`heldout_gain`.
BLOCK = 10
#: Smallest relative drop of the held-out tip RMSE that counts (a fit that barely moved from
#: the config passes the block test on differences at rounding level).
MIN_GAIN = 0.01
#: The override the refusal names.
OVERRIDE = "--accept-misfit"


def tracker_noise(q_path: np.ndarray, tip_mm: np.ndarray) -> tuple[float, int]:
    """(sigma_hat per axis in mm, number of row triples used) of one run (module docstring);
    (nan, 0) when no three rows step along a line."""
    q = np.asarray(q_path, dtype=float)
    p = np.asarray(tip_mm, dtype=float)
    if len(q) < 3:
        return math.nan, 0
    s1 = q[1:-1] - q[:-2]
    s2 = q[2:] - q[1:-1]
    step = np.linalg.norm(s1, axis=1)
    lin = (np.linalg.norm(s2 - s1, axis=1) <= LINEAR_TOL * step) & (step > 1e-3)
    D = p[2:] - 2 * p[1:-1] + p[:-2]
    ok = lin & np.all(np.isfinite(D), axis=1)
    if ok.sum() < 5:
        return math.nan, int(ok.sum())
    d2 = np.sum(D[ok] ** 2, axis=1)
    return float(math.sqrt(np.median(d2) / (6.0 * CHI2_3_MEDIAN))), int(ok.sum())


def heldout_gain(err2_nominal: np.ndarray, err2_fitted: np.ndarray) -> tuple[float, float]:
    """(mean drop of the squared tip error config -> fitted (mm^2), its standard error) over
    held-out rows in time order, blocks of :data:`BLOCK` rows."""
    d = np.asarray(err2_nominal, float) - np.asarray(err2_fitted, float)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return math.nan, math.nan
    # blocks of BLOCK rows; a short hold-out (under 4 blocks) in 4 shorter blocks
    nb = max(d.size // BLOCK, min(4, d.size))
    blocks = np.array([b.mean() for b in np.array_split(d, nb)])
    se = float(blocks.std(ddof=1) / math.sqrt(nb)) if nb > 1 else math.inf
    return float(d.mean()), se


@dataclass(frozen=True)
class KeypointVerdict:
    """What the gate found (module docstring)."""

    noise_mm: float  # sigma_hat per axis (upper bound)
    noise_triples: int
    residual_mm: float  # fitted rows' tip residual RMS per axis
    misfit_ratio: float  # residual / noise (lower bound)
    gain_mm2: float
    gain_se_mm2: float
    rmse_nominal: float
    rmse_fitted: float

    @property
    def misfit(self) -> bool:
        return not self.misfit_ratio <= MISFIT_FACTOR

    @property
    def improved(self) -> bool:
        return (
            self.gain_mm2 > 2.0 * self.gain_se_mm2
            and self.rmse_fitted < (1.0 - MIN_GAIN) * self.rmse_nominal
        )

    @property
    def write(self) -> bool:
        return self.improved

    def lines(self) -> list[str]:
        out = [
            f"tracker noise from the log: <= {self.noise_mm:.3g} mm per axis (second "
            f"differences of {self.noise_triples} row triples stepping along a line)",
            f"fitted rows' tip residual {self.residual_mm:.3g} mm per axis = "
            f"{self.misfit_ratio:.3g} x the noise (at least)",
        ]
        if self.misfit:
            out.append(
                f"MISFIT: the residual is more than {MISFIT_FACTOR:g} x the noise: it is model "
                "error, not noise (the model lacks an effect this robot has; more rows or "
                "iterations will not remove it; `cdcr-ctl discrepancy` names candidates)"
            )
        pct = 100 * (1 - self.rmse_fitted / self.rmse_nominal) if self.rmse_nominal else math.nan
        verdict = "improved beyond their noise" if self.improved else "NOT improved beyond noise"
        out.append(
            f"held-out rows {verdict}: tip RMSE {self.rmse_nominal:.4g} -> "
            f"{self.rmse_fitted:.4g} mm ({pct:+.1f} % less); mean squared error drop "
            f"{self.gain_mm2:.3g} mm^2, standard error {self.gain_se_mm2:.2g} mm^2 "
            f"(blocks of {BLOCK} rows)"
        )
        return out

    def as_dict(self) -> dict:
        return {
            "noise_mm": self.noise_mm,
            "noise_triples": self.noise_triples,
            "residual_mm": self.residual_mm,
            "misfit_ratio": self.misfit_ratio,
            "misfit": self.misfit,
            "heldout_gain_mm2": self.gain_mm2,
            "heldout_gain_se_mm2": self.gain_se_mm2,
            "heldout_improved": self.improved,
        }
