"""The shape of a disk friction law other than the capstan's: three numbers and its speed factor.

Pure physics, no I/O. Units: mm, s. The law itself (the log tension ratio it gives along the wrap,
the force-transfer chain that uses it) is :mod:`cdcr_ctl.model.cc_disk.friction_law`; this module
holds only the numbers, so the rig config can validate and carry them without loading the model's
solvers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Reference Stribeck speed (mm/s): a third of the cable speed of Qi et al. 2023's pi/10 rad/s
#: bend at 4 mm routing radius (1.3 mm/s); a fitted shape scales it.
BREAKAWAY_MM_S = 0.4


@dataclass(frozen=True)
class FrictionLawShape:
    """The law's shape: wrap ``exponent`` p, ``viscous_s_per_mm`` c_v (s/mm), ``breakaway`` b
    (fraction of the Coulomb coefficient) over ``breakaway_mm_s`` v_b (mm/s), in
    ln(T(z)/T_anchor) = s mu_k m(v_k) z_ref (z / z_ref)^p (Qi et al. 2023 eq. 16-24 widened; the
    Gaussian Stribeck curve of Armstrong-Helouvry et al. 1994 for m(v); the formula in full in
    :mod:`cdcr_ctl.model.cc_disk.friction_law`)."""

    exponent: float = 1.0
    viscous_s_per_mm: float = 0.0
    breakaway: float = 0.0
    breakaway_mm_s: float = BREAKAWAY_MM_S

    @property
    def capstan(self) -> bool:
        """The model's own law (p = 1, no speed dependence)."""
        return self.exponent == 1.0 and self.viscous_s_per_mm == 0.0 and self.breakaway == 0.0

    @property
    def speed_dependent(self) -> bool:
        return self.viscous_s_per_mm != 0.0 or self.breakaway != 0.0

    def speed_factor(self, v_mm_s: float) -> float:
        """m(v) of the module docstring (v >= 0, mm/s)."""
        return (
            1.0
            + self.viscous_s_per_mm * v_mm_s
            + self.breakaway * math.exp(-((v_mm_s / self.breakaway_mm_s) ** 2))
        )
