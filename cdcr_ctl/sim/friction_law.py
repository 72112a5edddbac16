"""Disk friction of another law than the controller's, for simulated worlds unlike the model.

The controller's model (Qi et al. 2023 eq. 16-24, :mod:`cdcr_ctl.model.cc_disk.transfer`) gives
every disk hole the same Coulomb coefficient mu and the capstan law T_in / T_out = exp(s mu dphi)
over the wrap dphi of each hole: the log tension ratio grows linearly with the wrap accumulated from
the anchor, z (rad), ln(T(z)/T_anchor) = s mu z.

The ``wrap_power`` law of this module (:class:`WrapPowerTransfer`) is a different one, what a
rig whose holes wear, whose cable flattens under load, or whose sheath stiffens towards the base
shows: the friction *density* grows with the wrap already accumulated from the anchor,

    ln(T(z) / T_anchor) = s mu z_ref (z / z_ref)^p,      p = ``exponent`` (> 1), z_ref = 1 rad,

so the holes near the base (large z) rub more than those near the tip, and the total friction
grows faster than linearly with the bend: at p = 1.5 and 90 deg of bend (z = 1.57 rad) it is
1.25 x the model's, at 30 deg 0.72 x. No single mu of the model's law fits both. The span
factors (the mean tension factor of a segment's spans, what its moment balance sees) follow the
same law span by span, and the stick capacity of a cable is the law's total ratio. p = 1 is the
model's law exactly.

The ``stribeck`` law (:class:`StribeckTransfer`) is velocity dependent, with a stick band: the
coefficient of every hole of cable k depends on the speed v_k (mm/s) at which the cable slides
through the holes (its drive's speed, through a first-order lag of ``memory_s``: the lubricant
film and the contact's pre-sliding take a moment to follow),

    mu_k(v) = mu_k [1 + (r_s - 1) exp(-(v / v_s)^2) + c_v v]                  (Stribeck curve)

Coulomb mu_k while sliding steadily, r_s mu_k at rest (static friction: after a reversal or a
hold the cable must shed r_s times the Coulomb tension difference before it slides again, a wider
stick band than the model's), falling to mu_k over the Stribeck speed v_s, plus a viscous part
c_v v growing with speed. The controller's model has one rate-independent mu (r_s = 1, c_v = 0).

The truth uses them in place of the controller's chain: :func:`use_friction_law` swaps the
:class:`~cdcr_ctl.model.cc_disk.transfer.ForceTransfer` of a
:class:`~cdcr_ctl.model.ForwardStepper`.
"""

from __future__ import annotations

import math

from cdcr_ctl.model import ForwardStepper
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer, Pose

#: Wrap at which the two laws agree (rad).
Z_REF_RAD = 1.0


class WrapPowerTransfer(ForceTransfer):
    """The force-transfer chain with the ``wrap_power`` friction law (module docstring)."""

    def __init__(self, *args, exponent: float = 1.5, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        if not exponent > 0:
            raise ValueError("the friction law's exponent must be > 0")
        self.exponent = float(exponent)

    def _W(self, z: float) -> float:
        """Effective wrap of the law (rad) for wrap z accumulated from the anchor."""
        return Z_REF_RAD * (max(z, 0.0) / Z_REF_RAD) ** self.exponent

    def factors_k(self, pose: Pose, k: int, s_k: float) -> tuple[list[float], float]:
        """Mean span-tension factor per crossed segment and ln(T_base/T_distal) of cable k."""
        a = self._a[k]
        beta = s_k * self._mu[k]
        if beta == 0.0:
            return [1.0] * (a + 1), 0.0
        Zb, inner, n = pose.Zb, pose.inner, self._n
        za = Zb[a]
        row = []
        for i in range(a + 1):
            z0 = za - Zb[i]
            ni = n[i]
            row.append(sum(math.exp(beta * self._W(z0 + p * inner[i])) for p in range(ni)) / ni)
        return row, beta * self._W(za)

    def friction_capacity(self, P: Pose, k: int) -> float:
        cap = self._mu[k] * self._W(P.Zb[self._a[k]])
        for lnk in self._pul_lnk0[k]:  # ln kappa of each pulley at T0
            cap += lnk
        return cap


class StribeckTransfer(ForceTransfer):
    """The force-transfer chain with the ``stribeck`` law (module docstring): the capstan
    factors of every hole with the speed-dependent coefficient mu_k(v_k) of
    :meth:`observe`'s last call."""

    def __init__(
        self,
        *args,
        static_ratio: float,
        stribeck_mm_s: float,
        viscous_s_per_mm: float,
        memory_s: float,
        **kwargs,
    ) -> None:
        super().__init__(*args, **kwargs)
        if not (static_ratio >= 1.0 and stribeck_mm_s > 0 and viscous_s_per_mm >= 0):
            raise ValueError("stribeck law: static_ratio >= 1, stribeck_mm_s > 0, viscous >= 0")
        self.r_s = float(static_ratio)
        self.v_s = float(stribeck_mm_s)
        self.c_v = float(viscous_s_per_mm)
        self.memory_s = float(memory_s)
        self._coulomb = list(self._mu)
        self.speed_mm_s = [0.0] * self.K
        self._q_last: list[float] | None = None
        self._mu = [m * self.r_s for m in self._coulomb]  # at rest

    def observe(self, q_mm: list[float], dt_s: float) -> None:
        """The cables' positions (mm) ``dt_s`` after the last call: update each cable's filtered
        sliding speed and its coefficient mu_k(v)."""
        if self._q_last is not None and dt_s > 0:
            a = 1.0 if self.memory_s <= 0 else 1.0 - math.exp(-dt_s / self.memory_s)
            for k in range(self.K):
                v = abs(q_mm[k] - self._q_last[k]) / dt_s
                self.speed_mm_s[k] += a * (v - self.speed_mm_s[k])
        self._q_last = list(q_mm)
        for k in range(self.K):
            v = self.speed_mm_s[k]
            f = 1.0 + (self.r_s - 1.0) * math.exp(-((v / self.v_s) ** 2)) + self.c_v * v
            self._mu[k] = self._coulomb[k] * f


def use_friction_law(stepper: ForwardStepper, law: str, **shape: float) -> StribeckTransfer | None:
    """Give ``stepper``'s forward model the friction ``law`` (``capstan``: unchanged).

    ``shape``: ``exponent`` (``wrap_power``); ``static_ratio``, ``stribeck_mm_s``,
    ``viscous_s_per_mm``, ``memory_s`` (``stribeck``). Returns the chain whose speeds the
    caller updates (:meth:`StribeckTransfer.observe`) before each step, None for a
    rate-independent law."""
    m = stepper.model
    if law == "capstan":
        return None
    if law == "wrap_power":
        m.ft = WrapPowerTransfer(m.params, m.effects, exponent=shape["exponent"])
        return None
    if law == "stribeck":
        m.ft = StribeckTransfer(
            m.params,
            m.effects,
            static_ratio=shape["static_ratio"],
            stribeck_mm_s=shape["stribeck_mm_s"],
            viscous_s_per_mm=shape["viscous_s_per_mm"],
            memory_s=shape["memory_s"],
        )
        return m.ft
    raise ValueError(f"unknown friction law {law!r}")
