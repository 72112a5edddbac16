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

Equation map: eq. 1 :func:`joint_rotation`, :func:`arc_transform`; eq. 2 :func:`tip_transform`;
eq. 3-5 :func:`joint_cable_length`, :func:`joint_cable_shortening`, :func:`cable_displacements`;
eq. 6 :func:`rotation_zyx`; eq. 7-8 :func:`angles_from_relative_rotation`, generalised to yaw-free
tilt pairs in :func:`angles_from_tilts`; eq. 9 :class:`LinearModule`; section 2.2 end-following
:class:`EndFollowPlanner`; the simulator's truth :func:`truth_pose`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from cdcr_ctl.errors import ModelError

#: Below this |u| the ratios sin(u)/u etc. use their Taylor series.
SERIES_BELOW = 0.05
#: Gauss-Newton (cable lengths -> joint) stops when the step is below this (rad).
SOLVE_STEP_TOL_RAD = 1e-13
SOLVE_MAX_ITER = 60
#: Attitude decode: sin(theta) (or a tilt difference) below this counts as singular.
SINGULAR_TOL = 1e-9
#: Central-difference step for the geometric stiffness of the pretension (rad).
FD_STEP_RAD = 1e-6
#: Iterations of the statics and of its inverse, and their tolerance (rad), which sits above the
#: round-off of the finite-difference gravity moment.
STATICS_MAX_ITER = 60
#: Central-difference step of the gravity moment (rad): large enough that the round-off of the
#: potential (~1e-16 V / h) stays below the statics tolerance, small enough for O(h^2) accuracy.
GRAVITY_FD_STEP_RAD = 1e-4
STATICS_TOL_RAD = 1e-10
#: The paper's end-following step (rad), section 2.2.
FOLLOW_STEP_RAD = 0.05


# =========================================================================== parameters
@dataclass(frozen=True)
class VertebraJoint:
    """One joint: ``n_gaps`` (n) ball-joint gaps of ``gap_mm`` (l0) and n disks with holes
    ``hole_length_mm`` (H) long; the rod's bending stiffness ``rod_EI_Nmm2``; ``disk_mass_g`` per
    disk (rod included). Length at the straight pose n (l0 + H)."""

    name: str
    n_gaps: int
    gap_mm: float
    hole_length_mm: float
    rod_EI_Nmm2: float = 0.0
    disk_mass_g: float = 0.0

    def __post_init__(self) -> None:
        if self.n_gaps < 1 or not self.gap_mm > 0 or self.hole_length_mm < 0:
            raise ModelError(f"joint {self.name}: n_gaps >= 1, gap_mm > 0, hole_length_mm >= 0")
        if self.rod_EI_Nmm2 < 0 or self.disk_mass_g < 0:
            raise ModelError(f"joint {self.name}: rod EI and disk mass must be >= 0")

    @property
    def length_mm(self) -> float:
        return self.n_gaps * (self.gap_mm + self.hole_length_mm)


@dataclass(frozen=True)
class VertebraCable:
    """A cable anchored at the last disk of joint ``joint`` (0-based), through holes at angle
    ``hole_angle_rad`` (beta, from x) and radius ``hole_radius_mm`` (r; eq. 3's d = 2 r) in every
    disk of that joint and all proximal joints. ``total_length_mm``: linear module to anchor at
    the straight pose (sets EA / L)."""

    name: str
    joint: int
    hole_angle_rad: float
    hole_radius_mm: float
    EA_N: float = math.inf
    total_length_mm: float = 1.0
    pretension_N: float = 0.0

    def __post_init__(self) -> None:
        if self.joint < 0 or not self.hole_radius_mm > 0:
            raise ModelError(f"cable {self.name}: joint >= 0 and hole_radius_mm > 0 required")
        if not (self.EA_N > 0 and self.total_length_mm > 0 and self.pretension_N >= 0):
            raise ModelError(f"cable {self.name}: EA, length > 0 and pretension >= 0 required")

    @property
    def stiffness_N_per_mm(self) -> float:
        return self.EA_N / self.total_length_mm


@dataclass(frozen=True)
class LinearModule:
    """A linear module: ``steps_per_rev`` (s) position units per screw turn (microsteps of a
    stepper driver, or encoder counts), ``lead_mm`` (c) per turn, speed limit ``v_max_mm_s``.

    Eq. 9: pulses m = (s / c) Delta l and pulse rate f = (s / c) v.
    """

    steps_per_rev: float
    lead_mm: float
    v_max_mm_s: float

    def __post_init__(self) -> None:
        if not (self.steps_per_rev > 0 and self.lead_mm > 0 and self.v_max_mm_s > 0):
            raise ModelError("linear module: steps_per_rev, lead_mm and v_max_mm_s must be > 0")

    @property
    def pulses_per_mm(self) -> float:
        return self.steps_per_rev / self.lead_mm

    def pulses(self, dl_mm: np.ndarray | float) -> np.ndarray:
        """Eq. 9: m = (s/c) Delta l (real-valued; round where pulses are sent)."""
        return np.asarray(dl_mm, dtype=float) * self.pulses_per_mm

    def pulse_rate_hz(self, v_mm_s: np.ndarray | float) -> np.ndarray:
        """Eq. 9: f = (s/c) v."""
        return np.asarray(v_mm_s, dtype=float) * self.pulses_per_mm

    @property
    def max_pulse_rate_hz(self) -> float:
        return self.steps_per_rev / self.lead_mm * self.v_max_mm_s


@dataclass(frozen=True)
class VertebraArm:
    """The arm: joints base to tip, cables, one linear module per cable (same order).

    ``gravity_mm_s2`` in the robot base frame; ``tip_mass_g`` at the tip (camera).
    """

    joints: tuple[VertebraJoint, ...]
    cables: tuple[VertebraCable, ...]
    modules: tuple[LinearModule, ...]
    gravity_mm_s2: tuple[float, float, float] = (0.0, 0.0, -9810.0)
    tip_mass_g: float = 0.0

    def __post_init__(self) -> None:
        N = len(self.joints)
        if N < 1:
            raise ModelError("the arm needs at least one joint")
        if len(self.modules) != len(self.cables):
            raise ModelError(f"{len(self.cables)} cables but {len(self.modules)} linear modules")
        for c in self.cables:
            if c.joint >= N:
                raise ModelError(f"cable {c.name}: joint index {c.joint} >= {N} joints")
        for i in range(N):
            own = [c for c in self.cables if c.joint == i]
            J0 = np.array([[math.cos(c.hole_angle_rad), math.sin(c.hole_angle_rad)] for c in own])
            if len(own) < 2 or np.linalg.matrix_rank(J0, tol=1e-9) < 2:
                raise ModelError(
                    f"joint {self.joints[i].name}: needs >= 2 cables not collinear with the centre"
                )

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def n_cables(self) -> int:
        return len(self.cables)

    @cached_property
    def own_cables(self) -> tuple[np.ndarray, ...]:
        return tuple(
            np.array([k for k, c in enumerate(self.cables) if c.joint == i], dtype=int)
            for i in range(self.n_joints)
        )

    @cached_property
    def anchor(self) -> np.ndarray:
        return np.array([c.joint for c in self.cables], dtype=int)

    @cached_property
    def betas(self) -> np.ndarray:
        return np.array([c.hole_angle_rad for c in self.cables])

    @cached_property
    def radii(self) -> np.ndarray:
        return np.array([c.hole_radius_mm for c in self.cables])

    @cached_property
    def pulses_per_mm(self) -> np.ndarray:
        return np.array([m.pulses_per_mm for m in self.modules])

    @cached_property
    def max_pulse_rate_hz(self) -> np.ndarray:
        return np.array([m.max_pulse_rate_hz for m in self.modules])


# =========================================================================== series
def s1(u: float) -> float:
    """sin(u)/u (-> 1)."""
    if abs(u) < SERIES_BELOW:
        u2 = u * u
        return 1.0 - u2 / 6.0 * (1.0 - u2 / 20.0 * (1.0 - u2 / 42.0 * (1.0 - u2 / 72.0)))
    return math.sin(u) / u


def d1(u: float) -> float:
    """(u cos u - sin u)/u^3 = s1'(u)/u (-> -1/3)."""
    if abs(u) < SERIES_BELOW:
        u2 = u * u
        return -1.0 / 3.0 + u2 / 30.0 - u2 * u2 / 840.0 + u2**3 / 45360.0
    return (u * math.cos(u) - math.sin(u)) / u**3


def c2(u: float) -> float:
    """(1 - cos u)/u^2 (-> 1/2)."""
    if abs(u) < SERIES_BELOW:
        u2 = u * u
        return 0.5 - u2 / 24.0 + u2 * u2 / 720.0 - u2**3 / 40320.0
    h = math.sin(0.5 * u)
    return 2.0 * h * h / (u * u)


def bend_vector(theta: float, phi: float) -> np.ndarray:
    """x = theta (cos phi, sin phi) (rad)."""
    return np.array([theta * math.cos(phi), theta * math.sin(phi)])


def psi_from_x(x: np.ndarray, phi_if_straight: float = 0.0) -> tuple[float, float]:
    """(theta >= 0, phi) of a bending vector; ``phi_if_straight`` where theta = 0."""
    theta = math.hypot(float(x[0]), float(x[1]))
    phi = math.atan2(float(x[1]), float(x[0])) if theta > 0.0 else phi_if_straight
    return theta, phi


def _psi_array(psi: np.ndarray, n: int) -> np.ndarray:
    p = np.asarray(psi, dtype=float)
    if p.shape != (n, 2):
        raise ModelError(f"joint poses must have shape ({n}, 2), got {p.shape}")
    return p


# =========================================================================== eq. 1-2
def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(b: float) -> np.ndarray:
    c, s = math.cos(b), math.sin(b)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(g: float) -> np.ndarray:
    c, s = math.cos(g), math.sin(g)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def joint_rotation(theta: float, phi: float) -> np.ndarray:
    """Rotation of a joint (or of one gap with theta/n), eq. 1: Rz(phi) Ry(theta) Rz(-phi).

    Element (2,1) is c phi s phi (c theta - 1) (the symmetric xy block; NOTES on Qi eq. 1 apply
    to the same matrix printed here).
    """
    ct, st, cp, sp = math.cos(theta), math.sin(theta), math.cos(phi), math.sin(phi)
    return np.array(
        [
            [ct * cp * cp + sp * sp, cp * sp * (ct - 1.0), st * cp],
            [cp * sp * (ct - 1.0), cp * cp + sp * sp * ct, st * sp],
            [-st * cp, -st * sp, ct],
        ]
    )


def arc_transform(theta: float, phi: float, length_mm: float) -> np.ndarray:
    """Eq. 1 in full: the constant-curvature arc of length L, 4x4 (position finite at theta = 0:
    L/theta (1 - cos theta) = L theta c2(theta), L/theta sin theta = L s1(theta))."""
    T = np.eye(4)
    T[:3, :3] = joint_rotation(theta, phi)
    a = length_mm * theta * c2(theta)
    T[:3, 3] = (a * math.cos(phi), a * math.sin(phi), length_mm * s1(theta))
    return T


def _unit_transform(theta: float, phi: float, joint: VertebraJoint) -> np.ndarray:
    """One vertebra unit: half gap, the gap's rotation about the ball centre, half gap, disk."""
    T = np.eye(4)
    R = joint_rotation(theta / joint.n_gaps, phi)
    a = 0.5 * joint.gap_mm
    # Trans(z, a) R Trans(z, a + H)
    T[:3, :3] = R
    T[:3, 3] = np.array([0.0, 0.0, a]) + R @ np.array([0.0, 0.0, a + joint.hole_length_mm])
    return T


def joint_transform(theta: float, phi: float, joint: VertebraJoint) -> np.ndarray:
    """Joint base -> joint end (top face of its last disk), the exact vertebra chain (4x4, mm).

    Its rotation is eq. 1's; its position is the polygon of n units, which tends to eq. 1's arc
    as n grows (:func:`arc_transform`).
    """
    return np.linalg.matrix_power(_unit_transform(theta, phi, joint), joint.n_gaps)


def tip_transform(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Robot base -> tip, eq. 2: the product of the joints' transforms (4x4, mm)."""
    p = _psi_array(psi, arm.n_joints)
    T = np.eye(4)
    for i, j in enumerate(arm.joints):
        T = T @ joint_transform(p[i, 0], p[i, 1], j)
    return T


def tip_position(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Tip position in the robot base frame (mm)."""
    return tip_transform(arm, psi)[:3, 3]


def mass_points(arm: VertebraArm, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions (K, 3) mm, masses (K,) g): every disk at its centre, and the tip mass."""
    p = _psi_array(psi, arm.n_joints)
    pts: list[np.ndarray] = []
    ms: list[float] = []
    T = np.eye(4)
    for i, j in enumerate(arm.joints):
        U = _unit_transform(p[i, 0], p[i, 1], j)
        centre = np.array([0.0, 0.0, -0.5 * j.hole_length_mm, 1.0])
        for _ in range(j.n_gaps):
            T = T @ U
            if j.disk_mass_g > 0:
                pts.append((T @ centre)[:3])
                ms.append(j.disk_mass_g)
    if arm.tip_mass_g > 0:
        pts.append(T[:3, 3].copy())
        ms.append(arm.tip_mass_g)
    if not pts:
        return np.zeros((0, 3)), np.zeros(0)
    return np.array(pts), np.array(ms)


# =========================================================================== eq. 3-5
def joint_cable_length(
    theta: float,
    phi: float,
    beta: np.ndarray | float,
    hole_radius_mm: np.ndarray | float,
    joint: VertebraJoint,
) -> np.ndarray:
    """Cable length through one joint, eq. 3 (mm): n [H + l0 cos(theta/2n) - d sin(theta/2n)
    cos(phi - beta)] with d = 2 r (the hole-circle diameter; module docstring)."""
    n = joint.n_gaps
    u = theta / (2.0 * n)
    d = 2.0 * np.asarray(hole_radius_mm, dtype=float)
    return n * (
        joint.hole_length_mm
        + joint.gap_mm * math.cos(u)
        - d * math.sin(u) * np.cos(phi - np.asarray(beta, dtype=float))
    )


def joint_cable_shortening(
    theta: float,
    phi: float,
    beta: np.ndarray | float,
    hole_radius_mm: np.ndarray | float,
    joint: VertebraJoint,
) -> np.ndarray:
    """Eq. 4: Delta L = n {l0 - [l0 cos(theta/2n) - d sin(theta/2n) cos(phi - beta)]} (mm, > 0
    when the cable is pulled in)."""
    return joint.n_gaps * (joint.gap_mm + joint.hole_length_mm) - joint_cable_length(
        theta, phi, beta, hole_radius_mm, joint
    )


def _joint_length_x(
    x: np.ndarray, beta: np.ndarray, r: np.ndarray, joint: VertebraJoint
) -> tuple[np.ndarray, np.ndarray]:
    """(L (K,), dL/dx (K, 2)) of eq. 3 in the bending vector x (smooth through x = 0).

    With u = theta/2n and x_beta = x . (cos beta, sin beta) = theta cos(phi - beta):
    L = n H + n l0 cos u - r s1(u) x_beta, and (s1, cos u even in theta)
    dL/dx = -(l0 / 4n) s1(u) x - (r / 4n^2) d1(u) x_beta x - r s1(u) (cos beta, sin beta).
    """
    n = joint.n_gaps
    theta = math.hypot(float(x[0]), float(x[1]))
    u = theta / (2.0 * n)
    e = np.column_stack((np.cos(beta), np.sin(beta)))
    xb = e @ x
    su = s1(u)
    L = n * joint.hole_length_mm + n * joint.gap_mm * math.cos(u) - r * su * xb
    dL = (
        -(joint.gap_mm / (4.0 * n)) * su * x[None, :]
        - (r * d1(u) * xb / (4.0 * n * n))[:, None] * x[None, :]
        - (r * su)[:, None] * e
    )
    return L, dL


def cable_path_lengths(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Per cable, its length through every joint it passes (mm), eq. 3 summed as in eq. 5."""
    p = _psi_array(psi, arm.n_joints)
    L = np.zeros(arm.n_cables)
    for i, j in enumerate(arm.joints):
        through = arm.anchor >= i
        L[through] += joint_cable_length(
            p[i, 0], p[i, 1], arm.betas[through], arm.radii[through], j
        )
    return L


def straight_path_mm(arm: VertebraArm) -> np.ndarray:
    """Per cable, its path length at the straight pose, sum of n (l0 + H) over its joints (mm)."""
    lengths = np.array([j.length_mm for j in arm.joints])
    return np.array([lengths[: c.joint + 1].sum() for c in arm.cables])


def cable_displacements(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Eq. 5: each cable's total shortening, the sum of eq. 4 over the joints it passes (mm pulled
    in). A distal joint's cables change with every proximal joint's pose (the coupling)."""
    return straight_path_mm(arm) - cable_path_lengths(arm, psi)


def cable_jacobian_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """d(path length)/d(bending vectors) (C x 2N, mm/rad), columns (x_1, y_1, x_2, ...)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    J = np.zeros((arm.n_cables, 2 * arm.n_joints))
    for i, j in enumerate(arm.joints):
        through = np.nonzero(arm.anchor >= i)[0]
        _, dL = _joint_length_x(xs[i], arm.betas[through], arm.radii[through], j)
        J[np.ix_(through, [2 * i, 2 * i + 1])] = dL
    return J


def _path_lengths_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    L = np.zeros(arm.n_cables)
    for i, j in enumerate(arm.joints):
        through = arm.anchor >= i
        L[through] += _joint_length_x(xs[i], arm.betas[through], arm.radii[through], j)[0]
    return L


def x_from_psi(psi: np.ndarray) -> np.ndarray:
    """(N, 2) rows (theta, phi) -> (N, 2) bending vectors."""
    p = np.asarray(psi, dtype=float)
    return np.column_stack((p[:, 0] * np.cos(p[:, 1]), p[:, 0] * np.sin(p[:, 1])))


def psi_from_xs(x: np.ndarray, phi_if_straight: np.ndarray | None = None) -> np.ndarray:
    """(N, 2) bending vectors -> rows (theta, phi); ``phi_if_straight`` per joint at theta = 0."""
    xs = np.asarray(x, dtype=float).reshape(-1, 2)
    out = np.zeros_like(xs)
    for i, xi in enumerate(xs):
        fallback = 0.0 if phi_if_straight is None else float(phi_if_straight[i])
        out[i] = psi_from_x(xi, fallback)
    return out


def solve_joint(
    lengths_mm: np.ndarray,
    beta: np.ndarray,
    r: np.ndarray,
    joint: VertebraJoint,
    guess: np.ndarray | None = None,
) -> np.ndarray:
    """Bending vector of one joint from its cables' lengths through it (Gauss-Newton on eq. 3).

    Least squares when the three lengths are inconsistent. Raises :class:`ModelError` when it
    does not converge (lengths out of reach).
    """
    ld = np.asarray(lengths_mm, dtype=float)
    x = np.zeros(2) if guess is None else np.array(guess, dtype=float)
    for _ in range(SOLVE_MAX_ITER):
        L, dL = _joint_length_x(x, beta, r, joint)
        step = np.linalg.lstsq(dL, ld - L, rcond=None)[0]
        big = float(np.max(np.abs(step)))
        if big > 0.5:
            step *= 0.5 / big
        x = x + step
        if big < SOLVE_STEP_TOL_RAD:
            return x
    raise ModelError(f"joint {joint.name}: cable lengths {ld.tolist()} mm out of reach")


def joints_from_displacements(
    arm: VertebraArm, q_mm: np.ndarray, guess_x: np.ndarray | None = None
) -> np.ndarray:
    """Inverse of eq. 5: bending vectors (N, 2) from cable displacements (mm pulled in).

    Joint 1 from its own cables, then its share of every distal cable is removed and joint 2 is
    solved, and so on outwards (the coupling runs one way: distal cables pass proximal joints).
    """
    L = straight_path_mm(arm) - np.asarray(q_mm, dtype=float)
    xs = np.zeros((arm.n_joints, 2))
    used = np.zeros(arm.n_cables)
    for i, j in enumerate(arm.joints):
        own = arm.own_cables[i]
        g = None if guess_x is None else np.asarray(guess_x, dtype=float).reshape(-1, 2)[i]
        xs[i] = solve_joint(L[own] - used[own], arm.betas[own], arm.radii[own], j, g)
        distal = arm.anchor > i
        if distal.any():
            used[distal] += _joint_length_x(xs[i], arm.betas[distal], arm.radii[distal], j)[0]
    return xs


# =========================================================================== eq. 6-8
def rotation_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Eq. 6: R = Rz(yaw) Ry(pitch) Rx(roll), the attitude sensor's Z-Y-X Euler convention.

    The printed matrix of eq. 6 is this product (its text says "Z-Y-Z" for the joint model and
    "Z-Y-X" for the sensor; the matrix is Z-Y-X with alpha = yaw, beta = pitch, gamma = roll).
    R maps sensor coordinates to world coordinates (world z up).
    """
    return rot_z(yaw_rad) @ rot_y(pitch_rad) @ rot_x(roll_rad)


def world_up_in_sensor(roll_rad: float, pitch_rad: float) -> np.ndarray:
    """The world z axis in sensor coordinates, R^T e_z = third row of eq. 6:
    (-sin pitch, cos pitch sin roll, cos pitch cos roll). Independent of yaw."""
    cp = math.cos(pitch_rad)
    return np.array([-math.sin(pitch_rad), cp * math.sin(roll_rad), cp * math.cos(roll_rad)])


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _nearest_mod_pi(phi0: float, prev: float) -> float:
    """phi0 or phi0 + pi, whichever is closer (on the circle) to ``prev``; wrapped to (-pi, pi]."""
    a, b = _wrap(phi0), _wrap(phi0 + math.pi)
    return a if abs(_wrap(a - prev)) <= abs(_wrap(b - prev)) else b


def angles_from_relative_rotation(
    R_rel: np.ndarray, prev_phi: float = 0.0, tol: float = SINGULAR_TOL
) -> tuple[float, float]:
    """(theta, phi) of a joint from its relative rotation R_rel = R_{i-1}^T R_i, eq. 7-8.

    Third row (a31, a32, a33) = (-s theta c phi, -s theta s phi, c theta):
    theta = atan2(sqrt(a31^2 + a32^2), a33) in [0, pi]; phi = -atan2(a32, -a31) = atan2(-a32, -a31)
    while sqrt(a31^2 + a32^2) > ``tol``. Singular cases (eq. 7-8's 0 deg / 180 deg branches):
    theta = 0: phi is undefined, ``prev_phi`` is kept (the paper's 0 when prev_phi = 0);
    theta = pi: R = 2 k k^T - I with k = (-s phi, c phi, 0), so the xy block gives
    cos 2phi = (a22 - a11)/2, sin 2phi = -(a12 + a21)/2: phi is known modulo pi (phi and phi + pi
    are the same rotation) and the one nearest ``prev_phi`` is returned.
    """
    R = np.asarray(R_rel, dtype=float)
    a31, a32, a33 = R[2, 0], R[2, 1], R[2, 2]
    s = math.hypot(a31, a32)
    theta = math.atan2(s, a33)
    if s > tol:
        return theta, math.atan2(-a32, -a31)
    if a33 > 0.0:
        return 0.0, prev_phi
    phi0 = 0.5 * math.atan2(-(R[0, 1] + R[1, 0]), R[1, 1] - R[0, 0])
    return math.pi, _nearest_mod_pi(phi0, prev_phi)


@dataclass(frozen=True)
class JointAttitude:
    """A decoded joint: bend ``theta`` [0, pi], direction ``phi`` (rad) and ``observability``
    in [0, 1] (sine of the angle between gravity and the bend axis; 0: this bend cannot be seen
    from tilt; near 0 the decode is noise-sensitive)."""

    theta: float
    phi: float
    observability: float


def angles_from_tilts(
    up_parent: np.ndarray, up_child: np.ndarray, prev_phi: float = 0.0, tol: float = SINGULAR_TOL
) -> JointAttitude:
    """A joint's (theta, phi) from the world-up vector seen by the sensors at both of its ends.

    Yaw-free decode (the magnetometer heading is not used). b = world up in the parent frame,
    a = world up in the child frame; the joint rotation R = Rot(k, theta), k = (-s phi, c phi, 0)
    (eq. 1), maps child to parent coordinates, so R a = b. A rotation about k keeps the component
    along k, so k is perpendicular to a - b and (twist-free) to z:

        k = +-(z x (a - b)) / |.|,  theta = signed angle from a_perp to b_perp about k,

    with k's sign chosen so that theta >= 0; phi = atan2(-k_x, k_y). For joint 1, b is the base's
    up vector (e.g. (0, 0, 1) for an upright base); it generalises eq. 7-8, which is this decode
    with b = e_z: then theta = atan2(sqrt(a31^2 + a32^2), a33), phi = atan2(-a32, -a31).

    Singular cases: |a - b| <= ``tol``: theta = 0 (or a bend about an axis parallel to gravity,
    which tilt cannot see; ``observability`` says which), phi = ``prev_phi``. (a - b) parallel to
    z but not 0 (e.g. theta = pi under an upright parent): every horizontal axis fits; the one at
    ``prev_phi`` is used.
    """
    b = np.asarray(up_parent, dtype=float)
    a = np.asarray(up_child, dtype=float)
    b = b / np.linalg.norm(b)
    a = a / np.linalg.norm(a)
    e = a - b
    exy = math.hypot(e[0], e[1])
    if float(np.linalg.norm(e)) <= tol:
        # straight, or bent about a horizontal axis parallel to a: the worst case over all
        # horizontal axes k of |a - (k.a) k| is |a_z|
        return JointAttitude(0.0, prev_phi, abs(float(a[2])))
    if exy > tol:
        k = np.array([-e[1], e[0], 0.0]) / exy
    else:  # every horizontal axis fits: keep the previous direction
        k = np.array([-math.sin(prev_phi), math.cos(prev_phi), 0.0])
    a_p = a - (k @ a) * k
    b_p = b - (k @ b) * k
    obs = float(np.linalg.norm(a_p))
    theta = math.atan2(float(k @ np.cross(a_p, b_p)), float(a_p @ b_p))
    if exy <= tol:
        # k fixed at prev_phi: a negative theta is the opposite direction, except at theta = pi
        # where rotations about k and -k coincide
        if theta < 0.0 and math.pi + theta > tol:
            return JointAttitude(-theta, _wrap(prev_phi + math.pi), obs)
        return JointAttitude(abs(theta), prev_phi, obs)
    if theta < 0.0:
        k, theta = -k, -theta
    return JointAttitude(theta, math.atan2(-k[0], k[1]), obs)


def rotvec_matrix(rotvec_rad: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrix of a rotation vector (axis * angle, rad)."""
    w = np.asarray(rotvec_rad, dtype=float)
    t = float(np.linalg.norm(w))
    if t < 1e-12:
        return np.eye(3)
    k = w / t
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(t) * K + (1.0 - math.cos(t)) * (K @ K)


def decode_joint_attitudes(
    roll_rad: np.ndarray,
    pitch_rad: np.ndarray,
    base_up: np.ndarray = (0.0, 0.0, 1.0),
    mounts: list[np.ndarray] | None = None,
    prev_phi: np.ndarray | None = None,
    tol: float = SINGULAR_TOL,
) -> list[JointAttitude]:
    """Every joint's (theta, phi) from the roll and pitch of the sensor on each joint end.

    Yaw is not an input: only the world-up vector R_i^T e_z of each sensor is used
    (:func:`world_up_in_sensor`), turned into the joint-end frame by the sensor's ``mounts``
    rotation (3x3, maps sensor coordinates to joint-end coordinates; None: axes parallel as in
    the paper), then
    :func:`angles_from_tilts` per joint with the previous joint end (the base's ``base_up``, the
    world up vector in the robot base frame, for joint 1). ``prev_phi`` keeps phi continuous
    through the singular poses.
    """
    rolls = np.asarray(roll_rad, dtype=float)
    pitches = np.asarray(pitch_rad, dtype=float)
    N = rolls.size
    ups = []
    for i in range(N):
        u = world_up_in_sensor(float(rolls[i]), float(pitches[i]))
        if mounts is not None:
            u = np.asarray(mounts[i], dtype=float) @ u
        ups.append(u)
    out = []
    parent = np.asarray(base_up, dtype=float)
    for i in range(N):
        prev = 0.0 if prev_phi is None else float(prev_phi[i])
        out.append(angles_from_tilts(parent, ups[i], prev, tol))
        parent = ups[i]
    return out


def decode_from_rotations(
    R_abs: list[np.ndarray],
    R_base: np.ndarray | None = None,
    prev_phi: np.ndarray | None = None,
    tol: float = SINGULAR_TOL,
) -> np.ndarray:
    """(N, 2) joint (theta, phi) from full absolute orientations (sensor -> world, eq. 6), eq. 7-8
    on R_rel = R_{i-1}^T R_i (R_0 = ``R_base``, identity when None). Use when the headings are
    trustworthy and shared (a tracker, a simulation); otherwise :func:`decode_joint_attitudes`.
    """
    parent = np.eye(3) if R_base is None else np.asarray(R_base, dtype=float)
    out = np.zeros((len(R_abs), 2))
    for i, R in enumerate(R_abs):
        Ri = np.asarray(R, dtype=float)
        prev = 0.0 if prev_phi is None else float(prev_phi[i])
        out[i] = angles_from_relative_rotation(parent.T @ Ri, prev, tol)
        parent = Ri
    return out


# =========================================================================== end following
@dataclass(frozen=True)
class SyncStep:
    """One synchronised move of every linear module (section 2.2, eq. 9).

    ``psi_from``/``psi_to`` (N, 2) joint poses; ``delta_mm`` (C,) exact cable displacement change
    (eq. 5); ``pulses`` (C,) signed integer pulses m sent (eq. 9, rounded on the absolute
    position so rounding never accumulates); ``pulse_rate_hz`` (C,) f >= 0 (eq. 9);
    ``velocity_mm_s`` (C,) = f c / s; ``duration_s``: the same for every axis, set by the axis
    that needs longest at its own speed limit.
    """

    psi_from: np.ndarray
    psi_to: np.ndarray
    delta_mm: np.ndarray
    pulses: np.ndarray
    pulse_rate_hz: np.ndarray
    velocity_mm_s: np.ndarray
    duration_s: float


def synchronise(pulses: np.ndarray, arm: VertebraArm) -> tuple[float, np.ndarray]:
    """(duration_s, pulse_rate_hz per axis) so every axis ends together (section 2.2).

    duration = max_k |m_k| / f_max,k (the longest move at its speed limit), f_k = |m_k| / duration
    <= f_max,k for every axis. All zero: (0, zeros).
    """
    m = np.abs(np.asarray(pulses, dtype=float))
    duration = float(np.max(m / arm.max_pulse_rate_hz)) if m.size else 0.0
    if duration <= 0.0:
        return 0.0, np.zeros_like(m)
    return duration, m / duration


class FollowMode(enum.Enum):
    """IDLE: at the targets; STEER: the distal joint moves towards the joystick target;
    FOLLOW: the joints move to the poses shifted down by :meth:`EndFollowPlanner.advance`."""

    IDLE = "idle"
    STEER = "steer"
    FOLLOW = "follow"


@dataclass(frozen=True)
class FollowParams:
    """Joystick end-following parameters (section 2.2).

    ``step_rad``: the largest change of any joint's bending vector per synchronised step (the
    paper's 0.05 rad). ``theta_increment_rad``/``phi_increment_rad``: change of the distal target
    per :meth:`EndFollowPlanner.steer` call at full stick deflection. ``theta_max_rad``: bend limit.
    """

    step_rad: float = FOLLOW_STEP_RAD
    theta_increment_rad: float = 0.02
    phi_increment_rad: float = 0.05
    theta_max_rad: float = math.pi / 2

    def __post_init__(self) -> None:
        if not (
            self.step_rad > 0
            and self.theta_increment_rad >= 0
            and self.phi_increment_rad >= 0
            and 0 < self.theta_max_rad <= math.pi
        ):
            raise ModelError("follow parameters: step > 0, increments >= 0, 0 < theta_max <= pi")


@dataclass
class EndFollowPlanner:
    """Joystick end-following (section 2.2) as a pure state machine: no clocks, no I/O.

    Only the distal joint is steered (:meth:`steer`: increments of its (theta, phi) from the
    normalised stick axes). "Follow" (:meth:`advance`, the paper's forward button, Fig. 12): every
    proximal joint takes the pose its distal neighbour has now, target_i = psi_{i+1} for
    i < N-1, the distal joint keeps its pose, so the shape the tip has been steered into moves
    one joint towards the base, as when a snake advances. Moves are cut into synchronised steps
    (:meth:`next_step`): K = ceil(max_i |x_target,i - x_i| / step_rad) steps in which every joint's
    bending vector moves by 1/K of its remaining way (straight lines in x, all joints arriving
    together, none moving more than ``step_rad`` per step); each step's cable changes (eq. 5) are
    sent as pulses (eq. 9) with the rates of :func:`synchronise`. The caller runs a step for its
    ``duration_s`` and then asks for the next; while FOLLOW runs, the stick is ignored.
    """

    arm: VertebraArm
    params: FollowParams = field(default_factory=FollowParams)
    psi: np.ndarray | None = None
    target: np.ndarray = field(init=False)
    position_pulses: np.ndarray = field(init=False)
    mode: FollowMode = field(init=False, default=FollowMode.IDLE)

    def __post_init__(self) -> None:
        N = self.arm.n_joints
        self.psi = np.zeros((N, 2)) if self.psi is None else _psi_array(self.psi, N).copy()
        if np.any(self.psi[:, 0] < 0) or np.any(self.psi[:, 0] > self.params.theta_max_rad):
            raise ModelError("initial bends must be in [0, theta_max]")
        self.target = self.psi.copy()
        self.position_pulses = np.rint(
            cable_displacements(self.arm, self.psi) * self.arm.pulses_per_mm
        ).astype(np.int64)

    def steer(self, axis_x: float, axis_y: float) -> bool:
        """Move the distal target: theta += axis_y * theta_increment (clamped to [0, theta_max]),
        phi += axis_x * phi_increment; axes in [-1, 1] (clipped). Returns False (ignored) while a
        follow move runs."""
        if self.mode is FollowMode.FOLLOW:
            return False
        jx = float(np.clip(axis_x, -1.0, 1.0))
        jy = float(np.clip(axis_y, -1.0, 1.0))
        t = self.target[-1]
        theta = float(
            np.clip(t[0] + jy * self.params.theta_increment_rad, 0.0, self.params.theta_max_rad)
        )
        phi = _wrap(float(t[1]) + jx * self.params.phi_increment_rad)
        self.target[-1] = (theta, phi)
        self.mode = FollowMode.STEER
        return True

    def set_distal_target(self, theta: float, phi: float) -> bool:
        """Set the distal target directly (clamped); False while a follow move runs."""
        if self.mode is FollowMode.FOLLOW:
            return False
        self.target[-1] = (float(np.clip(theta, 0.0, self.params.theta_max_rad)), _wrap(phi))
        self.mode = FollowMode.STEER
        return True

    def advance(self) -> bool:
        """Start a follow move: target_i = psi_{i+1} (current poses) for the proximal joints, the
        distal joint's target = its current pose. False if a follow move is already running."""
        if self.mode is FollowMode.FOLLOW:
            return False
        assert self.psi is not None
        self.target[:-1] = self.psi[1:]
        self.target[-1] = self.psi[-1]
        self.mode = FollowMode.FOLLOW
        return True

    def next_step(self) -> SyncStep | None:
        """The next synchronised step towards the targets, or None (mode -> IDLE) when there."""
        assert self.psi is not None
        x = x_from_psi(self.psi)
        xt = x_from_psi(self.target)
        rem = xt - x
        dist = float(np.max(np.hypot(rem[:, 0], rem[:, 1])))
        if dist <= 1e-12:
            self.psi = self.target.copy()
            self.mode = FollowMode.IDLE
            return None
        K = max(1, math.ceil(dist / self.params.step_rad - 1e-9))
        x_new = xt if K == 1 else x + rem / K
        psi_new = psi_from_xs(x_new, self.target[:, 1])
        if K == 1:
            psi_new = self.target.copy()
        q_old = cable_displacements(self.arm, self.psi)
        q_new = cable_displacements(self.arm, psi_new)
        pos_new = np.rint(q_new * self.arm.pulses_per_mm).astype(np.int64)
        pulses = pos_new - self.position_pulses
        duration, rate = synchronise(pulses, self.arm)
        step = SyncStep(
            psi_from=self.psi.copy(),
            psi_to=psi_new.copy(),
            delta_mm=q_new - q_old,
            pulses=pulses,
            pulse_rate_hz=rate,
            velocity_mm_s=rate / self.arm.pulses_per_mm,
            duration_s=duration,
        )
        self.psi = psi_new
        self.position_pulses = pos_new
        return step

    def run(self, max_steps: int = 10_000) -> list[SyncStep]:
        """All remaining steps (for tests and offline planning)."""
        steps: list[SyncStep] = []
        for _ in range(max_steps):
            s = self.next_step()
            if s is None:
                return steps
            steps.append(s)
        raise ModelError(f"end-following did not finish in {max_steps} steps")


# =========================================================================== truth
def _potential_batch(arm: VertebraArm, xs: np.ndarray) -> np.ndarray:
    """Gravity potential (B,) of B poses given as bending vectors (B, N, 2), the chain of
    :func:`mass_points` with batched 4x4 products."""
    X = np.asarray(xs, dtype=float)
    B = X.shape[0]
    g = np.asarray(arm.gravity_mm_s2, dtype=float)
    T = np.broadcast_to(np.eye(4), (B, 4, 4)).copy()
    V = np.zeros(B)
    for i, j in enumerate(arm.joints):
        theta = np.hypot(X[:, i, 0], X[:, i, 1])
        phi = np.arctan2(X[:, i, 1], X[:, i, 0])
        t = theta / j.n_gaps
        ct, st, cp, sp = np.cos(t), np.sin(t), np.cos(phi), np.sin(phi)
        U = np.zeros((B, 4, 4))
        U[:, 0, 0], U[:, 0, 1], U[:, 0, 2] = ct * cp * cp + sp * sp, cp * sp * (ct - 1.0), st * cp
        U[:, 1, 0], U[:, 1, 1], U[:, 1, 2] = cp * sp * (ct - 1.0), cp * cp + sp * sp * ct, st * sp
        U[:, 2, 0], U[:, 2, 1], U[:, 2, 2] = -st * cp, -st * sp, ct
        U[:, 3, 3] = 1.0
        a = 0.5 * j.gap_mm
        U[:, :3, 3] = (a + j.hole_length_mm) * U[:, :3, 2]
        U[:, 2, 3] += a
        for _ in range(j.n_gaps):
            T = T @ U
            if j.disk_mass_g > 0:
                p = T[:, :3, 3] - 0.5 * j.hole_length_mm * T[:, :3, 2]
                V -= j.disk_mass_g * 1e-6 * (p @ g)
    if arm.tip_mass_g > 0:
        V -= arm.tip_mass_g * 1e-6 * (T[:, :3, 3] @ g)
    return V


def gravity_potential_Nmm(arm: VertebraArm, psi: np.ndarray) -> float:
    """V = -sum m g . p of the disks and the tip mass (N*mm; g * 1e-3 -> kg, mm/s^2 * 1e-3)."""
    return float(_potential_batch(arm, x_from_psi(_psi_array(psi, arm.n_joints))[None])[0])


def _has_gravity(arm: VertebraArm) -> bool:
    return bool(np.any(np.asarray(arm.gravity_mm_s2) != 0.0))


def gravity_torque_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """Q = -dV/dx (2N,), N*mm per rad of bending vector, by central differences."""
    xs = np.asarray(x, dtype=float).ravel()
    n = xs.size
    if not _has_gravity(arm):
        return np.zeros(n)
    E = np.eye(n) * GRAVITY_FD_STEP_RAD
    V = _potential_batch(arm, np.concatenate((xs + E, xs - E)).reshape(2 * n, -1, 2))
    return -(V[:n] - V[n:]) / (2.0 * GRAVITY_FD_STEP_RAD)


def gravity_hessian_x(arm: VertebraArm, x: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """d^2 V / dx^2 (2N x 2N, N*mm/rad^2), four-point stencil."""
    xs = np.asarray(x, dtype=float).ravel()
    n = xs.size
    pairs = [(j, k) for j in range(n) for k in range(j, n)]
    Y = []
    for j, k in pairs:
        for sj, sk in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            y = xs.copy()
            y[j] += sj * h
            y[k] += sk * h
            Y.append(y)
    V = _potential_batch(arm, np.array(Y).reshape(len(Y), -1, 2))
    H = np.zeros((n, n))
    for p, (j, k) in enumerate(pairs):
        v = V[4 * p : 4 * p + 4]
        H[j, k] = H[k, j] = (v[0] - v[1] - v[2] + v[3]) / (4.0 * h * h)
    return H


def statics_x(arm: VertebraArm, x_kin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Small-deflection equilibrium (bending vectors (N, 2), cable tensions (C,)).

    At the kinematic pose x_kin (from the cable displacements) every cable is at its pretension;
    the rod wants x = 0 with stiffness EI / L_joint per joint; gravity loads the disks. With
    J = :func:`cable_jacobian_x`, k = EA / L_total, K_g = sum T0 d^2 L / dx^2 (the pretension's
    geometric stiffness, negative: it compresses the rod like a column), stationarity of
    sum [T0 L + k/2 (L - L(x_kin))^2] + sum EI/(2 L_i) |x_i|^2 + V_gravity gives

        (J^T k J + K_g + K_rod) dx = Q(x_kin + dx) - J^T T0 - K_rod x_kin

    with the cable lengths linearised at x_kin and the gravity moment Q at the sagged pose
    (quasi-Newton with :func:`gravity_hessian_x`). Cables whose tension would go negative go slack
    (active set) - the paper's "cables not taut" error. Raises :class:`ModelError` when there is
    no stable equilibrium.
    """
    x0 = np.asarray(x_kin, dtype=float).ravel()
    n = x0.size
    J = cable_jacobian_x(arm, x0)
    k = np.array([c.stiffness_N_per_mm for c in arm.cables])
    T0 = np.array([c.pretension_N for c in arm.cables])
    L_hess = np.zeros((arm.n_cables, n, n))  # d^2 L_k / dx^2 per cable
    for j in range(n):
        xp, xm = x0.copy(), x0.copy()
        xp[j] += FD_STEP_RAD
        xm[j] -= FD_STEP_RAD
        L_hess[:, :, j] = (cable_jacobian_x(arm, xp) - cable_jacobian_x(arm, xm)) / (
            2 * FD_STEP_RAD
        )
    L_hess = 0.5 * (L_hess + L_hess.transpose(0, 2, 1))
    K_rod = np.diag(np.repeat([j.rod_EI_Nmm2 / j.length_mm for j in arm.joints], 2))
    H = gravity_hessian_x(arm, x0) if _has_gravity(arm) else np.zeros((n, n))
    active = np.ones(T0.shape, dtype=bool)  # every cable taut (a zero pretension too)
    dx = np.zeros(n)
    for _ in range(STATICS_MAX_ITER):
        Ja = J[active]
        Kg = np.tensordot(T0[active], L_hess[active], axes=1)  # slack cables drop out
        K = Ja.T @ (k[active, None] * Ja) + Kg + K_rod
        A = K + H
        if np.linalg.eigvalsh(0.5 * (A + A.T)).min() <= 0.0:
            raise ModelError(
                "statics: no stable equilibrium (slack cables, or pretension or "
                "gravity buckling the rod)"
            )
        F = K @ dx + Ja.T @ T0[active] + K_rod @ x0 - gravity_torque_x(arm, x0 + dx)
        dx_new = dx - np.linalg.solve(A, F)
        new_active = (T0 + k * (J @ dx_new)) >= 0.0
        change = float(np.max(np.abs(dx_new - dx)))
        dx = dx_new
        if np.array_equal(new_active, active) and change < STATICS_TOL_RAD:
            break
        active = new_active
    else:
        raise ModelError("statics did not converge")
    tension = np.where(active, T0 + k * (J @ dx), 0.0)
    return (x0 + dx).reshape(-1, 2), tension


def truth_pose(
    arm: VertebraArm,
    q_mm: np.ndarray,
    statics: bool = True,
    guess_x: np.ndarray | None = None,
    phi_if_straight: np.ndarray | None = None,
) -> np.ndarray:
    """The simulator's truth: joint poses (N, 2) rows (theta, phi) for cable displacements
    ``q_mm`` (mm pulled in, cable order): kinematics (inverse of eq. 5, proximal first), then
    with ``statics`` the rod, cable elasticity, pretension, slack and gravity sag of
    :func:`statics_x`. ``guess_x`` warm-starts the solver (the last bending vectors)."""
    q = np.asarray(q_mm, dtype=float)
    if q.shape != (arm.n_cables,):
        raise ModelError(f"need {arm.n_cables} cable displacements, got shape {q.shape}")
    x = joints_from_displacements(arm, q, guess_x)
    if statics:
        x = statics_x(arm, x)[0]
    return psi_from_xs(x, phi_if_straight)


def statics_inverse_x(arm: VertebraArm, x_target: np.ndarray) -> np.ndarray:
    """x_kin such that :func:`statics_x` (x_kin) = ``x_target`` (fixed point; compensation of the
    sag: command the cables of x_kin to end at x_target)."""
    target = np.asarray(x_target, dtype=float).reshape(-1, 2)
    pre = target.copy()
    for _ in range(STATICS_MAX_ITER):
        err = target - statics_x(arm, pre)[0]
        pre = pre + err
        if float(np.max(np.abs(err))) < STATICS_TOL_RAD:
            return pre
    raise ModelError("statics inverse did not converge (sag too large for small deflection)")


def statics_inverse_step(arm: VertebraArm, x_target: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """One fixed-point step of :func:`statics_inverse_x` from ``guess`` (the control loop's warm
    start: its error is |d sag / d x| times the change of the sag offset since the last tick)."""
    target = np.asarray(x_target, dtype=float).reshape(-1, 2)
    pre = np.asarray(guess, dtype=float).reshape(-1, 2)
    return pre + (target - statics_x(arm, pre)[0])


# =========================================================================== loop adapter
#: Default integral gain of the attitude loop (1/s): bending-vector correction per second per
#: rad of error. Sensor at 100 Hz with ~10-30 ms delay: 5/s keeps > 60 deg of phase margin.
ATTITUDE_GAIN_PER_S = 5.0
#: Largest attitude correction of one joint's bending vector (rad): a wrong sensor cannot drive
#: the arm far (anti-windup).
ATTITUDE_MAX_CORRECTION_RAD = 0.3
#: A joint whose decode observability is below this is not corrected (gravity nearly along its
#: bend axis: the tilt does not show the bend).
ATTITUDE_MIN_OBSERVABILITY = 0.2
#: The error the integral sees is saturated at this (rad per joint): the correction then moves
#: at most gain * this rad/s (5/s * 0.02 = 0.1 rad/s, ~1.5 mm/s of cable at r = 15 mm), so a
#: decode jump or a large transient error cannot push the cables past their speed limit.
ATTITUDE_MAX_ERROR_RAD = 0.02


@dataclass(frozen=True)
class AttitudeLoopParams:
    """The joint-space closed loop on the attitude sensors (mode ``measured``).

    ``gain_per_tick``: integral gain per control cycle (gain per s times the period);
    ``max_correction_rad``, ``min_observability``, ``max_error_rad``: see the constants;
    ``stale_after_s``: older readings are not used (the correction is held); ``base_up``,
    ``mounts``, ``singular_tol``: :func:`decode_joint_attitudes`.
    """

    gain_per_tick: float = ATTITUDE_GAIN_PER_S / 100.0
    max_correction_rad: float = ATTITUDE_MAX_CORRECTION_RAD
    min_observability: float = ATTITUDE_MIN_OBSERVABILITY
    max_error_rad: float = ATTITUDE_MAX_ERROR_RAD
    stale_after_s: float = 0.1
    base_up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    mounts: tuple[np.ndarray, ...] | None = None
    singular_tol: float = SINGULAR_TOL

    def __post_init__(self) -> None:
        if not (0.0 < self.gain_per_tick <= 1.0 and self.max_correction_rad > 0):
            raise ModelError("attitude loop: 0 < gain_per_tick <= 1 and max_correction_rad > 0")


@dataclass
class VertebraLoopState:
    """Memory of :class:`VertebraModel` between cycles: the statics offset (warm start, x_kin -
    x_target), the attitude loop's integral correction (N, 2 bending vectors), the last decoded
    directions (continuity through singular poses) and the last measured joint poses."""

    sag_offset: np.ndarray | None = None
    correction: np.ndarray | None = None
    prev_phi: np.ndarray | None = None
    measured_psi: np.ndarray | None = None
    updates: int = 0


class VertebraModel:
    """The vertebra design as the control loop's ``RobotModelPort``: psi rows (theta, phi) per
    joint (rad); mm pulled in, cable order.

    Modes: ``off`` the paper's kinematic control (eq. 5); ``model`` adds the statics sag
    compensation (:func:`statics_inverse_x`, warm-started: one statics evaluation per cycle);
    ``measured`` closes a joint-space loop on the attitude sensors: each cycle the joints' poses
    are decoded from the sensors (eq. 6-8, :func:`decode_joint_attitudes`) and the commanded
    bending vectors are corrected by an integral of their error,

        c <- clip(c + g (x_cmd - x_measured)),   q = eq. 5 (x_cmd + c),

    per joint while its reading is fresh and observable (else c is held). The sensors reach the
    model through :meth:`attach_attitude` (an :class:`~cdcr_ctl.control.ports.AttitudePort`:
    latest roll, pitch and age per joint, never blocking); without one, ``measured`` raises.
    """

    def __init__(self, arm: VertebraArm, attitude_loop: AttitudeLoopParams | None = None) -> None:
        self.arm = arm
        self.n_segments = arm.n_joints
        self.n_cables = arm.n_cables
        self.attitude_loop = attitude_loop or AttitudeLoopParams()
        self.attitude: object | None = None

    def attach_attitude(self, port: object | None) -> None:
        """Use ``port`` (``latest() -> (roll_rad (N,), pitch_rad (N,), age_s (N,))``) in mode
        ``measured``; None detaches."""
        self.attitude = port

    def new_state(self) -> VertebraLoopState:
        return VertebraLoopState()

    def q_nominal(self, psi: np.ndarray) -> np.ndarray:
        return cable_displacements(self.arm, psi)

    def measure(self, state: VertebraLoopState) -> tuple[np.ndarray, np.ndarray] | None:
        """Decode the attached sensors: (psi (N, 2), usable (N,) bool), or None without sensors.

        A joint is usable when its sensor and its parent's are fresh and its observability is
        at least ``min_observability``.
        """
        if self.attitude is None:
            return None
        p = self.attitude_loop
        roll, pitch, age = (np.asarray(v, dtype=float) for v in self.attitude.latest())  # type: ignore[attr-defined]
        N = self.arm.n_joints
        if roll.shape != (N,) or pitch.shape != (N,):
            raise ModelError(f"attitude port gave {roll.shape} readings for {N} joints")
        fresh = np.isfinite(roll) & np.isfinite(pitch) & (np.asarray(age) <= p.stale_after_s)
        if not fresh.any():
            return np.zeros((N, 2)), np.zeros(N, dtype=bool)
        dec = decode_joint_attitudes(
            np.where(fresh, roll, 0.0),
            np.where(fresh, pitch, 0.0),
            np.asarray(p.base_up),
            None if p.mounts is None else list(p.mounts),
            state.prev_phi,
            p.singular_tol,
        )
        psi = np.array([[d.theta, d.phi] for d in dec])
        parent_fresh = np.concatenate(([True], fresh[:-1]))
        obs = np.array([d.observability for d in dec])
        usable = fresh & parent_fresh & (obs >= p.min_observability)
        state.prev_phi = psi[:, 1].copy()
        state.measured_psi = psi
        return psi, usable

    def q_command(
        self,
        psi: np.ndarray,
        q_nominal: np.ndarray,
        state: object,
        mode: str,
        measured_N: np.ndarray | None,
    ) -> np.ndarray:
        if not isinstance(state, VertebraLoopState):
            raise ModelError("q_command needs the state made by new_state()")
        if mode == "off":
            return np.asarray(q_nominal, dtype=float)
        p_cmd = _psi_array(psi, self.arm.n_joints)
        x_cmd = x_from_psi(p_cmd)
        if mode == "model":
            guess = x_cmd if state.sag_offset is None else x_cmd + state.sag_offset
            x_kin = statics_inverse_step(self.arm, x_cmd, guess)
            state.sag_offset = x_kin - x_cmd
            return np.asarray(q_nominal, dtype=float) + (
                cable_displacements(self.arm, psi_from_xs(x_kin, p_cmd[:, 1]))
                - cable_displacements(self.arm, p_cmd)
            )
        if mode != "measured":
            raise ModelError(
                f"the vertebra model compensates in mode off, model or measured, not {mode!r}"
            )
        got = self.measure(state)
        if got is None:
            raise ModelError("mode measured needs the attitude sensors (none attached)")
        psi_meas, usable = got
        c = np.zeros_like(x_cmd) if state.correction is None else state.correction
        err = x_cmd - x_from_psi(psi_meas)
        p = self.attitude_loop
        e_norm = np.hypot(err[:, 0], err[:, 1])
        err = err * np.minimum(1.0, p.max_error_rad / np.maximum(e_norm, 1e-300))[:, None]
        c = c + np.where(usable[:, None], p.gain_per_tick * err, 0.0)
        norm = np.hypot(c[:, 0], c[:, 1])
        c = c * np.minimum(1.0, p.max_correction_rad / np.maximum(norm, 1e-300))[:, None]
        state.correction = c
        state.updates += int(usable.any())
        return np.asarray(q_nominal, dtype=float) + (
            cable_displacements(self.arm, psi_from_xs(x_cmd + c, p_cmd[:, 1]))
            - cable_displacements(self.arm, p_cmd)
        )

    def tip(self, psi: np.ndarray) -> np.ndarray:
        return tip_position(self.arm, psi)
