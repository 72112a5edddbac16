"""Disk friction of a freer law than the capstan's: a wrap exponent and a speed-dependent part.

Pure physics, numpy only (no I/O, no clocks: times come in as arguments). Units: mm, s, N, rad.

The controller's model (Qi et al. 2023 eq. 16-24, :mod:`~cdcr_ctl.model.cc_disk.transfer`) has
one rate-independent coefficient mu_k per cable and the capstan law, the log tension ratio linear
in the wrap z (rad) accumulated from the anchor: ln(T(z)/T_anchor) = s mu_k z. Real holes and
cables need not follow it: friction that wears in where the cable bends most, a lubricant film
that thins with speed (Stribeck), a breakaway after a stop. :class:`FrictionLawShape` widens the
law by three numbers (all zero or one: the capstan law exactly),

    ln(T(z)/T_anchor) = s mu_k m(v_k) W(z),     W(z) = z_ref (z / z_ref)^p,  z_ref = 1 rad,
    m(v) = 1 + c_v v + b exp(-(v / v_b)^2),

p the wrap exponent (the friction density grows with the wrap already accumulated, p > 1, or
falls, p < 1), c_v (s/mm) a viscous part growing with the cable's sliding speed v_k (mm/s), b a
breakaway excess at rest decaying over the Stribeck speed v_b (static friction above the Coulomb
value: a wider stick band after reversals and holds; the Gaussian Stribeck curve of
Armstrong-Helouvry et al. 1994). The speed of a cable is its drive's speed along the
logged path (:func:`cable_speeds`). The stick capacity of a cable is the law's total ratio;
everything else (statics, pulleys, stick and slide) is the model's.
"""

from __future__ import annotations

import math

import numpy as np

from cdcr_ctl.model.cc_disk.forward import ForwardStepper
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.params import Effects, RobotParams
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer, Pose

#: Wrap at which W(z) = z for every exponent (rad).
Z_REF_RAD = 1.0
#: Time constant (s) over which a cable's friction follows its speed (:func:`cable_speeds`).
SPEED_MEMORY_S = 0.05


class LawTransfer(ForceTransfer):
    """The force-transfer chain with a :class:`FrictionLawShape` (module docstring). The
    coefficients follow the speeds last given to :meth:`set_speeds` (at rest until then)."""

    def __init__(
        self, params: RobotParams, effects: Effects | None, shape: FrictionLawShape
    ) -> None:
        super().__init__(params, effects)
        self.shape = shape
        self._mu_coulomb = list(self._mu)
        self.set_speeds([0.0] * self.K)

    def set_speeds(self, v_mm_s) -> None:
        """Each cable's sliding speed (mm/s, >= 0): the coefficients mu_k m(v_k)."""
        f = self.shape.speed_factor
        self._mu = [m * f(float(v)) for m, v in zip(self._mu_coulomb, v_mm_s, strict=True)]

    def _wrap(self, z: float) -> float:
        return Z_REF_RAD * (z / Z_REF_RAD) ** self.shape.exponent if z > 0.0 else 0.0

    def factors_k(self, pose: Pose, k: int, s_k: float) -> tuple[list[float], float]:
        """Mean span-tension factor of cable k per crossed segment (the mean of exp(beta W) over
        the segment's spans) and ln(T_base/T_distal), beta = s mu_k m(v_k)."""
        if self.shape.exponent == 1.0:
            return super().factors_k(pose, k, s_k)
        a = self._a[k]
        beta = s_k * self._mu[k]
        if beta == 0.0:
            return [1.0] * (a + 1), 0.0
        za = pose.Zb[a]
        means = []
        for i in range(a + 1):
            z0 = za - pose.Zb[i]
            spans = [math.exp(beta * self._wrap(z0 + j * pose.inner[i])) for j in range(self._n[i])]
            means.append(math.fsum(spans) / len(spans))
        return means, beta * self._wrap(za)

    def friction_capacity(self, P: Pose, k: int) -> float:
        """ln of the largest tension ratio cable k can hold: the law's total over its wrap plus
        each pulley's ln kappa at pretension."""
        return self._mu[k] * self._wrap(P.Zb[self._a[k]]) + math.fsum(self._pul_lnk0[k])


def cable_speeds(t_s: np.ndarray, q_mm: np.ndarray, memory_s: float = SPEED_MEMORY_S) -> np.ndarray:
    """(N, K) sliding speed of every cable (mm/s, >= 0) at the rows of a path: |dq/dt| between
    rows, followed with a first-order lag of ``memory_s`` (the contact takes a moment to follow
    the speed; 0: none)."""
    t = np.asarray(t_s, dtype=float)
    q = np.asarray(q_mm, dtype=float)
    out = np.zeros_like(q)
    for i in range(1, len(t)):
        dt = t[i] - t[i - 1]
        if dt <= 0:
            out[i] = out[i - 1]
            continue
        v = np.abs(q[i] - q[i - 1]) / dt
        a = 1.0 if memory_s <= 0 else -math.expm1(-dt / memory_s)
        out[i] = out[i - 1] + a * (v - out[i - 1])
    return out


def law_stepper(params: RobotParams, effects: Effects, shape: FrictionLawShape) -> ForwardStepper:
    """A :class:`ForwardStepper` whose chain has the law ``shape`` (:class:`LawTransfer`); with
    a speed-dependent shape the caller gives the speeds before each step
    (``stepper.model.ft.set_speeds(v)`` then ``stepper.model.forget_evaluation()``)."""
    st = ForwardStepper(params, effects)
    st.model.ft = LawTransfer(params, effects, shape)
    st.model.forget_evaluation()
    return st
