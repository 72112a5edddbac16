"""Ball-jointed vertebra arm on an elastic NiTi rod (fuel-tank inspection robot): kinematics,
linear-module drive, attitude decode, joystick end-following planner, truth with gravity sag.

Pure numpy: no I/O, no clocks. Units: mm, N, rad, s, g (masses), N*mm^2 (EI), mm/s^2 (gravity).

Design (paper section 1.1): N joints (3 x 220 mm on the prototype), each of n vertebra disks
joined by ball joints and threaded on a superelastic rod; 3 steel cables per joint at 120 deg,
anchored at the joint's last disk and passing every proximal joint; each cable is pulled by a
linear module (9 on the prototype).

Joint geometry (eq. 3, derived here; NOTES eq. 3-4). Per joint n identical units: a gap of
``gap_mm`` (l0) between the facing hole exits of two disks with the ball centre in its middle,
then a disk whose holes are ``hole_length_mm`` (H) long. A joint bent by theta in the direction phi
turns every gap by theta/n about the axis (-sin phi, cos phi, 0) through its ball centre
(R = Rz(phi) Ry(theta/n) Rz(-phi), eq. 1, twist-free, so every hole keeps its angle beta). The
straight line between the two exits of a hole at radius r and angle beta is exactly

    l_gap = l0 cos(theta/2n) - 2 r sin(theta/2n) cos(phi - beta)

(the component along the bend axis is unchanged; in the bending plane it is 2 (a cos(psi/2) -
r' sin(psi/2)) with a = l0/2, r' = r cos(phi - beta), psi = theta/n). So eq. 3,
L = n [H + l0 cos(theta/2n) - d sin(theta/2n) cos(...)], is exact with d = 2 r: **d is the
DIAMETER of the hole circle**, as Fig. 2 labels it. The paper's cos(phi_i + (j-1) alpha) is
cos(phi - beta_j) for holes at beta_j = -(j-1) alpha (numbered clockwise seen from the tip); here
every cable carries its own ``hole_angle_rad`` beta, counter-clockwise from x.

Coordinates. psi (N, 2) rows (theta, phi): bend >= 0 and direction (rad). Internally the smooth
bending vector x = theta (cos phi, sin phi) is used (analytic through the straight pose).
Cable displacement q: mm PULLED IN (= the paper's Delta L, eq. 4-5: shortening is positive).

Frames. Robot base frame: z along the straight arm (up on the prototype, tip at (0, 0, 660) when
straight), x towards hole angle 0. Joint i's base frame is joint i-1's end frame (the top face of
its last disk). Attitude sensors: one on each joint end with x, y parallel to the end frame's
(paper Fig. 6), optionally turned by a known mount rotation.

Equation map (module: what it implements):

- :mod:`.params`: joints, cables, the arm; eq. 9 :class:`LinearModule`; the solvers' constants.
- :mod:`.forward`: the small-angle series; eq. 1 :func:`joint_rotation`, :func:`arc_transform`;
  eq. 2 :func:`tip_transform`; :func:`mass_points`.
- :mod:`.cables`: eq. 3-5 :func:`joint_cable_length`, :func:`joint_cable_shortening`,
  :func:`cable_displacements`, their Jacobian and Hessian, and the inverse
  :func:`joints_from_displacements`.
- :mod:`.attitude`: eq. 6 :func:`rotation_zyx`; eq. 7-8 :func:`angles_from_relative_rotation`,
  generalised to yaw-free tilt pairs in :func:`angles_from_tilts`; :func:`decode_joint_attitudes`.
- :mod:`.planner`: section 2.2 end-following :class:`EndFollowPlanner`, eq. 9's synchronised
  pulses :func:`synchronise`.
- :mod:`.statics`: gravity sag on the elastic rod :func:`statics_x`; the simulator's truth
  :func:`truth_pose`.
- :mod:`.loop`: the control loop's ``RobotModelPort`` :class:`VertebraModel` (eq. 5, 6-8).
"""

from cdcr_ctl.model.vertebra.attitude import (
    JointAttitude,
    angles_from_relative_rotation,
    angles_from_tilts,
    decode_from_rotations,
    decode_joint_attitudes,
    rotation_zyx,
    rotvec_matrix,
    world_up_in_sensor,
)
from cdcr_ctl.model.vertebra.cables import (
    cable_displacements,
    cable_hessian_x,
    cable_jacobian_x,
    cable_path_lengths,
    joint_cable_length,
    joint_cable_shortening,
    joints_from_displacements,
    psi_from_xs,
    solve_joint,
    straight_path_mm,
    x_from_psi,
)
from cdcr_ctl.model.vertebra.forward import (
    arc_transform,
    bend_vector,
    c2,
    d1,
    d2,
    joint_rotation,
    joint_transform,
    mass_points,
    psi_from_x,
    rot_x,
    rot_y,
    rot_z,
    s1,
    tip_position,
    tip_transform,
)
from cdcr_ctl.model.vertebra.loop import (
    ATTITUDE_GAIN_PER_S,
    ATTITUDE_MAX_CORRECTION_RAD,
    ATTITUDE_MAX_ERROR_RAD,
    ATTITUDE_MIN_OBSERVABILITY,
    AttitudeLoopParams,
    VertebraLoopState,
    VertebraModel,
)
from cdcr_ctl.model.vertebra.params import (
    D2_SERIES_BELOW,
    FOLLOW_STEP_RAD,
    GRAVITY_FD_STEP_RAD,
    SERIES_BELOW,
    SINGULAR_TOL,
    SOLVE_MAX_ITER,
    SOLVE_STEP_TOL_RAD,
    STATICS_MAX_ITER,
    STATICS_NEWTON_BELOW_RAD,
    STATICS_TOL_RAD,
    LinearModule,
    VertebraArm,
    VertebraCable,
    VertebraJoint,
)
from cdcr_ctl.model.vertebra.planner import (
    EndFollowPlanner,
    FollowMode,
    FollowParams,
    SyncStep,
    synchronise,
)
from cdcr_ctl.model.vertebra.statics import (
    _gravity_torque_and_hessian as _gravity_torque_and_hessian,
)
from cdcr_ctl.model.vertebra.statics import (
    gravity_hessian_x,
    gravity_potential_Nmm,
    gravity_torque_x,
    statics_inverse_step,
    statics_inverse_x,
    statics_x,
    truth_pose,
)

__all__ = [
    "ATTITUDE_GAIN_PER_S",
    "ATTITUDE_MAX_CORRECTION_RAD",
    "ATTITUDE_MAX_ERROR_RAD",
    "ATTITUDE_MIN_OBSERVABILITY",
    "D2_SERIES_BELOW",
    "FOLLOW_STEP_RAD",
    "GRAVITY_FD_STEP_RAD",
    "SERIES_BELOW",
    "SINGULAR_TOL",
    "SOLVE_MAX_ITER",
    "SOLVE_STEP_TOL_RAD",
    "STATICS_MAX_ITER",
    "STATICS_NEWTON_BELOW_RAD",
    "STATICS_TOL_RAD",
    "AttitudeLoopParams",
    "EndFollowPlanner",
    "FollowMode",
    "FollowParams",
    "JointAttitude",
    "LinearModule",
    "SyncStep",
    "VertebraArm",
    "VertebraCable",
    "VertebraJoint",
    "VertebraLoopState",
    "VertebraModel",
    "angles_from_relative_rotation",
    "angles_from_tilts",
    "arc_transform",
    "bend_vector",
    "c2",
    "cable_displacements",
    "cable_hessian_x",
    "cable_jacobian_x",
    "cable_path_lengths",
    "d1",
    "d2",
    "decode_from_rotations",
    "decode_joint_attitudes",
    "gravity_hessian_x",
    "gravity_potential_Nmm",
    "gravity_torque_x",
    "joint_cable_length",
    "joint_cable_shortening",
    "joint_rotation",
    "joint_transform",
    "joints_from_displacements",
    "mass_points",
    "psi_from_x",
    "psi_from_xs",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_zyx",
    "rotvec_matrix",
    "s1",
    "solve_joint",
    "statics_inverse_step",
    "statics_inverse_x",
    "statics_x",
    "straight_path_mm",
    "synchronise",
    "tip_position",
    "tip_transform",
    "truth_pose",
    "world_up_in_sensor",
    "x_from_psi",
]
