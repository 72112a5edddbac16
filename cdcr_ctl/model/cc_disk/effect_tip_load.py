"""The tip payload as a candidate effect of model-discrepancy analysis (:class:`TipPayload`).

Pure physics, numpy only. A payload of mass m (g) at the tip of the last segment (a camera, a
tool) weighs m g along the config's gravity vector (base frame, mm/s^2; standard gravity along
-z when the config's is zero); the statics and the compensation take it as the tip wrench
J_tip^T F of the project's tip-load model (``RobotParams.tip_mass_g``, Qi et al. 2023 eq. 7-9
with the external load W_e at the tip).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cdcr_ctl.model.cc_disk.effect_spec import (
    STANDARD_GRAVITY_MM_S2,
    EffectParam,
    EffectTerm,
    FittedValue,
    ModelSpec,
)

#: Largest payload the term may fit (g): far beyond what bends a CDCR of this size usefully.
MAX_PAYLOAD_G = 500.0


class TipPayload(EffectTerm):
    """A payload at the tip with a corrected mass.

    Parameter ``d_payload_g`` (g): the tip mass is m0 + d, m0 the config's
    (``robot.tip_load.payload_kg``), bounded to [0, :data:`MAX_PAYLOAD_G`]. Signature: a sag
    along gravity that grows with the lever of the tip about each segment's base (the tip's
    horizontal distance), so the whole robot bends more where it reaches out; unlike the disk
    weights (:class:`~cdcr_ctl.model.cc_disk.effect_terms.GravitySag`), the load is concentrated at
    the tip, so the distal segment's share of the moment is larger.
    """

    name = "tip_load"
    title = "tip payload"
    signature = "sag along gravity growing with the tip's reach (a weight at the tip)"
    reference = "Qi et al. 2023 eq. 7-9 (external load W_e at the tip)"

    def parameters(self, base: ModelSpec) -> tuple[EffectParam, ...]:
        m0 = base.params.tip_mass_g
        return (EffectParam("d_payload_g", "g", 2.0, -m0, MAX_PAYLOAD_G - m0),)

    def _mass(self, base: ModelSpec, values: np.ndarray) -> float:
        return min(max(base.params.tip_mass_g + float(values[0]), 0.0), MAX_PAYLOAD_G)

    def apply(self, base: ModelSpec, values: np.ndarray) -> ModelSpec:
        p = base.params
        g = p.gravity_mm_s2 if np.linalg.norm(p.gravity_mm_s2) > 0 else STANDARD_GRAVITY_MM_S2
        params = replace(p, tip_mass_g=self._mass(base, values), gravity_mm_s2=tuple(g))
        return replace(base, params=params)

    def fitted(self, base: ModelSpec, values: np.ndarray) -> list[FittedValue]:
        return [FittedValue("robot", "", "tip_payload_kg", self._mass(base, values) / 1000.0)]
