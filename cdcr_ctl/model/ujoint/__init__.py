"""Universal-joint segmented cable-driven arm (Yang et al. 2022, ROBOT 44(1): 45-54).

Pure numpy: no I/O, no clocks. Units: mm, N, rad, g (masses), N*mm (moments), mm/s^2 (gravity).

Design (paper section 2.1): N segments in series; segment n has M_n universal-joint sub-joints
that move by equal angles (two pairs of 8-shaped linkage cables couple neighbouring sub-joints)
and is bent by 3 drive cables anchored at its tip. Each segment has 2 DOF.

Joint coordinates. ``theta`` is an (N, 2) array, row n = (theta_{2n-1}, theta_{2n}) of the paper:
the rotation of EVERY sub-joint of segment n about the segment x axis and about the cross's
y axis (rad). The whole segment therefore bends by about M_n * |theta|; Yang's prototype (M = 6,
12 sub-joints) reaches a whole-arm bend of 72 deg at theta = 6 deg (sections 4.2-4.3).

Frames. Robot base frame: z along the straight arm, x towards the hole angle 0. The lower disk
D1 of a sub-joint, its centre O_U (the crossing of the axes xi_I, xi_J) at distance d above D1,
and the upper disk D2 at d above O_U. Sub-joint transform D1 -> D2 (eq. 4, verified below):

    T_sub = Trans(z, d) Rot(x, theta_a) Rot(y, theta_b) Trans(z, d)

followed by a rigid link tube of length ``link_mm`` (D2 -> the next sub-joint's D1; the cable is
straight and of constant length inside it). Disk holes are at radius rho and angle beta from x in
every disk frame; all disks carry the holes of every cable that passes (no twist is needed: eq. 4
is evaluated in each sub-joint's own D1 frame).

Eq. 6 (first-axis sign). The paper writes theta_{2n-1} = (-1)^(i+1) psi_{n,i,I}: in the paper's
D-H frames (Table 2, not in our extracted text) the first axis xi_{n,i,I} of sub-joint i points
along (-1)^(i+1) x. The physical rotation about +x is then (-1)^(i+1) psi_I = theta_{2n-1} in every
sub-joint: a uniform bend, which is what 8-shaped (crossed) linkage cables produce (a crossed
cable between joints i and i+1 keeps r*alpha_i - r*alpha_{i+1} = 0). :func:`subjoint_angles` gives
the D-H-local (psi_I, psi_J) of eq. 6 and :func:`segment_cable_lengths` converts them back with the
axis sign before using eq. 4. Feeding eq. 4 the alternating psi_I directly (same hole frames)
would describe a zig-zag whose cable lengths do not change to first order in theta_{2n-1} for even
M (a segment that its own cables cannot steer), so that reading is rejected.

Cable displacement ``q`` is mm PULLED IN at the drive (this project's sign; the paper's Delta l is
the change of cable length in the arm, q = -Delta l).

Equation map (module: what it implements):

- :mod:`.params`: the design's parameters; eq. 3 :class:`LeadScrewDrive`; eq. 14, 16-17's
  :class:`DeformationParams`; the solver constants.
- :mod:`.kinematics`: eq. 4 :func:`subjoint_cable_length`; eq. 5-6 :func:`segment_cable_lengths`,
  :func:`subjoint_angles`; eq. 7-10 :func:`solve_segment_angles`; eq. 11-12
  :func:`cable_path_lengths`, :func:`angles_from_path_lengths`; eq. 13 and 15
  :func:`linearised_angle_error`; the analytic Jacobian and Hessian (fast paths).
- :mod:`.forward`: eq. 1-2 :func:`tip_transform`, :func:`mass_points`.
- :mod:`.deadzone`: dead zone of section 4.1 :func:`dead_zone_mm`, :func:`play_update`.
- :mod:`.deformation`: eq. 14, 16-17 :func:`deformation_rad`, :func:`undeform`.
- :mod:`.statics`: gravity and cable-stretch equilibrium :func:`statics_angles` (NOTES).
- :mod:`.compensation`: section 3 algorithm :func:`compensate`; the simulator's truth
  :func:`truth_angles`.
- :mod:`.loop`: the control loop's ``RobotModelPort`` :class:`UJointModel`.
"""

from cdcr_ctl.model.ujoint.compensation import (
    UJointCompState,
    UJointTruthState,
    compensate,
    truth_angles,
)
from cdcr_ctl.model.ujoint.deadzone import (
    calibrate_friction_exponent,
    dead_zone_mm,
    dead_zone_width_mm,
    play_inverse,
    play_update,
)
from cdcr_ctl.model.ujoint.deformation import (
    cable_friction_state,
    deformation_rad,
    motion_direction,
    segment_friction_direction,
    undeform,
)
from cdcr_ctl.model.ujoint.forward import (
    mass_points,
    segment_transform,
    subjoint_transform,
    tip_position,
    tip_transform,
)
from cdcr_ctl.model.ujoint.kinematics import (
    _hole_lengths as _hole_lengths,
)
from cdcr_ctl.model.ujoint.kinematics import (
    _hole_terms as _hole_terms,
)
from cdcr_ctl.model.ujoint.kinematics import (
    angles_from_displacements,
    angles_from_path_lengths,
    cable_displacements,
    cable_jacobian,
    cable_jacobian_hessian,
    cable_path_lengths,
    first_axis_signs,
    linearised_angle_error,
    rot_x,
    rot_y,
    segment_cable_jacobian,
    segment_cable_lengths,
    solve_segment_angles,
    subjoint_angles,
    subjoint_cable_length,
    subjoint_cable_length_grad,
)
from cdcr_ctl.model.ujoint.loop import (
    DELTA_FLOOR,
    DELTA_HEADROOM,
    UJointLoopState,
    UJointModel,
    joint_angles_from_psi,
    psi_from_joint_angles,
)
from cdcr_ctl.model.ujoint.params import (
    CABLE_MOTION_EPS_MM,
    GRAVITY_FD_STEP_RAD,
    LOOP_STATICS_EVALS,
    MOTION_EPS_RAD,
    NEWTON_MAX_ITER,
    NEWTON_STEP_TOL_RAD,
    STATICS_MAX_ITER,
    STATICS_TOL_RAD,
    DeformationKind,
    DeformationParams,
    GearRatioKind,
    HoleSet,
    LeadScrewDrive,
    SegmentHoles,
    UJointArm,
    UJointCable,
    UJointEffects,
    UJointSegment,
)
from cdcr_ctl.model.ujoint.statics import (
    gravity_hessian,
    gravity_potential_Nmm,
    gravity_torque,
    small_deflection,
    statics_angles,
    statics_inverse,
)

__all__ = [
    "CABLE_MOTION_EPS_MM",
    "DELTA_FLOOR",
    "DELTA_HEADROOM",
    "GRAVITY_FD_STEP_RAD",
    "LOOP_STATICS_EVALS",
    "MOTION_EPS_RAD",
    "NEWTON_MAX_ITER",
    "NEWTON_STEP_TOL_RAD",
    "STATICS_MAX_ITER",
    "STATICS_TOL_RAD",
    "DeformationKind",
    "DeformationParams",
    "GearRatioKind",
    "HoleSet",
    "LeadScrewDrive",
    "SegmentHoles",
    "UJointArm",
    "UJointCable",
    "UJointCompState",
    "UJointEffects",
    "UJointLoopState",
    "UJointModel",
    "UJointSegment",
    "UJointTruthState",
    "angles_from_displacements",
    "angles_from_path_lengths",
    "cable_displacements",
    "cable_friction_state",
    "cable_jacobian",
    "cable_jacobian_hessian",
    "cable_path_lengths",
    "calibrate_friction_exponent",
    "compensate",
    "dead_zone_mm",
    "dead_zone_width_mm",
    "deformation_rad",
    "first_axis_signs",
    "gravity_hessian",
    "gravity_potential_Nmm",
    "gravity_torque",
    "joint_angles_from_psi",
    "linearised_angle_error",
    "mass_points",
    "motion_direction",
    "play_inverse",
    "play_update",
    "psi_from_joint_angles",
    "rot_x",
    "rot_y",
    "segment_cable_jacobian",
    "segment_cable_lengths",
    "segment_friction_direction",
    "segment_transform",
    "small_deflection",
    "solve_segment_angles",
    "statics_angles",
    "statics_inverse",
    "subjoint_angles",
    "subjoint_cable_length",
    "subjoint_cable_length_grad",
    "subjoint_transform",
    "tip_position",
    "tip_transform",
    "truth_angles",
    "undeform",
]
