"""One solved static pose of the forward model (:class:`ForwardResult`) and a small helper of
the solver. Units: mm, N, rad; frames: the robot base frame (tip), segment order (psi, x)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdcr_ctl.model.friction import FrictionState


def _amax(v: np.ndarray) -> float:
    """max |v_i| of a short vector, NaN if any entry is NaN (as ``np.max(np.abs(v))``), on
    floats: a third of the numpy reductions' call cost for the solver's 2S + 2K entries."""
    vals = v.tolist()
    m = max(map(abs, vals))
    for x in vals:
        if x != x:
            return x
    return m


@dataclass(frozen=True)
class ForwardResult:
    """A solved static pose (arrays in cable / segment order)."""

    psi: np.ndarray  # (S, 2) theta, phi (rad)
    x: np.ndarray  # (2S,) bending vectors (rad)
    tip_mm: np.ndarray  # (3,) base frame
    tension_distal_N: np.ndarray
    tension_base_N: np.ndarray
    tension_actuator_N: np.ndarray
    q_geom_mm: np.ndarray
    delta_mm: np.ndarray
    state: FrictionState
    modes: tuple[str, ...]
    iterations: int
    residual: float  # largest scaled residual (rad-equivalent); rigid cables: mm
    #: tip frame's rotation (3, 3) in the base frame (eq. 1-3, computed with tip_mm)
    R_tip: np.ndarray | None = None

    def tension_at(self, location: str) -> np.ndarray:
        """Tensions at the load-cell location (``robot_base`` or ``actuator``)."""
        return self.tension_base_N if location == "robot_base" else self.tension_actuator_N
