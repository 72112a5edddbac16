"""The ``friction_law`` candidate: disk friction of another law than the capstan's.

Pure physics, numpy only. The law (a wrap exponent, a viscous part, a breakaway at rest) is
:mod:`cdcr_ctl.model.cc_disk.friction_law`; this term fits it together with the coefficient's
scale, so it contains :class:`~cdcr_ctl.model.cc_disk.effect_terms.DiskFriction` (its first
parameter) and explains what a rescaled mu cannot: friction whose hysteresis grows with the bend
faster or slower than exp(mu theta), or with the speed of the motion.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from cdcr_ctl.model.cc_disk.effect_spec import EffectParam, FittedValue, ModelSpec
from cdcr_ctl.model.cc_disk.effect_terms import DiskFriction
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape


class OtherFrictionLaw(DiskFriction):
    """Disk friction with a corrected coefficient and a freer law.

    Parameters: ``d_mu_scale`` (as :class:`DiskFriction`), ``d_exponent`` (the wrap exponent
    p = 1 + d), ``viscous_s_per_mm`` (c_v >= 0, per mm/s of the cable's speed),
    ``breakaway`` (b >= 0, the static excess at rest, a fraction of the Coulomb coefficient)
    and ``d_log_stribeck`` (the log of its Stribeck speed's ratio). Each is a
    correction of the model's own law (``ModelSpec.friction_law``, the config's
    ``robot.friction_law``; the capstan law when it has none): p = p_0 + d, c_v = c_v0 + dc,
    b = b_0 + db, v_b = v_b0 exp(d). All zero: the model as it is. Signature: a direction-dependent
    error (hysteresis) whose width does not follow the capstan law: it grows with the bend
    faster or slower than exp(mu theta), or with the speed, or a stick band after every stop
    wider than the model's.
    """

    name = "friction_law"
    title = "disk friction of another law (wrap exponent, speed dependence)"
    signature = "hysteresis whose width grows with the bend or the speed unlike the capstan law"
    reference = "Qi et al. 2023 eq. 16-24 generalised (friction_law.py: wrap exponent, Stribeck)"
    refines = "disk_friction"

    @staticmethod
    def base_law(base: ModelSpec) -> FrictionLawShape:
        """The model's own law (the capstan law when the spec has none)."""
        return FrictionLawShape() if base.friction_law is None else base.friction_law

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        b = self.base_law(base)
        return (
            *super().parameters(base),
            EffectParam("d_exponent", "1 (wrap exponent - model's)", 0.2, 0.4 - b.exponent, 2.0),
            EffectParam("viscous_s_per_mm", "s/mm", 0.1, -b.viscous_s_per_mm, 5.0),
            EffectParam("breakaway", "1 (x mu at rest)", 0.3, -b.breakaway, 4.0),
            EffectParam("d_log_stribeck", "1 (ln of v_b / model's v_b)", 0.3, -3.0, 3.0),
        )

    @classmethod
    def shape(cls, values: np.ndarray, base: ModelSpec | None = None) -> FrictionLawShape:
        b = FrictionLawShape() if base is None else cls.base_law(base)
        return FrictionLawShape(
            exponent=b.exponent + float(values[1]),
            viscous_s_per_mm=max(b.viscous_s_per_mm + float(values[2]), 0.0),
            breakaway=max(b.breakaway + float(values[3]), 0.0),
            breakaway_mm_s=b.breakaway_mm_s * math.exp(float(values[4])),
        )

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        spec = super().apply(base, values[:1])
        law = self.shape(values, base)
        return replace(spec, friction_law=None if law.capstan else law)

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        law = self.shape(values, base)
        return [
            *super().fitted(base, values[:1]),
            FittedValue("friction_law", "", "wrap_exponent", law.exponent),
            FittedValue("friction_law", "", "viscous_s_per_mm", law.viscous_s_per_mm),
            FittedValue("friction_law", "", "breakaway", law.breakaway),
            FittedValue("friction_law", "", "stribeck_mm_s", law.breakaway_mm_s),
        ]
