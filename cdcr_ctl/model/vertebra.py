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
from functools import cached_property, lru_cache

import numpy as np

from cdcr_ctl.errors import ModelError

#: Below this |u| the ratios sin(u)/u etc. use their Taylor series.
SERIES_BELOW = 0.05
#: Below this |u| :func:`d2` uses its series (its closed form loses ~1e-16/u^5 to cancellation).
D2_SERIES_BELOW = 0.3
#: Gauss-Newton (cable lengths -> joint) stops when the step is below this (rad).
SOLVE_STEP_TOL_RAD = 1e-13
SOLVE_MAX_ITER = 60
#: Attitude decode: sin(theta) (or a tilt difference) below this counts as singular.
SINGULAR_TOL = 1e-9
#: Iterations of the statics and of its inverse, and their tolerance (rad), which sits above the
#: round-off of the finite-difference gravity moment.
STATICS_MAX_ITER = 60
#: Central-difference step of the gravity moment (rad): large enough that the round-off of the
#: potential (~1e-16 V / h) stays below the statics tolerance, small enough for O(h^2) accuracy.
GRAVITY_FD_STEP_RAD = 1e-4
STATICS_TOL_RAD = 1e-10
#: Statics steps below this (rad) keep the last gravity Hessian (quasi-Newton): the linear rate
#: |dH| / |A| is then ~1e-3 or better, and a gravity moment alone costs half a Hessian batch.
STATICS_NEWTON_BELOW_RAD = 1e-3
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

    @cached_property
    def cable_stiffness(self) -> np.ndarray:
        """EA / L_total per cable (N/mm)."""
        return np.array([c.stiffness_N_per_mm for c in self.cables])

    @cached_property
    def pretensions(self) -> np.ndarray:
        return np.array([c.pretension_N for c in self.cables])

    @cached_property
    def rod_stiffness(self) -> np.ndarray:
        """K_rod (2N x 2N): EI / L_joint per joint on both bending-vector components
        (N*mm/rad)."""
        return np.diag(np.repeat([j.rod_EI_Nmm2 / j.length_mm for j in self.joints], 2))

    @cached_property
    def through(self) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
        """Per joint i: (indices of the cables through it (anchor >= i), their hole directions
        e = (cos beta, sin beta) (K, 2), their hole radii r (K,) mm)."""
        out = []
        for i in range(self.n_joints):
            idx = np.nonzero(self.anchor >= i)[0]
            b = self.betas[idx]
            out.append((idx, np.column_stack((np.cos(b), np.sin(b))), self.radii[idx]))
        return tuple(out)

    @cached_property
    def potential_constants(self) -> tuple[np.ndarray, ...]:
        """Per joint, for :func:`_potential_batch`: n, l0/2, l0/2 + H, the disk centre's z below
        the top face -H/2 (mm), disk mass (g), and the rotation-sum weights (N, n_max + 1, 3)
        (zero beyond a joint's own n)."""
        n = np.array([j.n_gaps for j in self.joints], dtype=float)
        half = np.array([0.5 * j.gap_mm for j in self.joints])
        ell = half + np.array([j.hole_length_mm for j in self.joints])
        zc = np.array([-0.5 * j.hole_length_mm for j in self.joints])
        mass = np.array([j.disk_mass_g for j in self.joints])
        n_max = max(j.n_gaps for j in self.joints)
        W = np.zeros((self.n_joints, n_max + 1, 3))
        for i, j in enumerate(self.joints):
            W[i, : j.n_gaps + 1] = _unit_sum_weights(j.n_gaps)
        return n, half, ell, zc, mass, W

    @cached_property
    def straight_path(self) -> np.ndarray:
        """Per cable, its path length at the straight pose (mm), :func:`straight_path_mm`."""
        lengths = np.array([j.length_mm for j in self.joints])
        return np.array([lengths[: c.joint + 1].sum() for c in self.cables])


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


def d2(u: float) -> float:
    """d1'(u)/u = (3 sin u - 3 u cos u - u^2 sin u)/u^5 (-> 1/15). Its closed form cancels to
    O(u^5), so the series (next term 1.9e-8 u^8) is used up to :data:`D2_SERIES_BELOW`."""
    if abs(u) < D2_SERIES_BELOW:
        u2 = u * u
        return 1.0 / 15.0 - u2 / 210.0 + u2 * u2 / 7560.0 - u2**3 / 498960.0
    return (3.0 * math.sin(u) - 3.0 * u * math.cos(u) - u * u * math.sin(u)) / u**5


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
    as n grows (:func:`arc_transform`). In closed form (the product of the n units of
    :func:`_unit_transform`): with a = theta/n, k = (-sin phi, cos phi, 0) and a unit's
    translation t = (l0/2) e_z + (l0/2 + H) Rot(k, a) e_z (in the bending plane, k . t = 0), the
    end is sum_{l<n} Rot(k, l a) t = C t + S (k x t), C = sum_{l<n} cos(l a),
    S = sum_{l<n} sin(l a) (see :func:`_potential_batch`).
    """
    n = joint.n_gaps
    a = theta / n
    cp, sp = math.cos(phi), math.sin(phi)
    half = 0.5 * joint.gap_mm
    arm_mm = half + joint.hole_length_mm
    sa = math.sin(a)
    t0, t1, t2 = arm_mm * sa * cp, arm_mm * sa * sp, arm_mm * math.cos(a) + half
    C = S = 0.0
    for m in range(n):
        C += math.cos(m * a)
        S += math.sin(m * a)
    T = np.eye(4)
    T[:3, :3] = joint_rotation(theta, phi)
    # k x t = (cp t2, sp t2, -cp t0 - sp t1)
    T[:3, 3] = (C * t0 + S * cp * t2, C * t1 + S * sp * t2, C * t2 - S * (cp * t0 + sp * t1))
    return T


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
    return arm.straight_path.copy()


def cable_displacements(arm: VertebraArm, psi: np.ndarray) -> np.ndarray:
    """Eq. 5: each cable's total shortening, the sum of eq. 4 over the joints it passes (mm pulled
    in). A distal joint's cables change with every proximal joint's pose (the coupling)."""
    return arm.straight_path - cable_path_lengths(arm, psi)


def cable_jacobian_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """d(path length)/d(bending vectors) (C x 2N, mm/rad), columns (x_1, y_1, x_2, ...)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    J = np.zeros((arm.n_cables, 2 * arm.n_joints))
    for i, j in enumerate(arm.joints):
        through = np.nonzero(arm.anchor >= i)[0]
        _, dL = _joint_length_x(xs[i], arm.betas[through], arm.radii[through], j)
        J[np.ix_(through, [2 * i, 2 * i + 1])] = dL
    return J


def _joint_length_hess_x(
    x: np.ndarray, beta: np.ndarray, r: np.ndarray, joint: VertebraJoint
) -> np.ndarray:
    """d^2 L / dx^2 (K, 2, 2) of eq. 3 in the bending vector (mm/rad^2), the derivative of
    :func:`_joint_length_x`'s dL/dx. With ds1/dx = d1(u) x / 4n^2 and dd1/dx = d2(u) x / 4n^2:

        -(l0/4n) s1 I - (l0 d1/16n^3) x x^T - (r d1 x_beta/4n^2) I
        - (r d1/4n^2) (x e^T + e x^T) - (r x_beta d2/16n^4) x x^T,   e = (cos beta, sin beta).
    """
    n = joint.n_gaps
    xv = np.asarray(x, dtype=float)
    theta = math.hypot(float(xv[0]), float(xv[1]))
    u = theta / (2.0 * n)
    su, du, ddu = s1(u), d1(u), d2(u)
    e = np.column_stack((np.cos(beta), np.sin(beta)))
    xb = e @ xv
    r = np.asarray(r, dtype=float)
    xx = np.outer(xv, xv)
    eye = np.eye(2)
    l0 = joint.gap_mm
    common = -(l0 / (4.0 * n)) * su * eye - (l0 * du / (16.0 * n**3)) * xx
    xe = xv[None, :, None] * e[:, None, :]  # x e^T per cable
    return (
        common[None]
        - (r * du * xb / (4.0 * n * n))[:, None, None] * eye[None]
        - (r * du / (4.0 * n * n))[:, None, None] * (xe + xe.transpose(0, 2, 1))
        - (r * xb * ddu / (16.0 * n**4))[:, None, None] * xx[None]
    )


def cable_hessian_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """d^2(path length)/d(bending vectors)^2 (C, 2N, 2N, mm/rad^2), analytic
    (:func:`_joint_length_hess_x`); block diagonal per joint (a joint's share of a cable's length
    depends on that joint's bending vector only)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    Hs = np.zeros((arm.n_cables, 2 * arm.n_joints, 2 * arm.n_joints))
    for i, j in enumerate(arm.joints):
        through = np.nonzero(arm.anchor >= i)[0]
        Hs[through, 2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = _joint_length_hess_x(
            xs[i], arm.betas[through], arm.radii[through], j
        )
    return Hs


def _cable_jacobian_and_hessian(arm: VertebraArm, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`cable_jacobian_x`, :func:`cable_hessian_x`) at ``x`` in one pass over the joints
    (the formulas of :func:`_joint_length_x` and :func:`_joint_length_hess_x`, entry by entry)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    n2 = 2 * arm.n_joints
    J = np.zeros((arm.n_cables, n2))
    Hs = np.zeros((arm.n_cables, n2, n2))
    for i, j in enumerate(arm.joints):
        idx, e, r = arm.through[i]
        n = j.n_gaps
        x0, x1 = float(xs[i, 0]), float(xs[i, 1])
        u = math.hypot(x0, x1) / (2.0 * n)
        su, du, ddu = s1(u), d1(u), d2(u)
        e0, e1 = e[:, 0], e[:, 1]
        xb = e0 * x0 + e1 * x1
        g = -(j.gap_mm / (4.0 * n)) * su
        a = r * du * xb / (4.0 * n * n)
        rs = r * su
        J[idx, 2 * i] = (g - a) * x0 - rs * e0
        J[idx, 2 * i + 1] = (g - a) * x1 - rs * e1
        # g I - (l0 d1/16n^3) x x^T - a I - b (x e^T + e x^T) - c x x^T
        b = r * du / (4.0 * n * n)
        cxx = (j.gap_mm * du / (16.0 * n**3)) + r * xb * ddu / (16.0 * n**4)
        diag = g - a
        Hs[idx, 2 * i, 2 * i] = diag - 2.0 * b * x0 * e0 - cxx * x0 * x0
        Hs[idx, 2 * i + 1, 2 * i + 1] = diag - 2.0 * b * x1 * e1 - cxx * x1 * x1
        off = -b * (x0 * e1 + x1 * e0) - cxx * x0 * x1
        Hs[idx, 2 * i, 2 * i + 1] = off
        Hs[idx, 2 * i + 1, 2 * i] = off
    return J, Hs


def _path_lengths_x(arm: VertebraArm, x: np.ndarray) -> np.ndarray:
    """Per cable, its path length (mm) at the bending vectors ``x`` (eq. 3 summed as in eq. 5,
    the L of :func:`_joint_length_x`)."""
    xs = np.asarray(x, dtype=float).reshape(arm.n_joints, 2)
    L = np.zeros(arm.n_cables)
    for i, j in enumerate(arm.joints):
        idx, e, r = arm.through[i]
        x0, x1 = float(xs[i, 0]), float(xs[i, 1])
        n = j.n_gaps
        u = math.hypot(x0, x1) / (2.0 * n)
        L[idx] += (
            n * j.hole_length_mm
            + n * j.gap_mm * math.cos(u)
            - r * s1(u) * (e[:, 0] * x0 + e[:, 1] * x1)
        )
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
    """Bending vector of one joint from its cables' lengths through it (Gauss-Newton on eq. 3,
    the L and dL/dx of :func:`_joint_length_x`, in scalar arithmetic: a joint has a handful of
    cables).

    Least squares (2x2 normal equations) when the lengths are inconsistent. Raises
    :class:`ModelError` when it does not converge (lengths out of reach) or the cables cannot
    fix the bend (all collinear with the centre).
    """
    ld = [float(v) for v in np.asarray(lengths_mm, dtype=float)]
    cables = [
        (math.cos(float(b)), math.sin(float(b)), float(rr), li)
        for b, rr, li in zip(
            np.asarray(beta, dtype=float), np.asarray(r, dtype=float), ld, strict=True
        )
    ]
    n = joint.n_gaps
    base = n * joint.hole_length_mm
    l0 = joint.gap_mm
    x0, x1 = (0.0, 0.0) if guess is None else (float(guess[0]), float(guess[1]))
    for _ in range(SOLVE_MAX_ITER):
        u = math.hypot(x0, x1) / (2.0 * n)
        su, du = s1(u), d1(u)
        common = base + n * l0 * math.cos(u)
        ga = -(l0 / (4.0 * n)) * su
        # normal equations: (dL^T dL) step = dL^T (ld - L)
        a00 = a01 = a11 = b0 = b1 = 0.0
        for ec, es, rr, li in cables:
            xb = ec * x0 + es * x1
            res = li - (common - rr * su * xb)
            f = ga - rr * du * xb / (4.0 * n * n)
            j0 = f * x0 - rr * su * ec
            j1 = f * x1 - rr * su * es
            a00 += j0 * j0
            a01 += j0 * j1
            a11 += j1 * j1
            b0 += j0 * res
            b1 += j1 * res
        det = a00 * a11 - a01 * a01
        if not det > 1e-12 * (a00 * a11 + 1e-300):
            raise ModelError(f"joint {joint.name}: its cables do not fix the bend here")
        s0 = (a11 * b0 - a01 * b1) / det
        s1_ = (a00 * b1 - a01 * b0) / det
        big = max(abs(s0), abs(s1_))
        if big > 0.5:
            s0, s1_ = s0 * 0.5 / big, s1_ * 0.5 / big
        x0, x1 = x0 + s0, x1 + s1_
        if big < SOLVE_STEP_TOL_RAD:
            return np.array([x0, x1])
    raise ModelError(f"joint {joint.name}: cable lengths {ld} mm out of reach")


def joints_from_displacements(
    arm: VertebraArm, q_mm: np.ndarray, guess_x: np.ndarray | None = None
) -> np.ndarray:
    """Inverse of eq. 5: bending vectors (N, 2) from cable displacements (mm pulled in).

    Joint 1 from its own cables, then its share of every distal cable is removed and joint 2 is
    solved, and so on outwards (the coupling runs one way: distal cables pass proximal joints).
    """
    L = arm.straight_path - np.asarray(q_mm, dtype=float)
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

    def set_targets(self, psi: np.ndarray) -> bool:
        """Move every joint to ``psi`` (N, 2) (bends clamped to [0, theta_max]), e.g. back to
        straight; False (ignored) while a follow move runs."""
        if self.mode is FollowMode.FOLLOW:
            return False
        p = _psi_array(psi, self.arm.n_joints).copy()
        p[:, 0] = np.clip(p[:, 0], 0.0, self.params.theta_max_rad)
        self.target = p
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
@lru_cache(maxsize=8)
def _unit_sum_weights(n: int) -> np.ndarray:
    """(n + 1, 3) weights over m = 0..n of the three rotation sums of :func:`_potential_batch`:
    n - m for m < n (the disk centres' translations), 1 for 1 <= m <= n (their offsets), 1 for
    m < n (the joint's end)."""
    W = np.zeros((n + 1, 3))
    W[:n, 0] = np.arange(n, 0, -1)
    W[1:, 1] = 1.0
    W[:n, 2] = 1.0
    return W


def _potential_batch(arm: VertebraArm, xs: np.ndarray) -> np.ndarray:
    """Gravity potential (B,) of B poses given as bending vectors (B, N, 2): the masses of
    :func:`mass_points` in closed form (N*mm).

    A joint's n units each turn by a = theta/n about k = (-sin phi, cos phi, 0), so unit m's
    rotation is R^m = Rot(k, m a) = k k^T + cos(m a) (I - k k^T) + sin(m a) [k]x and a sum
    sum_m w_m R^m is M(C, S, W) = W k k^T + C (I - k k^T) + S [k]x with C = sum w_m cos(m a),
    S = sum w_m sin(m a), W = sum w_m. A unit is Trans(z, l0/2) R Trans(z, l0/2 + H), i.e. the
    translation t = (l0/2) e_z + (l0/2 + H) R e_z, which lies in the bending plane (k . t = 0);
    so in the joint's base frame

        end of the joint            = sum_{l<n} R^l t               = M(C2, S2, n) t,
        sum of the n disk centres   = sum_{l<n} (n - l) R^l t + sum_{m=1..n} R^m c
                                    = M(C0, S0, n(n+1)/2) t + M(C1, S1, n) c,

    c = (0, 0, -H/2) (a disk's centre below the top face of its hole; k . c = 0 too). Only
    g . p is needed: g is carried into each joint's base frame (g_i = R_{i-1}^T g) and g . p of
    the joint bases accumulates, so the chain costs a few element-wise operations per joint on
    the components (no 3x3 or 4x4 products): g . M(C, S, W) v = C g . v + S (g x k) . v for v
    perpendicular to k.
    """
    X = np.asarray(xs, dtype=float)
    B = X.shape[0]
    n_arr, half, ell, zc, mass, W = arm.potential_constants
    # per joint, independent of the chain: (B, N) arrays
    xi, yi = X[..., 0], X[..., 1]
    theta = np.hypot(xi, yi)
    straight = theta == 0.0  # phi = atan2(0, 0) = 0 there
    inv = 1.0 / np.where(straight, 1.0, theta)
    cp, sp = np.where(straight, 1.0, xi * inv), yi * inv
    a = theta / n_arr
    E = np.exp(1j * (a.T[..., None] * np.arange(W.shape[1]))) @ W  # (N, B, 3)
    C, S = E.real, E.imag  # per joint (B, 3): C0, C1, C2 and S0, S1, S2
    sa = ell * np.sin(a)
    t2 = ell * np.cos(a) + half
    ct, st = np.cos(theta), np.sin(theta)
    # probe vectors per joint: t = (sa cp, sa sp, t2), k x t = (cp t2, sp t2, -sa) (k . t = 0),
    # k x e_z = (cp, sp, 0)
    P = np.empty((*X.shape[:2], 3, 3))
    P[..., 0, 0], P[..., 0, 1], P[..., 0, 2] = sa * cp, sa * sp, t2
    P[..., 1, 0], P[..., 1, 1], P[..., 1, 2] = cp * t2, sp * t2, -sa
    P[..., 2, 0], P[..., 2, 1], P[..., 2, 2] = cp, sp, 0.0
    # Rot(k, theta)^T (eq. 1 transposed): carries g from a joint's base into its end frame
    c1 = cp * sp * (ct - 1.0)
    RT = np.empty((*X.shape[:2], 3, 3))
    RT[..., 0, 0], RT[..., 0, 1], RT[..., 0, 2] = ct * cp * cp + sp * sp, c1, -st * cp
    RT[..., 1, 0], RT[..., 1, 1], RT[..., 1, 2] = c1, cp * cp + sp * sp * ct, -st * sp
    RT[..., 2, 0], RT[..., 2, 1], RT[..., 2, 2] = st * cp, st * sp, ct
    g = np.tile(np.asarray(arm.gravity_mm_s2, dtype=float), (B, 1))  # in the joint base frame
    pg = np.zeros(B)  # g . (position of the joint base)
    V = np.zeros(B)
    for i in range(arm.n_joints):
        d = np.einsum("bpk,bk->bp", P[:, i], g)  # g . t, g . (k x t), g . (k x e_z)
        Ci, Si = C[i], S[i]
        if mass[i] > 0:
            # g . M(C1, S1, n) c = (C1 g_z + S1 g . (k x e_z)) c_z
            centres = (
                n_arr[i] * pg
                + Ci[:, 0] * d[:, 0]
                + Si[:, 0] * d[:, 1]
                + (Ci[:, 1] * g[:, 2] + Si[:, 1] * d[:, 2]) * zc[i]
            )
            V -= mass[i] * 1e-6 * centres
        pg = pg + Ci[:, 2] * d[:, 0] + Si[:, 2] * d[:, 1]
        g = np.einsum("bkl,bl->bk", RT[:, i], g)
    if arm.tip_mass_g > 0:
        V -= arm.tip_mass_g * 1e-6 * pg
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


@lru_cache(maxsize=8)
def _hessian_stencil(n: int, h: float) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Offsets (4 P, n) of the four-point stencil of every pair j <= k (P pairs), and the pairs."""
    pairs = [(j, k) for j in range(n) for k in range(j, n)]
    D = np.zeros((4 * len(pairs), n))
    for p, (j, k) in enumerate(pairs):
        for q, (sj, sk) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
            D[4 * p + q, j] += sj * h
            D[4 * p + q, k] += sk * h
    return D, pairs


def _hessian_from_stencil(V: np.ndarray, pairs: list[tuple[int, int]], n: int, h: float):
    v = V.reshape(-1, 4)
    vals = (v[:, 0] - v[:, 1] - v[:, 2] + v[:, 3]) / (4.0 * h * h)
    H = np.zeros((n, n))
    jj, kk = np.array(pairs).T
    H[jj, kk] = vals
    H[kk, jj] = vals
    return H


def gravity_hessian_x(arm: VertebraArm, x: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """d^2 V / dx^2 (2N x 2N, N*mm/rad^2), four-point stencil."""
    xs = np.asarray(x, dtype=float).ravel()
    n = xs.size
    D, pairs = _hessian_stencil(n, h)
    V = _potential_batch(arm, (xs + D).reshape(len(D), -1, 2))
    return _hessian_from_stencil(V, pairs, n, h)


@lru_cache(maxsize=8)
def _solver_stencil(n: int, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets (1 + 2n + n(n-1)/2, n) for :func:`_gravity_torque_and_hessian`: 0, +-h e_j, then
    h (e_j + e_k) for j < k; and the pair indices (j, k)."""
    jj, kk = np.triu_indices(n, 1)
    E = np.eye(n) * h
    D = np.concatenate((np.zeros((1, n)), E, -E, E[jj] + E[kk]))
    return D, jj, kk


def _gravity_torque_and_hessian(arm: VertebraArm, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`gravity_torque_x`, an approximate gravity Hessian) at ``x`` from ONE batch of
    1 + 2n + n(n-1)/2 potentials: the torque by the same central differences; the Hessian by
    the three-point second difference on the diagonal and a forward mixed difference
    (V(x + h e_j + h e_k) - V(x + h e_j) - V(x + h e_k) + V(x)) / h^2 off it (O(h), ~1e-4
    relative at h = 1e-4): it only sets the statics' Newton matrix and stability check, never
    the equilibrium."""
    xs = np.asarray(x, dtype=float).ravel()
    n = xs.size
    h = GRAVITY_FD_STEP_RAD
    D, jj, kk = _solver_stencil(n, h)
    V = _potential_batch(arm, (xs + D).reshape(len(D), -1, 2))
    v0, vp, vm, vpp = V[0], V[1 : n + 1], V[n + 1 : 2 * n + 1], V[2 * n + 1 :]
    Q = -(vp - vm) / (2.0 * h)
    H = np.diag((vp - 2.0 * v0 + vm) / (h * h))
    off = (vpp - vp[jj] - vp[kk] + v0) / (h * h)
    H[jj, kk] = off
    H[kk, jj] = off
    return Q, H


def statics_x(
    arm: VertebraArm, x_kin: np.ndarray, dx_guess: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Small-deflection equilibrium (bending vectors (N, 2), cable tensions (C,)).

    At the kinematic pose x_kin (from the cable displacements) every cable is at its pretension;
    the rod wants x = 0 with stiffness EI / L_joint per joint; gravity loads the disks. With
    J = :func:`cable_jacobian_x`, k = EA / L_total, K_g = sum T0 d^2 L / dx^2
    (:func:`cable_hessian_x`; the pretension's geometric stiffness, negative: it compresses the
    rod like a column), stationarity of
    sum [T0 L + k/2 (L - L(x_kin))^2] + sum EI/(2 L_i) |x_i|^2 + V_gravity gives

        F(dx) = (J^T k J + K_g + K_rod) dx + J^T T0 + K_rod x_kin - Q(x_kin + dx) = 0

    with the cable lengths linearised at x_kin and the gravity moment Q at the sagged pose,
    solved by Newton (dF/ddx = J^T k J + K_g + K_rod + d^2 V/dx^2 at the iterate,
    :func:`_gravity_torque_and_hessian`; once a step is below :data:`STATICS_NEWTON_BELOW_RAD`
    the last Hessian is kept, which changes the convergence rate, not the solution) from
    ``dx_guess`` (default 0, every cable taut; with a guess, e.g. the last step's sag, (2N,) or
    (N, 2), the cables taut at the guess). Cables whose tension would go negative go slack
    (active set) - the paper's "cables not taut" error. Raises :class:`ModelError` when there is
    no stable equilibrium.
    """
    x0 = np.asarray(x_kin, dtype=float).ravel()
    n = x0.size
    J, L_hess = _cable_jacobian_and_hessian(arm, x0)  # dL/dx, d^2 L_k / dx^2 per cable
    k = arm.cable_stiffness
    T0 = arm.pretensions
    K_rod = arm.rod_stiffness
    gravity = _has_gravity(arm)
    Q, H = np.zeros(n), np.zeros((n, n))
    if dx_guess is None:
        dx = np.zeros(n)
        active = np.ones(T0.shape, dtype=bool)  # every cable taut (a zero pretension too)
    else:  # the cables the guess leaves taut
        dx = np.asarray(dx_guess, dtype=float).ravel().copy()
        active = (T0 + k * (J @ dx)) >= 0.0
    K = Ja = None
    far = True
    last_change = math.inf  # the previous step with the same active set
    seen = {active.tobytes()}
    for _ in range(STATICS_MAX_ITER):
        new_matrix = far or K is None
        if K is None:
            Ja = J[active]
            Kg = np.tensordot(T0[active], L_hess[active], axes=1)  # slack cables drop out
            K = Ja.T @ (k[active, None] * Ja) + Kg + K_rod
            JT0 = Ja.T @ T0[active]
        if gravity:
            if far:
                Q, H = _gravity_torque_and_hessian(arm, x0 + dx)
            else:  # near the solution: the last Hessian (same fixed point, fewer potentials)
                Q = gravity_torque_x(arm, x0 + dx)
        A = K + H
        if new_matrix and np.linalg.eigvalsh(0.5 * (A + A.T)).min() <= 0.0:
            raise ModelError(
                "statics: no stable equilibrium (slack cables, or pretension or "
                "gravity buckling the rod)"
            )
        F = K @ dx + JT0 + K_rod @ x0 - Q
        dx_new = dx - np.linalg.solve(A, F)
        new_active = (T0 + k * (J @ dx_new)) >= 0.0
        change = float(np.max(np.abs(dx_new - dx)))
        far = change > STATICS_NEWTON_BELOW_RAD
        dx = dx_new
        if np.array_equal(new_active, active):
            # converged: this step was below the tolerance, or two steps on the same active
            # set show a contraction (rate = change / last_change < 1/2) so fast that the
            # remaining error, about change * rate, is
            rate = change / last_change if math.isfinite(last_change) else 1.0
            if change < STATICS_TOL_RAD or (rate < 0.5 and change * rate < STATICS_TOL_RAD):
                break
            last_change = change
        elif new_active.tobytes() in seen:
            # the active set cycles: the cables that flip sit on the slack threshold
            both = active & new_active
            dx = _statics_on_kink(arm, x0, J, L_hess, both, active ^ new_active, dx)
            tension = np.where(both, T0 + k * (J @ dx), 0.0)
            return (x0 + dx).reshape(-1, 2), tension
        else:
            seen.add(new_active.tobytes())
            active, K, last_change = new_active, None, math.inf
    else:
        raise ModelError("statics did not converge")
    tension = np.where(active, T0 + k * (J @ dx), 0.0)
    return (x0 + dx).reshape(-1, 2), tension


def _statics_on_kink(
    arm: VertebraArm,
    x0: np.ndarray,
    J: np.ndarray,
    L_hess: np.ndarray,
    taut: np.ndarray,
    edge: np.ndarray,
    dx: np.ndarray,
) -> np.ndarray:
    """The equilibrium of :func:`statics_x` when its active set cycles (bool masks: ``taut``
    cables, ``edge`` cables that flip): taut, an edge cable's tension T0 + k J dx is negative;
    slack, it is stretched. The model switches the edge cable's force J^T T and its
    pretension's geometric stiffness T0 d^2L/dx^2 off together, so neither set holds; the
    equilibrium sits on the switching surface (Filippov): each edge cable exactly at zero
    tension, T0 + k J dx = 0, its geometric stiffness entering with a weight w in [0, 1].
    Newton on (dx, w) from the cycling iterate; returns dx. Raises :class:`ModelError` if the
    weights leave [0, 1] (no such equilibrium)."""
    n = x0.size
    k, T0, K_rod = arm.cable_stiffness, arm.pretensions, arm.rod_stiffness
    Jb = J[taut]
    K_base = Jb.T @ (k[taut, None] * Jb) + np.tensordot(T0[taut], L_hess[taut], axes=1) + K_rod
    JT0 = Jb.T @ T0[taut]
    idx = np.nonzero(edge)[0]
    m = idx.size
    Ge = T0[idx, None, None] * L_hess[idx]  # (m, n, n) geometric stiffness of each edge cable
    w = np.full(m, 0.5)
    gravity = _has_gravity(arm)
    Q, H = np.zeros(n), np.zeros((n, n))
    for _ in range(STATICS_MAX_ITER):
        if gravity:
            Q, H = _gravity_torque_and_hessian(arm, x0 + dx)
        Kw = K_base + np.tensordot(w, Ge, axes=1)
        R = np.concatenate((Kw @ dx + JT0 + K_rod @ x0 - Q, T0[idx] + k[idx] * (J[idx] @ dx)))
        A = np.zeros((n + m, n + m))
        A[:n, :n] = Kw + H
        A[:n, n:] = (Ge @ dx).T
        A[n:, :n] = k[idx, None] * J[idx]
        step = np.linalg.solve(A, -R)
        dx, w = dx + step[:n], w + step[n:]
        if float(np.max(np.abs(step[:n]))) < STATICS_TOL_RAD:
            break
    else:
        raise ModelError("statics did not converge (cables on the slack threshold)")
    if np.any(w < -1e-9) or np.any(w > 1.0 + 1e-9):
        raise ModelError("statics: no equilibrium with the cables on the slack threshold")
    return dx


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
    sag = None
    for _ in range(STATICS_MAX_ITER):
        x = statics_x(arm, pre, sag)[0]
        sag = x - pre
        err = target - x
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

    ``max_offset_step_mm``: applies to modes ``model`` AND ``measured``: the largest change per
    control cycle of the compensation offset q_cmd - q_nominal of each cable (mm; the
    compensation's rate limit in mm/s times the period, ``vertebra.compensation_max_rate_mm_s``).
    The planned motion uses a share of each axis' speed limit; the offset adds its rate on top,
    so bounding it keeps the sum within the limit. Infinite: no bound.
    """

    gain_per_tick: float = ATTITUDE_GAIN_PER_S / 100.0
    max_correction_rad: float = ATTITUDE_MAX_CORRECTION_RAD
    min_observability: float = ATTITUDE_MIN_OBSERVABILITY
    max_error_rad: float = ATTITUDE_MAX_ERROR_RAD
    stale_after_s: float = 0.1
    base_up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    mounts: tuple[np.ndarray, ...] | None = None
    singular_tol: float = SINGULAR_TOL
    max_offset_step_mm: float = math.inf

    def __post_init__(self) -> None:
        if not (0.0 < self.gain_per_tick <= 1.0 and self.max_correction_rad > 0):
            raise ModelError("attitude loop: 0 < gain_per_tick <= 1 and max_correction_rad > 0")
        if not self.max_offset_step_mm > 0:
            raise ModelError("compensation: max_offset_step_mm must be > 0")


@dataclass
class VertebraLoopState:
    """Memory of :class:`VertebraModel` between cycles: the statics offset (warm start, x_kin -
    x_target) and the sag at the last x_kin (the statics' warm start), the attitude loop's
    integral correction (N, 2 bending vectors), the last decoded directions (continuity through
    singular poses), the last measured joint poses and the cable offset q_cmd - q_nominal last
    commanded (mm, rate-limited; None: zero, as in mode off)."""

    sag_offset: np.ndarray | None = None
    sag: np.ndarray | None = None
    offset_mm: np.ndarray | None = None
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

    In both compensating modes the cable offset q_cmd - q_nominal moves towards its target by
    at most ``attitude_loop.max_offset_step_mm`` per cycle: entering a compensating mode ramps
    the compensation in from zero (mode off commands no offset), and the offset's rate never adds
    more than that to the planned cable speed.
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
        q_nom = np.asarray(q_nominal, dtype=float)
        if mode == "off":
            state.offset_mm = None
            return q_nom
        p_cmd = _psi_array(psi, self.arm.n_joints)
        x_cmd = x_from_psi(p_cmd)
        if mode == "model":
            # one fixed-point step of statics_inverse_x (statics_inverse_step), the statics
            # itself warm-started from the last cycle's sag
            guess = x_cmd if state.sag_offset is None else x_cmd + state.sag_offset
            x_sagged = statics_x(self.arm, guess, state.sag)[0]
            state.sag = x_sagged - guess
            x_kin = guess + (x_cmd - x_sagged)
            state.sag_offset = x_kin - x_cmd
            # eq. 5 at x_kin minus eq. 5 at x_cmd = L(x_cmd) - L(x_kin)
            target = _path_lengths_x(self.arm, x_cmd) - _path_lengths_x(self.arm, x_kin)
            return q_nom + self._ramp_offset(state, target)
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
        target = _path_lengths_x(self.arm, x_cmd) - _path_lengths_x(self.arm, x_cmd + c)
        return q_nom + self._ramp_offset(state, target)

    def _ramp_offset(self, state: VertebraLoopState, target_mm: np.ndarray) -> np.ndarray:
        """The cable offset of this cycle: ``target_mm`` approached from the last one by at most
        ``max_offset_step_mm`` per cable (mm)."""
        prev = np.zeros_like(target_mm) if state.offset_mm is None else state.offset_mm
        step = self.attitude_loop.max_offset_step_mm
        offset = prev + np.clip(target_mm - prev, -step, step)
        state.offset_mm = offset
        return offset

    def tip(self, psi: np.ndarray) -> np.ndarray:
        return tip_position(self.arm, psi)
