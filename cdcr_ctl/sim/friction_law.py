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

The truth uses it in place of the controller's chain: :func:`use_friction_law` swaps the
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


def use_friction_law(stepper: ForwardStepper, law: str, exponent: float) -> None:
    """Give ``stepper``'s forward model the friction ``law`` (``capstan``: unchanged)."""
    if law == "capstan":
        return
    if law != "wrap_power":
        raise ValueError(f"unknown friction law {law!r}")
    m = stepper.model
    m.ft = WrapPowerTransfer(m.params, m.effects, exponent=exponent)
