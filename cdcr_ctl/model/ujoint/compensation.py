"""The universal-joint arm's compensation and the simulator's truth (Yang et al. 2022).

:func:`compensate`: the improved inverse kinematics of section 3 (eq. 11-17: cable lengths, dead
zone of section 4.1, deformation eq. 14 / 16-17). :func:`truth_angles`: the simulated arm, the
same effects forwards (play operator, statics, deformation) for given drive inputs.

Units: mm (pulled in), N, rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.ujoint.deadzone import play_inverse, play_update
from cdcr_ctl.model.ujoint.deformation import (
    cable_friction_state,
    deformation_rad,
    motion_direction,
    segment_friction_direction,
    undeform,
)
from cdcr_ctl.model.ujoint.kinematics import (
    _as_theta,
    _hole_lengths,
    _solve_holes,
    angles_from_path_lengths,
)
from cdcr_ctl.model.ujoint.params import (
    CABLE_MOTION_EPS_MM,
    MOTION_EPS_RAD,
    UJointArm,
    UJointEffects,
)
from cdcr_ctl.model.ujoint.statics import statics_angles, statics_inverse


# =========================================================================== truth
@dataclass(frozen=True)
class UJointTruthState:
    """Memory of :func:`truth_angles`: cable outputs after the dead zone, the last kinematic
    angles (for sgn(theta_dot), eq. 17) and the last motion sign of every segment coordinate;
    ``theta_coupled``: the last deformation pass's solution of each segment's own cables (N, 2,
    rad; a warm start, None before the first pass)."""

    q_out_mm: np.ndarray
    theta_kin: np.ndarray | None
    direction: np.ndarray
    theta_coupled: np.ndarray | None = None

    @classmethod
    def initial(cls, arm: UJointArm) -> UJointTruthState:
        """Homed: straight, outputs at 0, nothing moved yet."""
        return cls(np.zeros(arm.n_cables), None, np.zeros((arm.n_segments, 2)))


def truth_angles(
    arm: UJointArm,
    q_in_mm: np.ndarray,
    state: UJointTruthState | None = None,
    effects: UJointEffects | None = None,
) -> tuple[np.ndarray, UJointTruthState]:
    """The simulator's truth: joint angles (N, 2, rad) for drive inputs ``q_in_mm`` (cable pulled
    in at each drive, mm; motor angles convert with :meth:`LeadScrewDrive.cable_from_motor`).

    1. dead zone: every cable's output follows its input through :func:`play_update`;
    2. kinematics (eq. 11-12): the segment angles from the outputs, proximal first; this pass
       without deformation gives theta_kin and its direction of motion sgn(theta_dot) (eq. 17);
    3. deformation (eq. 14/16-17): segment n turns by :func:`deformation_rad`, and the distal
       cables run through the deformed segment (the coupling term of eq. 15), so the distal
       segments are solved again against the deformed proximal ones;
    4. statics: cable elasticity and pretension against gravity, :func:`statics_angles`.

    Returns (theta, new_state); ``state`` None starts from :meth:`UJointTruthState.initial`.
    """
    eff = effects or UJointEffects()
    st = state or UJointTruthState.initial(arm)
    q_in = np.asarray(q_in_mm, dtype=float)
    if q_in.shape != (arm.n_cables,):
        raise ModelError(f"need {arm.n_cables} cable inputs, got shape {q_in.shape}")
    if eff.dead_zone:
        pull, release = arm.dead_zones_mm
        q_out = play_update(st.q_out_mm, q_in, pull, release)
    else:
        q_out = q_in.copy()
    L = arm.straight_path_mm - q_out
    kin, theta = angles_from_path_lengths(arm, L, st.theta_kin)
    direction = motion_direction(
        kin, st.theta_kin, st.direction, arm.deformation.hold_when_stopped, MOTION_EPS_RAD
    )
    if eff.friction_driven_deformation and eff.dead_zone:
        pull, release = arm.dead_zones_mm
        sigma = cable_friction_state(q_in, q_out, pull, release)
        direction = segment_friction_direction(arm, kin, sigma)
    if eff.deformation and arm.deformation.kind != "off":
        # deformation of n needs only segments <= n solved: one pass, proximal first
        N = arm.n_segments
        offsets = np.zeros((N, 2))
        used = np.zeros(arm.n_cables)
        coupled = kin.copy()
        # warm start: this pass moves each solution away from the kinematic one by about as much
        # as it did last time
        shift = (
            st.theta_coupled - st.theta_kin
            if st.theta_coupled is not None and st.theta_kin is not None
            else np.zeros_like(kin)
        )
        for n, holes in enumerate(arm.hole_sets):
            own = holes.own.index
            if n > 0:  # segment 1 has no proximal coupling: the first pass solved it already
                coupled[n] = _solve_holes(holes.own, L[own] - used[own], kin[n] + shift[n])
            kn = coupled[n]
            full = np.zeros((N, 2))
            full[n] = kn
            offsets[n] = deformation_rad(arm, full, direction)[n]
            theta[n] = kn + offsets[n]
            distal = holes.through
            if distal.index.size:
                used[distal.index] += _hole_lengths(distal, theta[n, 0], theta[n, 1])
    else:
        coupled = None
    if eff.statics:
        theta = statics_angles(arm, theta)[0]
    return theta, UJointTruthState(q_out, kin, direction, coupled)


# =========================================================================== compensation
@dataclass(frozen=True)
class UJointCompState:
    """Memory of :func:`compensate`: last desired angles after the statics inverse (for the
    desired sgn(theta_dot)), their motion signs, last cable outputs and each cable's last
    direction (for the dead zone), and the last statics offset (warm start)."""

    theta_d: np.ndarray | None
    direction: np.ndarray
    q_out_mm: np.ndarray | None
    cable_direction: np.ndarray
    sag_offset: np.ndarray | None = None

    @classmethod
    def initial(cls, arm: UJointArm) -> UJointCompState:
        """Homed like :meth:`UJointTruthState.initial`: cable outputs at 0 with the play centred,
        so the first command already moves each cable out of its dead zone."""
        return cls(
            None, np.zeros((arm.n_segments, 2)), np.zeros(arm.n_cables), np.zeros(arm.n_cables)
        )


def compensate(
    arm: UJointArm,
    theta_d: np.ndarray,
    state: UJointCompState | None = None,
    effects: UJointEffects | None = None,
    statics_evals: int | None = None,
) -> tuple[np.ndarray, UJointCompState]:
    """Improved inverse kinematics (section 3): drive inputs q~ (mm pulled in) for desired angles.

    The paper's algorithm predicts the angles a command produces (steps 3-7: l = l_d + l_h,
    theta_n = theta_dn + Delta theta_hn + Delta theta_den, re-couple distal cables); here it is
    inverted so that :func:`truth_angles` with the same parameters returns ``theta_d``:

    1. statics: theta_pre = :func:`statics_inverse` (theta_d), warm-started from the last offset;
       ``statics_evals`` None converges fully, an integer caps the statics evaluations per call
       (the loop adapter uses 1: a third of the cost, error ~1e-9 rad at 1 kHz steps);
    2. deformation (eq. 14/16-17): sgn(theta_dot_m) from the change of the desired angles; the
       cables of segment n must produce theta_kin,n = :func:`undeform` (theta_pre), while distal
       cables run through the deformed (= desired) proximal segments;
    3. geometry (eq. 11): cable output q_out_k = sum_i 2 M_i d_i - [sum_{i<n_k} f_{i,k}(theta_pre,i)
       + f_{n_k,k}(theta_kin,n_k)];
    4. dead zone: q~ = :func:`play_inverse` (q_out) with each cable's direction of motion (kept
       while the cable output holds), so q~ = q + delta with delta = +e_p / -e_r / 0.

    Returns (q_in_mm, new_state). The round trip is exact (to the statics tolerance) as long as
    the truth's sgn(theta_dot) of the distal segments, taken from its kinematic angles, matches
    the one taken here from the desired angles (the tests' out-and-back paths never differ).
    """
    eff = effects or UJointEffects()
    st = state or UJointCompState.initial(arm)
    td = _as_theta(arm, theta_d).copy()
    if eff.statics:
        guess = None if st.sag_offset is None else td + st.sag_offset
        pre = statics_inverse(arm, td, guess, statics_evals if guess is not None else None)
    else:
        pre = td
    direction = motion_direction(
        pre, st.theta_d, st.direction, arm.deformation.hold_when_stopped, MOTION_EPS_RAD
    )
    if eff.deformation and arm.deformation.kind != "off":
        kin = undeform(arm, pre, direction)
    else:
        kin = pre
    L = np.zeros(arm.n_cables)
    for i, holes in enumerate(arm.hole_sets):
        if holes.through.index.size:
            L[holes.through.index] += _hole_lengths(holes.through, pre[i, 0], pre[i, 1])
        L[holes.own.index] += _hole_lengths(holes.own, kin[i, 0], kin[i, 1])
    q_out = arm.straight_path_mm - L
    cable_dir = motion_direction(q_out, st.q_out_mm, st.cable_direction, True, CABLE_MOTION_EPS_MM)
    if eff.dead_zone:
        pull, release = arm.dead_zones_mm
        q_in = play_inverse(q_out, cable_dir, pull, release)
    else:
        q_in = q_out
    return q_in, UJointCompState(pre, direction, q_out, cable_dir, pre - td)
