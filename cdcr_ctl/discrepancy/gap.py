"""The tip gap between model and tracker: the model's systematic error, not the tracker's noise.

The per-sample tip error e_i = measured - predicted (mm, base frame, one row of the log) is the
model's error plus the tracker's white noise (sigma per axis): its RMS norm never falls below
the noise floor sqrt(3) sigma, so on a gap of a few noise sigmas even a perfect model shows
little shrink. The gap reported as the headline is the RMS norm of the error averaged over a
centred window of :data:`GAP_WINDOW_S` seconds (every row within +-W/2 of row i, NaN rows left
out): averaging n independent tracker samples divides the noise's standard deviation by
sqrt(n), while an error that changes over times longer than W passes nearly unchanged (a
boxcar of width W scales a sinusoid of period P by sinc(W / P): 0.94 at P = 1 s, 0.85 at the
0.65 s of a slow cable reversal's transient).

A sample-and-hold tracker slower than the log repeats a frame in several rows; those rows share
one noise draw, so the floor is computed from the weights the window gives each distinct frame:
var = sigma^2 sum_j (c_j / n)^2 per axis (c_j rows of frame j among the window's n rows), which
is sigma^2 / n when every row has its own frame.
"""

from __future__ import annotations

import math

import numpy as np

#: Width (s) of the centred window the tip error is averaged over: 11 rows at 50 Hz (the
#: tracker's noise / 3.3), shorter than the features of the model's error along Qi et al.
#: 2023's trajectories (a bend of several seconds, reversal transients of 0.25-0.65 s).
GAP_WINDOW_S = 0.2


def frame_ids(meas_mm: np.ndarray) -> np.ndarray:
    """(N,) index of the tracker frame of each row: a row repeating the previous row's
    measurement (every axis equal) is the same frame of a sample-and-hold tracker."""
    new = np.ones(len(meas_mm), dtype=bool)
    if len(meas_mm) > 1:
        same = np.all(meas_mm[1:] == meas_mm[:-1], axis=1) & np.all(np.isfinite(meas_mm[1:]), 1)
        new[1:] = ~same
    return np.cumsum(new) - 1


def windowed_error(
    t_s: np.ndarray, err_mm: np.ndarray, frames: np.ndarray, window_s: float = GAP_WINDOW_S
) -> tuple[np.ndarray, np.ndarray]:
    """The error (N, 3) mm averaged over the centred window of each row, and each row's noise
    variance factor f_i (the averaged noise's variance is f_i sigma^2 per axis; 1 for a single
    sample). Rows with a NaN error are left out of every window; a row whose window holds no
    finite error is NaN."""
    ok = np.all(np.isfinite(err_mm), axis=1)
    lo = np.searchsorted(t_s, t_s - 0.5 * window_s - 1e-9, side="left")
    hi = np.searchsorted(t_s, t_s + 0.5 * window_s + 1e-9, side="right")
    cs = np.concatenate((np.zeros((1, 3)), np.cumsum(np.where(ok[:, None], err_mm, 0.0), 0)))
    cn = np.concatenate(([0], np.cumsum(ok)))
    n = (cn[hi] - cn[lo]).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (cs[hi] - cs[lo]) / n[:, None]
        factor = 1.0 / n
    out[n == 0] = np.nan
    factor[n == 0] = np.nan
    if np.any(np.diff(frames[ok]) == 0):  # repeated frames: weigh each frame by its rows
        for i in np.flatnonzero(n > 0):
            m = ok[lo[i] : hi[i]]
            _, c = np.unique(frames[lo[i] : hi[i]][m], return_counts=True)
            factor[i] = float(np.sum(c.astype(float) ** 2)) / n[i] ** 2
    return out, factor


def gap_rms(err_mm: np.ndarray) -> float:
    """RMS over the rows of the error's norm (mm), NaN rows left out."""
    e = np.linalg.norm(err_mm, axis=1)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def rms(x: np.ndarray | None) -> float:
    """RMS of the finite entries of ``x`` (NaN when there are none or ``x`` is None)."""
    if x is None or not np.isfinite(x).any():
        return float("nan")
    return float(np.sqrt(np.nanmean(x**2)))


def windowed_floor(sigma_mm: float, factor: np.ndarray) -> float:
    """What :func:`gap_rms` of the windowed error reads for a model without error: the RMS norm
    of the averaged noise, sqrt(3 sigma^2 mean(f_i)) (mm)."""
    f = factor[np.isfinite(factor)]
    return math.sqrt(3.0 * sigma_mm**2 * float(np.mean(f))) if f.size else float("nan")
