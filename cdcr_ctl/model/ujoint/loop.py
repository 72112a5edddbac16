"""The universal-joint design as the control loop's ``RobotModelPort`` (Yang et al. 2022).

:class:`UJointModel` converts the loop's (tilt, direction) rows to the paper's (theta_{2n-1},
theta_{2n}) (:func:`joint_angles_from_psi`, :func:`psi_from_joint_angles`), and gives nominal
(eq. 11-12) and compensated (section 3, :func:`compensate`) cable displacements.

Units: mm (pulled in), rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.ujoint.compensation import UJointCompState, compensate
from cdcr_ctl.model.ujoint.forward import tip_position
from cdcr_ctl.model.ujoint.kinematics import cable_displacements
from cdcr_ctl.model.ujoint.params import LOOP_STATICS_EVALS, UJointArm, UJointEffects


# =========================================================================== loop adapter
def joint_angles_from_psi(psi: np.ndarray) -> np.ndarray:
    """Sub-joint angles (theta_{2n-1}, theta_{2n}) (N, 2) from the loop's rows (tilt, direction).

    The loop, its trajectories and logs speak one language for every design: per segment a bend
    magnitude >= 0 and its direction (rad). For this design the bend is the TILT of one sub-joint
    (the angle between the z axes of D1 and D2, which every sub-joint of the segment shares) and
    the direction phi is where that tilt points, from x about z. With the sub-joint rotation
    Rx(a) Ry(b) (eq. 4), the tilted axis is Rx(a) Ry(b) e_z = (sin b, -sin a cos b, cos a cos b)
    = (sin t cos phi, sin t sin phi, cos t), so

        b = asin(sin t cos phi),   a = atan2(-sin t sin phi, cos t)       (t in [0, pi/2))

    e.g. (t, 0) -> (0, t): Yang's go-and-return [0, 6 deg, 0, 6 deg] is t = 6 deg, phi = 0 for
    both segments. Smooth through t = 0 (a ~ -t sin phi, b ~ t cos phi).
    """
    p = np.asarray(psi, dtype=float)
    st, ct = np.sin(p[:, 0]), np.cos(p[:, 0])
    b = np.arcsin(np.clip(st * np.cos(p[:, 1]), -1.0, 1.0))
    a = np.arctan2(-st * np.sin(p[:, 1]), ct)
    return np.column_stack((a, b))


def psi_from_joint_angles(theta: np.ndarray, phi_if_straight: float = 0.0) -> np.ndarray:
    """Inverse of :func:`joint_angles_from_psi`: rows (tilt >= 0, direction) from (a, b) (rad)."""
    t = np.asarray(theta, dtype=float)
    a, b = t[:, 0], t[:, 1]
    v = np.column_stack((np.sin(b), -np.sin(a) * np.cos(b), np.cos(a) * np.cos(b)))
    tilt = np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2])
    phi = np.where(tilt > 0.0, np.arctan2(v[:, 1], v[:, 0]), phi_if_straight)
    return np.column_stack((tilt, phi))


#: Share of the cable velocity limit the compensation term may use on top of the ideal motion,
#: and the share it may always use (even when the ideal motion alone is near the limit).
DELTA_HEADROOM = 0.9
DELTA_FLOOR = 0.05


@dataclass
class UJointLoopState:
    """Mutable holder of the compensation memory for :class:`UJointModel`: section 3's state,
    the compensation term now applied (mm, rate-limited) and the last ideal command (mm)."""

    comp: UJointCompState
    delta_mm: np.ndarray | None = None
    q_nominal_prev: np.ndarray | None = None


class UJointModel:
    """The universal-joint design as the control loop's ``RobotModelPort``.

    ``psi`` rows are (tilt, direction) per segment (:func:`joint_angles_from_psi`), the same
    (bend, direction) form as the other designs, so trajectories, logs and limits
    (``limits.bend_rad`` is the sub-joint tilt) need nothing design-specific; internally every
    call converts them to the paper's (theta_{2n-1}, theta_{2n}). Cable displacements are mm pulled
    in at the drives, in ``arm.cables`` order. ``effects`` selects what mode ``model`` compensates
    (section 3's algorithm, :func:`compensate`); mode ``measured`` has no meaning here (no
    tension-based model) and raises.

    The dead zone makes section 3's command STEP by e_p + e_r (up to ~1 mm) where a cable
    reverses, and the proximal deformation term flips with it. With ``cable_velocity_mm_s`` and
    ``period_s`` given, the compensation term delta = q_command - q_nominal moves towards its
    target by the same fraction on every cable per cycle, the largest fraction for which no cable
    exceeds the headroom the ideal motion leaves under the velocity limit,
    max(DELTA_HEADROOM v dt - |dq_nominal|, DELTA_FLOOR v dt): a synchronised move, so the distal
    cables cross their dead zone (reversing the friction torque) while the proximal cables take up
    the reversed deformation, and the command never exceeds the limit the supervisor enforces.
    """

    def __init__(
        self,
        arm: UJointArm,
        effects: UJointEffects | None = None,
        cable_velocity_mm_s: float | None = None,
        period_s: float | None = None,
    ) -> None:
        self.arm = arm
        self.effects = effects or UJointEffects()
        self.n_segments = arm.n_segments
        self.n_cables = arm.n_cables
        if (cable_velocity_mm_s is None) != (period_s is None):
            raise ModelError("give both cable_velocity_mm_s and period_s, or neither")
        self.step_mm: float | None = None
        if cable_velocity_mm_s is not None and period_s is not None:
            self.step_mm = cable_velocity_mm_s * period_s
        if self.step_mm is not None and not self.step_mm > 0:
            raise ModelError("cable velocity and period must be > 0")

    def new_state(self) -> UJointLoopState:
        return UJointLoopState(UJointCompState.initial(self.arm))

    def q_nominal(self, psi: np.ndarray) -> np.ndarray:
        """Ideal inverse kinematics, eq. 11 (mm pulled in): the ideal geometric model."""
        return cable_displacements(self.arm, joint_angles_from_psi(psi))

    def q_command(
        self,
        psi: np.ndarray,
        q_nominal: np.ndarray,
        state: object,
        mode: str,
        measured_N: np.ndarray | None,
    ) -> np.ndarray:
        """``off``: q_nominal (the memory still follows the motion); ``model``: q_nominal + delta
        with delta = :func:`compensate` - ideal (dead zone, deformation, statics), mm."""
        if not isinstance(state, UJointLoopState):
            raise ModelError("q_command needs the state made by new_state()")
        if mode not in ("off", "model"):
            raise ModelError(f"the ujoint model compensates in mode off or model, not {mode!r}")
        theta = joint_angles_from_psi(psi)
        q_comp, state.comp = compensate(
            self.arm, theta, state.comp, self.effects, statics_evals=LOOP_STATICS_EVALS
        )
        q = np.asarray(q_nominal, dtype=float)
        q_prev = state.q_nominal_prev
        state.q_nominal_prev = q.copy()
        if mode == "off":
            state.delta_mm = None  # the loop ramps a mode switch out itself
            return q
        target = q_comp - cable_displacements(self.arm, theta)
        if self.step_mm is None or state.delta_mm is None:
            delta = target if self.step_mm is None else np.zeros_like(target)
        else:
            delta = state.delta_mm
        if self.step_mm is not None:
            moved = np.zeros_like(q) if q_prev is None else np.abs(q - q_prev)
            room = np.maximum(DELTA_HEADROOM * self.step_mm - moved, DELTA_FLOOR * self.step_mm)
            # every cable covers the same fraction of its way per cycle: the distal cables
            # cross their dead zone (reversing the friction torque) in step with the proximal
            # cables taking up the reversed deformation, as one synchronised move
            need = np.abs(target - delta)
            frac = float(np.min(np.where(need > room, room / np.maximum(need, 1e-300), 1.0)))
            delta = delta + frac * (target - delta)
        state.delta_mm = delta
        return q + delta

    def tip(self, psi: np.ndarray) -> np.ndarray:
        """Tip position in the robot base frame (mm), eq. 1-2."""
        return tip_position(self.arm, joint_angles_from_psi(psi))
