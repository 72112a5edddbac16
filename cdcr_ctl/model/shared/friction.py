"""Capstan friction of the cables in the disk holes, with stick memory (Qi et al. 2023 eq. 16-24).

Hole by hole (eq. 16-19, 23): across a hole of wrap angle eta the tension ratio is bounded by
exp(mu eta). Sliding, the side towards the actuator is the high one when the cable is pulled in
and the low one when it is paid out. With q pulled in (this project's sign; the paper uses cable
length, hence its opposite sign) and the mobilised fraction s in [-1, 1]:

    T_base_side = T_distal_side * exp(s mu eta)                         (eq. 19 / 23)

propagated from the anchor (where the statics gives T_distal) to the base hole, so the tension
entering the robot is T_base = T_distal exp(s mu sum(eta)).

Friction state per cable (:class:`FrictionState`):

* ``s`` - the mobilised fraction of friction, the same at every contact of the cable (a lumped,
  uniform-mobilisation closure). s = +1: sliding while pulled in; s = -1: sliding while paid out;
  |s| < 1: stuck. Pulleys follow the same s (ln(T_high/T_low) = |s| ln kappa, eq. 32).
* ``w_mm`` - the cable material drawn out of the robot through the base hole (mm) relative to the
  straight, pretensioned reference: w = q_geom + delta_in, the geometric shortening of the path
  inside the robot plus the stretch of the cable inside it (see
  :mod:`cdcr_ctl.model.cc_disk.elongation`).

Stick/slide rule (rate independent; derived, the paper's "keep the last value" is its rigid limit):
while a cable is stuck no material crosses the holes, so w is constant. The moment balance sees
the mean tension M of each cable along a segment, and w = q_geom + sum_i l_i (M_i - T0)/EA, so
with w fixed for the cables of a segment its pose and mean tensions are frozen (exactly for one
segment; with several, distal cables load proximal segments through their s-dependent mean
tension there, so a proximal segment can still creep while distal cables stick). The actuator can
then only stretch or relax the cable outside the robot (free length, pulleys), which moves T_base
and therefore s through T_base = T_distal exp(s mu sum eta), T_distal = M / Fbar(s). When s
reaches +-1 the friction is fully mobilised and the cable slides (s stays at +-1, w changes with
the sign of s). So at a reversal each actuator travels a dead zone while the robot stands still:

    dead zone_k = q_k(s = +1) - q_k(s = -1) at the frozen pose and mean tensions
                (the stretch of the cable between actuator and base hole changes with T_base)

which follows from the cable elasticity and shrinks to zero for a rigid cable. The forward model
(:mod:`cdcr_ctl.model.cc_disk.forward`) solves this as an active set (stick: w = w_prev, |s| <= 1;
slide: s = +-1 with sign(w - w_prev) = s). The inverse (compensation) model at a desired pose uses
the direction of material flow: s = sign(w - w_prev) when w changes, else s is kept (hysteresis);
with rigid cables w = q_geom and this is exactly the paper's sgn(q_dot) with memory at q_dot = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FrictionState:
    """Friction memory of every cable: mobilised fraction ``s`` and material drawn out ``w_mm``."""

    s: tuple[float, ...]
    w_mm: tuple[float, ...]

    @classmethod
    def initial(cls, n_cables: int) -> FrictionState:
        """Straight, pretensioned, nothing mobilised (s = 0, w = 0)."""
        return cls(s=(0.0,) * n_cables, w_mm=(0.0,) * n_cables)

    @classmethod
    def sliding(cls, s: np.ndarray | list[float], w_mm: np.ndarray | None = None) -> FrictionState:
        """A state with given s (e.g. +1 pulling, -1 paying out) and w (default 0)."""
        s_t = tuple(float(v) for v in s)
        w_t = (0.0,) * len(s_t) if w_mm is None else tuple(float(v) for v in w_mm)
        return cls(s=s_t, w_mm=w_t)

    def __post_init__(self) -> None:
        if len(self.s) != len(self.w_mm):
            raise ValueError("s and w_mm must have one entry per cable")
        if any(not -1.0 - 1e-12 <= v <= 1.0 + 1e-12 for v in self.s):
            raise ValueError(f"mobilised fraction s must be in [-1, 1], got {self.s}")


def hole_ratio(mu: float, eta_rad: float, s: float) -> float:
    """T_base_side / T_distal_side across one hole, eq. 18-19 (s = sgn(q_dot) when sliding)."""
    return math.exp(s * mu * eta_rad)


def propagate(
    T_distal_N: float, wraps_rad: np.ndarray, mu: float, s: float
) -> tuple[np.ndarray, float]:
    """Tensions along a cable inside the robot, hole by hole from the anchor (eq. 23).

    ``wraps_rad`` are the contact angles base first
    (:func:`cdcr_ctl.model.cc_disk.routing.wrap_angles`); piece j is the cable just distal of
    contact j, the last piece ends at the anchor with ``T_distal_N``. Returns (piece tensions base
    first, tension entering the base hole), N.
    """
    wraps = np.asarray(wraps_rad, dtype=float)
    M = wraps.size
    T = np.empty(M)
    T[M - 1] = T_distal_N
    for j in range(M - 1, 0, -1):
        T[j - 1] = T[j] * hole_ratio(mu, wraps[j], s)
    T_base = T[0] * hole_ratio(mu, wraps[0], s) if M else T_distal_N
    return T, float(T_base)


def mean_geometric(y: float, n: int) -> float:
    """(1/n) sum_{p=0}^{n-1} exp(p y) = expm1(n y) / (n expm1(y)) (1 at y = 0).

    The mean tension factor of the n spans of one segment whose holes each wrap theta/n:
    y = s mu theta / n (closed form of the eq. 23 product, used by the fast path).
    """
    if y == 0.0:
        return 1.0
    return math.expm1(n * y) / (n * math.expm1(y))


def direction_update(s_prev: float, dw_mm: float, tol_mm: float = 1e-12) -> float:
    """Inverse-model rule: sliding in the direction material crosses the base hole, else keep s.

    dw > 0 (material leaves the robot: pulled in) -> +1; dw < 0 -> -1; |dw| <= tol -> s_prev.
    """
    if dw_mm > tol_mm:
        return 1.0
    if dw_mm < -tol_mm:
        return -1.0
    return s_prev


def band_update(s_prev: float, dq_mm: float, band_mm: float) -> float:
    """Smoothed inverse rule: s moves by dq/band (clipped to [-1, 1]) instead of jumping.

    ``band_mm`` is the nominal cable travel over which a reversal is spread (a smooth dead-zone
    inverse); band -> 0 recovers :func:`direction_update`.
    """
    if band_mm <= 0.0:
        return direction_update(s_prev, dq_mm)
    return max(-1.0, min(1.0, s_prev + dq_mm / band_mm))
