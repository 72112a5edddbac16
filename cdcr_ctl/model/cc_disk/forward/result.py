"""One solved static pose of the forward model (:class:`ForwardResult`) and a small helper of
the solver. Units: mm, N, rad; frames: the robot base frame (tip), segment order (psi, x)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.model.cc_disk.kinematics import tip_frame_fast
from cdcr_ctl.model.shared.friction import FrictionState


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


def pack_result(xs, tr, state, modes, it, res, lengths) -> ForwardResult:
    """The solved pose as a :class:`ForwardResult`: bending vectors ``xs`` (2S, rad), the cables'
    transfer ``tr`` (N, mm), the friction ``state``, the cable ``modes``, the Newton iterations
    ``it`` and residual ``res``; ``lengths`` the segment lengths (mm) for the tip frame."""
    xs = [float(v) for v in xs]
    psi = []
    for i in range(len(xs) // 2):  # x_to_psi on floats: theta >= 0, phi = 0 where straight
        X, Y = xs[2 * i], xs[2 * i + 1]
        t = math.hypot(X, Y)
        psi.append((t, math.atan2(Y, X) if t > 0.0 else 0.0))
    R, tip = tip_frame_fast(xs, lengths)
    return ForwardResult(
        psi=np.array(psi, dtype=float).reshape(-1, 2),
        x=np.array(xs, dtype=float),
        tip_mm=np.array(tip),
        tension_distal_N=np.asarray(tr.T_distal),
        tension_base_N=np.asarray(tr.T_base),
        tension_actuator_N=np.asarray(tr.T_actuator),
        q_geom_mm=np.asarray(tr.q_geom),
        delta_mm=np.asarray(tr.q) - np.asarray(tr.q_geom),
        state=state,
        modes=modes,
        iterations=it,
        residual=res,
        R_tip=np.array(R),
    )
