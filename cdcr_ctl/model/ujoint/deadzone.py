"""The universal-joint arm's cable dead zone (Yang et al. 2022, section 4.1; NOTES eq. 13-17).

How far a cable's output lags its input while pulled / released through the friction of its
path (:func:`dead_zone_mm`, :func:`dead_zone_width_mm`, :func:`calibrate_friction_exponent`),
and the play operator that applies it (:func:`play_update`, :func:`play_inverse`).

Units: mm, N.
"""

from __future__ import annotations

import math

import numpy as np

from cdcr_ctl.errors import ModelError


# =========================================================================== dead zone
def dead_zone_mm(
    pretension_N: float, length_mm: float, EA_N: float, friction_exponent_per_mm: float
) -> tuple[float, float]:
    """(pull_mm, release_mm): how far the cable output lags its input while pulled / released.

    Derivation (section 4.1's measurement; NOTES eq. 13-17). The cable of length L runs from the
    input (s = 0) to the output (s = L), where the load holds it at the pretension T0. Friction
    along the path (holes, guides) is capstan-like with kappa = mu * wrap angle per mm, so while
    the input pulls the tension falls towards the output, T(s) = T0 exp(kappa (L - s)), and while
    it releases T(s) = T0 exp(-kappa (L - s)). The output moves by the input minus the change of
    the cable's stretch, integral (T(s) - T0) / EA ds:

        pull:     e_p = T0 / EA * ((exp(kappa L) - 1) / kappa - L)
        release:  e_r = T0 / EA * (L - (1 - exp(-kappa L)) / kappa)

    Sliding while pulled in, output = input - e_p; while released, output = input + e_r; at a
    reversal the output stands still (stick) until the input has travelled the dead zone

        w = e_p + e_r = 2 T0 / (EA kappa) (cosh(kappa L) - 1)   (-> T0 kappa L^2 / EA)

    Both are exactly linear in the pretension T0 (the paper: "linear in pretension"), zero for a
    rigid cable or no friction. :func:`calibrate_friction_exponent` fits kappa to a measured w.
    """
    if pretension_N < 0 or length_mm <= 0 or EA_N <= 0 or friction_exponent_per_mm < 0:
        raise ModelError("dead zone needs pretension >= 0, length > 0, EA > 0, kappa >= 0")
    x = friction_exponent_per_mm * length_mm
    scale = pretension_N * length_mm / EA_N
    if x < 1e-5:  # series: (e^x - 1 - x)/x = x/2 + x^2/6, (x - 1 + e^-x)/x = x/2 - x^2/6
        return scale * (0.5 * x + x * x / 6.0), scale * (0.5 * x - x * x / 6.0)
    return scale * (math.expm1(x) - x) / x, scale * (x + math.expm1(-x)) / x


def dead_zone_width_mm(
    pretension_N: float, length_mm: float, EA_N: float, friction_exponent_per_mm: float
) -> float:
    """Full dead zone at a direction reversal, w = e_p + e_r (mm); see :func:`dead_zone_mm`."""
    p, r = dead_zone_mm(pretension_N, length_mm, EA_N, friction_exponent_per_mm)
    return p + r


def calibrate_friction_exponent(
    width_mm: float, pretension_N: float, length_mm: float, EA_N: float
) -> float:
    """kappa (1/mm) such that :func:`dead_zone_width_mm` gives ``width_mm`` for this cable.

    Solves 2 (cosh x - 1) / x = w EA / (T0 L) for x = kappa L (monotonic in x) by bisection.
    Yang et al. 2022 section 4.1: w = 3.4 mm at T0 = 100 N for L = 2877 mm of 1.2 mm steel cable.
    """
    if not (width_mm > 0 and pretension_N > 0 and length_mm > 0 and EA_N > 0):
        raise ModelError("calibration needs width, pretension, length and EA > 0")
    target = width_mm * EA_N / (pretension_N * length_mm)

    def h(x: float) -> float:
        return 2.0 * (math.cosh(x) - 1.0) / x

    lo, hi = 1e-12, 1.0
    while h(hi) < target:
        hi *= 2.0
        if hi > 700.0:
            raise ModelError("dead zone too large for any friction exponent")
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if h(mid) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi) / length_mm


def play_update(
    q_out_prev_mm: np.ndarray, q_in_mm: np.ndarray, pull_mm: np.ndarray, release_mm: np.ndarray
) -> np.ndarray:
    """Cable output after the dead zone (play operator), per cable (mm pulled in).

    q_out = clip(q_out_prev, q_in - e_p, q_in + e_r): sliding while pulled in the output trails
    by e_p, while released it leads by e_r, in between it sticks (:func:`dead_zone_mm`).
    """
    q_in = np.asarray(q_in_mm, dtype=float)
    return np.clip(np.asarray(q_out_prev_mm, dtype=float), q_in - pull_mm, q_in + release_mm)


def play_inverse(
    q_out_mm: np.ndarray, direction: np.ndarray, pull_mm: np.ndarray, release_mm: np.ndarray
) -> np.ndarray:
    """Input that puts the cable output at ``q_out_mm`` moving in ``direction`` (+1 pull, -1
    release, 0 never moved): q_in = q_out + e_p, q_out - e_r or q_out (inverse of the play)."""
    s = np.asarray(direction, dtype=float)
    return (
        np.asarray(q_out_mm, dtype=float)
        + np.where(s > 0, pull_mm, 0.0)
        - np.where(s < 0, release_mm, 0.0)
    )
