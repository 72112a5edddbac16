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

Equation map: eq. 1-2 :func:`tip_transform`; eq. 3 :class:`LeadScrewDrive`; eq. 4
:func:`subjoint_cable_length`; eq. 5-6 :func:`segment_cable_lengths`, :func:`subjoint_angles`;
eq. 7-10 :func:`solve_segment_angles`; eq. 11-12 :func:`cable_path_lengths`,
:func:`angles_from_path_lengths`; eq. 13 and 15 :func:`linearised_angle_error`; dead zone of
section 4.1 :func:`dead_zone_mm`, :func:`play_update`; eq. 14, 16-17 :func:`deformation_rad`;
section 3 algorithm :func:`compensate`; the simulator's truth :func:`truth_angles`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np

from cdcr_ctl.errors import ModelError

#: Newton iteration of eq. 10: stop when the angle step is below this (rad).
NEWTON_STEP_TOL_RAD = 1e-13
#: Newton iteration of eq. 10: give up after this many iterations.
NEWTON_MAX_ITER = 60
#: A change of a joint angle smaller than this (rad) counts as "not moving" (eq. 17, theta_dot = 0).
#: Above the statics' round-off (STATICS_TOL_RAD) so that solver noise at rest is no motion.
MOTION_EPS_RAD = 1e-9
#: A change of a cable output smaller than this (mm) keeps the cable's last direction: above the
#: statics' round-off (~1e-8 mm of cable), far below an encoder count (~1e-4 mm).
CABLE_MOTION_EPS_MM = 1e-6
#: Iterations of the statics and of its inverse, and their tolerance (rad), which sits above the
#: round-off of the finite-difference gravity moment.
STATICS_MAX_ITER = 60
#: Central-difference step of the gravity moment (rad): large enough that the round-off of the
#: potential (~1e-16 V / h) stays below the statics tolerance, small enough for O(h^2) accuracy.
GRAVITY_FD_STEP_RAD = 1e-4
STATICS_TOL_RAD = 1e-10
#: Statics evaluations per control-loop tick in :class:`UJointModel` (warm-started, see
#: :func:`compensate`).
LOOP_STATICS_EVALS = 1

GearRatioKind = Literal["reduction", "multiplier"]
DeformationKind = Literal["off", "proportional", "torque"]


# =========================================================================== parameters
@dataclass(frozen=True)
class UJointSegment:
    """One segment: ``n_subjoints`` (M) universal joints with half-gap d and rigid link tubes.

    ``half_gap_mm`` (d): distance from a disk face to the joint centre (both sides, eq. 4).
    ``link_mm``: rigid tube from D2 of a sub-joint to D1 of the next (constant cable length).
    ``link_mass_g``: mass of one moving link (cross, upper disk, tube), centred in its tube.
    Pitch of the sub-joints: 2 d + link; segment length M (2 d + link).
    """

    name: str
    n_subjoints: int
    half_gap_mm: float
    link_mm: float = 0.0
    link_mass_g: float = 0.0

    def __post_init__(self) -> None:
        if self.n_subjoints < 1 or not self.half_gap_mm > 0:
            raise ModelError(f"segment {self.name}: need n_subjoints >= 1 and half_gap_mm > 0")
        if self.link_mm < 0 or self.link_mass_g < 0:
            raise ModelError(f"segment {self.name}: link_mm and link_mass_g must be >= 0")

    @property
    def pitch_mm(self) -> float:
        """Distance between consecutive joint centres at the straight pose (mm)."""
        return 2.0 * self.half_gap_mm + self.link_mm

    @property
    def length_mm(self) -> float:
        """Segment length at the straight pose (mm)."""
        return self.n_subjoints * self.pitch_mm

    @property
    def straight_gap_length_mm(self) -> float:
        """Cable length across the segment's joint gaps at the straight pose, 2 M d (eq. 11)."""
        return 2.0 * self.n_subjoints * self.half_gap_mm


@dataclass(frozen=True)
class UJointCable:
    """One drive cable, anchored at the tip of segment ``segment`` (0-based), passing all proximal
    segments through holes at ``hole_angle_rad`` (beta) and radius ``hole_radius_mm`` (rho).

    ``total_length_mm``: actuator to anchor at the straight pose, drive box included (Yang:
    780 mm and 1290 mm); it sets the cable's axial stiffness EA / L and its dead zone.
    """

    name: str
    segment: int
    hole_angle_rad: float
    hole_radius_mm: float
    EA_N: float
    total_length_mm: float
    pretension_N: float

    def __post_init__(self) -> None:
        if self.segment < 0 or not self.hole_radius_mm > 0:
            raise ModelError(f"cable {self.name}: segment >= 0 and hole_radius_mm > 0 required")
        if not (self.EA_N > 0 and self.total_length_mm > 0 and self.pretension_N >= 0):
            raise ModelError(f"cable {self.name}: EA, length > 0 and pretension >= 0 required")

    @property
    def stiffness_N_per_mm(self) -> float:
        """Axial stiffness of the whole cable, EA / L (N/mm)."""
        return self.EA_N / self.total_length_mm


@dataclass(frozen=True)
class LeadScrewDrive:
    """Motor -> lead screw -> moving pulley -> cable (Yang et al. 2022 eq. 3, Fig. 6).

    The nut carries a moving pulley: the cable loops round it, so the cable taken in is
    ``pulley_factor`` (2) times the nut travel. The screw advances ``lead_mm`` (S) per turn.
    ``gear_ratio`` is the paper's lambda: with ``gear_ratio_kind = "reduction"`` the motor turns
    lambda times per screw turn and lambda DIVIDES (a gearbox 14:1 means lambda = 14); with
    ``"multiplier"`` lambda is screw turns per motor turn and multiplies, as eq. 3 is printed:

        reduction:   dq = dvartheta * pulley_factor * S / (2 pi) / lambda
        multiplier:  dq = dvartheta * pulley_factor * S / (2 pi) * lambda

    With pulley_factor = 2 this is eq. 3's dvartheta * S / pi (NOTES: the moving pulley doubles the
    cable change). dvartheta is the motor angle (rad), dq the cable pulled in (mm).
    """

    lead_mm: float
    gear_ratio: float = 1.0
    gear_ratio_kind: GearRatioKind = "reduction"
    pulley_factor: float = 2.0

    def __post_init__(self) -> None:
        if not (self.lead_mm > 0 and self.gear_ratio > 0 and self.pulley_factor > 0):
            raise ModelError("lead screw drive: lead, gear ratio and pulley factor must be > 0")
        if self.gear_ratio_kind not in ("reduction", "multiplier"):
            raise ModelError(
                f"gear_ratio_kind must be reduction or multiplier, not {self.gear_ratio_kind!r}"
            )

    @property
    def cable_mm_per_motor_rad(self) -> float:
        """Cable pulled in per motor radian (mm/rad), eq. 3."""
        base = self.pulley_factor * self.lead_mm / (2.0 * math.pi)
        if self.gear_ratio_kind == "reduction":
            return base / self.gear_ratio
        return base * self.gear_ratio

    def cable_from_motor(self, dvartheta_rad: np.ndarray | float) -> np.ndarray:
        """Cable pulled in (mm) for a motor rotation (rad), eq. 3."""
        return np.asarray(dvartheta_rad, dtype=float) * self.cable_mm_per_motor_rad

    def motor_from_cable(self, dq_mm: np.ndarray | float) -> np.ndarray:
        """Motor rotation (rad) for a cable pulled in (mm), inverse of eq. 3."""
        return np.asarray(dq_mm, dtype=float) / self.cable_mm_per_motor_rad

    def counts_per_mm(self, counts_per_motor_rev: float) -> float:
        """Encoder counts per mm of cable pulled in, for an encoder on the motor shaft."""
        return counts_per_motor_rev / (2.0 * math.pi * self.cable_mm_per_motor_rad)


@dataclass(frozen=True)
class DeformationParams:
    """Proximal-segment deformation by the distal segments' drive torque (eq. 14, 16-17).

    ``kind``: ``"proportional"`` (eq. 16-17, the paper's simulation), ``"torque"`` (eq. 14, with
    ``friction_torque_Nmm[m]`` tau_f,m in N*mm and ``stiffness_Nmm_per_rad[n]`` k_n in N*mm per
    rad of the sub-joint angle theta) or ``"off"``. For segment n, each distal m > n and each
    coordinate (theta_{2n-1} with theta_dot_{2m-1}, theta_{2n} with theta_dot_{2m}):

        proportional:  Delta theta_de,n = sgn(theta_dot_m) * eta * |theta_n|
        torque:        Delta theta_de,n = sgn(theta_dot_m) * |sgn(theta_n)| * tau_f,m / k_n

    summed over m. Sign (derived; NOTES eq. 13-17): eq. 16-17 read literally, Delta theta = eta
    theta_n with eta of the sign of theta_dot_m theta_n, is sgn(theta_dot_m) eta |theta_n|; eq. 14
    read literally, sgn(theta_dot_m theta_n) tau / k, agrees with it only for theta_n > 0 (the
    paper's planar tests) and is not mirror-symmetric (theta -> -theta everywhere must flip the
    deformation). Physically the extra tension that drives m towards theta_dot_m runs through n on
    the same side and bends n the same way. So both forms use sgn(theta_dot_m), keep eq. 14/17's
    zero at theta_n = 0, and equal the printed equations whenever theta_n > 0.
    ``hold_when_stopped``: eq. 17 sets eta = 0 while theta_dot_m = 0 (False, the paper); True keeps
    the sign of the last motion (static friction holding the torque).
    """

    kind: DeformationKind = "proportional"
    eta: float = 0.1
    friction_torque_Nmm: tuple[float, ...] = ()
    stiffness_Nmm_per_rad: tuple[float, ...] = ()
    hold_when_stopped: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("off", "proportional", "torque"):
            raise ModelError(f"deformation kind must be off/proportional/torque, not {self.kind!r}")
        if self.kind == "proportional" and not 0.0 <= self.eta < 1.0:
            raise ModelError("deformation eta must be in [0, 1) (eq. 17 gives its sign)")
        if any(k <= 0 for k in self.stiffness_Nmm_per_rad) or any(
            t < 0 for t in self.friction_torque_Nmm
        ):
            raise ModelError("deformation stiffness must be > 0 and friction torque >= 0")


@dataclass(frozen=True)
class UJointArm:
    """The whole arm: segments base to tip, cables, drive, dead-zone and deformation parameters.

    ``friction_exponent_per_mm`` (kappa, 1/mm): mu times the cable's wrap angle per mm of path,
    the distributed friction that makes the dead zone (:func:`dead_zone_mm`).
    ``base_link_mm``: rigid base from the robot base frame to the first D1 (mm).
    ``tip_link_mm``/``tip_mass_g``: rigid end effector after the last segment, mass at its middle.
    ``gravity_mm_s2``: gravity in the robot base frame.
    """

    segments: tuple[UJointSegment, ...]
    cables: tuple[UJointCable, ...]
    drive: LeadScrewDrive
    friction_exponent_per_mm: float = 0.0
    deformation: DeformationParams = field(default_factory=DeformationParams)
    base_link_mm: float = 0.0
    tip_link_mm: float = 0.0
    tip_mass_g: float = 0.0
    gravity_mm_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        N = len(self.segments)
        if N < 1:
            raise ModelError("the arm needs at least one segment")
        if self.friction_exponent_per_mm < 0 or self.base_link_mm < 0 or self.tip_link_mm < 0:
            raise ModelError("friction exponent and link lengths must be >= 0")
        for c in self.cables:
            if c.segment >= N:
                raise ModelError(f"cable {c.name}: segment index {c.segment} >= {N} segments")
        for n in range(N):
            own = [c for c in self.cables if c.segment == n]
            if len(own) < 2:
                raise ModelError(
                    f"segment {self.segments[n].name}: needs >= 2 cables (has {len(own)})"
                )
            J0 = np.array(
                [
                    [
                        c.hole_radius_mm * math.sin(c.hole_angle_rad),
                        -c.hole_radius_mm * math.cos(c.hole_angle_rad),
                    ]
                    for c in own
                ]
            )
            if np.linalg.matrix_rank(J0, tol=1e-9 * float(np.abs(J0).max())) < 2:
                raise ModelError(
                    f"segment {self.segments[n].name}: cable holes are collinear "
                    "with the centre; eq. 10 has no unique solution"
                )
        d = self.deformation
        if d.kind == "proportional" and d.eta * (N - 1) >= 1.0:
            raise ModelError(
                "deformation eta * (segments - 1) must be < 1 (else the deformed "
                "angle can change sign and eq. 16 cannot be inverted)"
            )
        if d.kind == "torque" and (
            len(d.friction_torque_Nmm) != N or len(d.stiffness_Nmm_per_rad) != N
        ):
            raise ModelError(
                "torque deformation needs friction_torque_Nmm and "
                "stiffness_Nmm_per_rad with one value per segment"
            )

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    @property
    def n_cables(self) -> int:
        return len(self.cables)

    @cached_property
    def own_cables(self) -> tuple[np.ndarray, ...]:
        """Per segment, the indices of the cables anchored in it (eq. 7's three cables)."""
        return tuple(
            np.array([k for k, c in enumerate(self.cables) if c.segment == n], dtype=int)
            for n in range(self.n_segments)
        )

    @cached_property
    def betas(self) -> np.ndarray:
        return np.array([c.hole_angle_rad for c in self.cables])

    @cached_property
    def rhos(self) -> np.ndarray:
        return np.array([c.hole_radius_mm for c in self.cables])

    @cached_property
    def anchor(self) -> np.ndarray:
        return np.array([c.segment for c in self.cables], dtype=int)

    @cached_property
    def straight_path_mm(self) -> np.ndarray:
        """Per cable, its length across all joint gaps at the straight pose, sum 2 M_i d_i."""
        gaps = np.array([s.straight_gap_length_mm for s in self.segments])
        return np.array([gaps[: c.segment + 1].sum() for c in self.cables])

    @cached_property
    def cable_stiffness_N_per_mm(self) -> np.ndarray:
        return np.array([c.stiffness_N_per_mm for c in self.cables])

    @cached_property
    def pretension_N(self) -> np.ndarray:
        return np.array([c.pretension_N for c in self.cables])

    @cached_property
    def dead_zones_mm(self) -> tuple[np.ndarray, np.ndarray]:
        """(pull_mm, release_mm) per cable, :func:`dead_zone_mm` at its pretension and length."""
        pr = [
            dead_zone_mm(c.pretension_N, c.total_length_mm, c.EA_N, self.friction_exponent_per_mm)
            for c in self.cables
        ]
        return np.array([p for p, _ in pr]), np.array([r for _, r in pr])

    @cached_property
    def hole_sets(self) -> tuple[SegmentHoles, ...]:
        """Per segment, the holes of the cables that cross its joints, built once (constant
        geometry) for the vectorised eq. 4-5 of the control loop and the simulator's truth."""
        out = []
        for i, seg in enumerate(self.segments):
            sets = [
                HoleSet.of(np.nonzero(sel)[0], self.betas, self.rhos, seg)
                for sel in (self.anchor == i, self.anchor > i, self.anchor >= i)
            ]
            out.append(SegmentHoles(*sets))
        return tuple(out)


@dataclass(frozen=True, eq=False)
class HoleSet:
    """The holes of some cables in the disks of one segment, for eq. 4 in matrix form.

    ``index`` (K,): the cables (indices into ``UJointArm.cables``). With u the hole in disk D2's
    own frame, (rho cos beta, rho sin beta, d), and l the hole in disk D1 seen from the joint
    centre, (rho cos beta, rho sin beta, -d) (mm), eq. 4's chord of a sub-joint is
    v = R u - l, R = Rx(a) Ry(b), and

        f_i^2 = |u|^2 + |l|^2 - 2 l^T R u = ``norms`` - 2 ``outer`` . vec(R)

    with ``outer`` (K, 9) the rows vec(l u^T) and ``norms`` (K,) = |u|^2 + |l|^2 = 2 (rho^2 + d^2):
    one matrix product gives every cable's chord and, with the derivatives of R, its derivatives
    (:func:`_hole_terms`; stored transposed, (9, K)). ``m``: sub-joints (eq. 5).
    """

    index: np.ndarray
    outer: np.ndarray
    norms: np.ndarray
    m: int

    @classmethod
    def of(
        cls, index: np.ndarray, betas: np.ndarray, rhos: np.ndarray, seg: UJointSegment
    ) -> HoleSet:
        return cls.from_holes(index, betas[index], rhos[index], seg.half_gap_mm, seg.n_subjoints)

    @classmethod
    def from_holes(
        cls,
        index: np.ndarray,
        beta: np.ndarray | float,
        rho: np.ndarray | float,
        d: float,
        m: int,
    ) -> HoleSet:
        """Holes at angle ``beta`` (rad) and radius ``rho`` (mm), half gap ``d`` (mm)."""
        b, r = np.broadcast_arrays(np.atleast_1d(beta), np.atleast_1d(rho))
        x, y = r * np.cos(b), r * np.sin(b)
        dz = np.full(x.shape, float(d))
        upper, lower = np.array([x, y, dz]).T, np.array([x, y, -dz]).T  # (K, 3)
        outer = (lower[:, :, None] * upper[:, None, :]).reshape(-1, 9)
        norms = (upper * upper).sum(axis=1) + (lower * lower).sum(axis=1)
        return cls(np.asarray(index), np.ascontiguousarray(outer.T), norms, int(m))


@dataclass(frozen=True)
class SegmentHoles:
    """One segment's :class:`HoleSet` s: ``own`` cables (anchored in it), ``through`` cables
    (anchored further out) and ``passing`` (both, cable order)."""

    own: HoleSet
    through: HoleSet
    passing: HoleSet


@dataclass(frozen=True)
class UJointEffects:
    """Which non-ideal effects a truth or compensation call includes.

    ``dead_zone``: cable stick at direction reversal (section 4.1); ``deformation``: eq. 14-17;
    ``statics``: cable elasticity with pretension vs gravity (:func:`statics_angles`).
    ``friction_driven_deformation`` (truth only): the sign of eq. 14/17 comes from the friction
    state of the distal segment's own cables (:func:`cable_friction_state`,
    :func:`segment_friction_direction`) instead of sgn(theta_dot_m): the friction torque reverses
    while those cables cross their dead zone, not at the first tiny backward motion of the distal
    angle (which the proximal segment's own motion can cause through the coupling of eq. 11).
    """

    dead_zone: bool = True
    deformation: bool = True
    statics: bool = True
    friction_driven_deformation: bool = False


# =========================================================================== rotations
def rot_x(a: float) -> np.ndarray:
    """Rotation about x by ``a`` (rad), 3x3."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(b: float) -> np.ndarray:
    """Rotation about y by ``b`` (rad), 3x3."""
    c, s = math.cos(b), math.sin(b)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _homog(R: np.ndarray, p: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def _trans_z(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


def _rotation_rows(a: float, b: float, order: int) -> np.ndarray:
    """Rx(a) Ry(b) (eq. 4's sub-joint rotation) and its partial derivatives, each flattened row by
    row, (1, 3 or 6, 9): R; with order >= 1 also R_a, R_b; with order 2 also R_aa, R_ab, R_bb
    (a, b in rad)."""
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    rows = [[cb, 0.0, sb, sa * sb, ca, -sa * cb, -ca * sb, sa, ca * cb]]
    if order >= 1:
        rows.append([0.0, 0.0, 0.0, ca * sb, -sa, -ca * cb, sa * sb, ca, -sa * cb])
        rows.append([-sb, 0.0, cb, sa * cb, 0.0, sa * sb, -ca * cb, 0.0, -ca * sb])
    if order >= 2:
        rows.append([0.0, 0.0, 0.0, -sa * sb, -ca, sa * cb, ca * sb, -sa, -ca * cb])
        rows.append([0.0, 0.0, 0.0, ca * cb, 0.0, ca * sb, sa * cb, 0.0, sa * sb])
        rows.append([-cb, 0.0, -sb, -sa * sb, 0.0, sa * cb, ca * sb, 0.0, -ca * cb])
    return np.array(rows)


def _hole_lengths(holes: HoleSet, a: float, b: float) -> np.ndarray:
    """Eq. 5 for the cables of ``holes``, every sub-joint at the physical angles (a, b): the
    lengths (K,) across the segment, m f_i (mm); see :func:`_hole_terms`."""
    S = _rotation_rows(a, b, 0) @ holes.outer
    return holes.m * np.sqrt(holes.norms - 2.0 * S[0])


def _hole_terms(
    holes: HoleSet, a: float, b: float, second: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 5 for the cables of ``holes`` with every sub-joint at the physical angles (a, b):
    (f (K,), g (2, K), h (3, K)), f = m f_i the length across the segment (mm), g its
    derivatives along a and b (mm/rad, eq. 9) and, with ``second``, h the second derivatives
    aa, ab, bb (mm/rad^2; else h is empty, (0, K)).

    Eq. 4 as the bilinear form of :class:`HoleSet`: with s = l^T R u and its derivatives
    s_x = l^T R_x u (one product ``outer @ vec(R_x)``), f_i^2 = ``norms`` - 2 s, so
    f_x = -s_x / f_i and f_xy = -(s_xy + f_x f_y) / f_i. f_i >= 2 d cos(angle) - 2 rho > 0 for a
    real joint, so nothing divides by 0.
    """
    S = _rotation_rows(a, b, 2 if second else 1) @ holes.outer  # s, s_a, s_b(, s_aa, s_ab, s_bb)
    f = np.sqrt(holes.norms - 2.0 * S[0])
    g = -S[1:3] / f  # (2, K)
    h = -(S[3:6] + g[_HESS_I] * g[_HESS_J]) / f if second else S[3:]  # aa, ab, bb
    m = holes.m
    return m * f, m * g, m * h


#: Rows of the (aa, ab, bb) second derivatives: index pairs into the first derivatives (a, b).
_HESS_I = np.array([0, 0, 1])
_HESS_J = np.array([0, 1, 1])


# =========================================================================== eq. 4-6
def subjoint_cable_length(
    psi_I: float, psi_J: float, beta: np.ndarray | float, rho: np.ndarray | float, d: float
) -> np.ndarray:
    """Straight cable length between the hole pair of one sub-joint (mm), eq. 4 as printed.

    Holes at (rho cos beta, rho sin beta, -d) in the joint-centre frame (disk D1) and at
    Rot(x, psi_I) Rot(y, psi_J) (rho cos beta, rho sin beta, d) (disk D2); the three components
    below are those of the difference, exactly eq. 4's three squared terms. ``psi_I`` is the
    physical rotation about the frame's x axis (see module docstring on eq. 6). At psi = 0: 2 d.
    """
    b = np.asarray(beta, dtype=float)
    r = np.asarray(rho, dtype=float)
    cI, sI, cJ, sJ = math.cos(psi_I), math.sin(psi_I), math.cos(psi_J), math.sin(psi_J)
    cb, sb = np.cos(b), np.sin(b)
    v1 = d * sJ + r * cJ * cb - r * cb
    v2 = r * cb * sI * sJ + r * cI * sb - d * sI * cJ - r * sb
    v3 = r * sI * sb - r * cb * cI * sJ + d * cI * cJ + d
    return np.sqrt(v1 * v1 + v2 * v2 + v3 * v3)


def subjoint_cable_length_grad(
    psi_I: float, psi_J: float, beta: np.ndarray | float, rho: np.ndarray | float, d: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f, df/dpsi_I, df/dpsi_J) of eq. 4 (mm, mm/rad), from the component derivatives.

    f = |v| is never 0 for a real joint (f >= 2 d cos(psi) - 2 rho), so the gradient v.dv / f is
    finite everywhere, including the straight pose where it is (rho sin beta, -rho cos beta).
    """
    b = np.asarray(beta, dtype=float)
    r = np.asarray(rho, dtype=float)
    cI, sI, cJ, sJ = math.cos(psi_I), math.sin(psi_I), math.cos(psi_J), math.sin(psi_J)
    cb, sb = np.cos(b), np.sin(b)
    v1 = d * sJ + r * cJ * cb - r * cb
    v2 = r * cb * sI * sJ + r * cI * sb - d * sI * cJ - r * sb
    v3 = r * sI * sb - r * cb * cI * sJ + d * cI * cJ + d
    f = np.sqrt(v1 * v1 + v2 * v2 + v3 * v3)
    # d/dpsi_I (v1 has no psi_I)
    v2a = r * cb * cI * sJ - r * sI * sb - d * cI * cJ
    v3a = r * cI * sb + r * cb * sI * sJ - d * sI * cJ
    # d/dpsi_J
    v1b = d * cJ - r * sJ * cb
    v2b = r * cb * sI * cJ + d * sI * sJ
    v3b = -r * cb * cI * cJ - d * cI * sJ
    return f, (v2 * v2a + v3 * v3a) / f, (v1 * v1b + v2 * v2b + v3 * v3b) / f


def first_axis_signs(m: int) -> np.ndarray:
    """Direction of the first axis xi_{n,i,I} along the segment x axis, (-1)^(i+1), i = 1..m."""
    return np.array([1.0 if i % 2 == 1 else -1.0 for i in range(1, m + 1)])


def subjoint_angles(theta_a: float, theta_b: float, m: int) -> np.ndarray:
    """(m, 2) D-H-local sub-joint angles (psi_{n,i,I}, psi_{n,i,J}) of eq. 6 (rad).

    theta_{2n-1} = (-1)^(i+1) psi_{n,i,I} and theta_{2n} = psi_{n,i,J} for i = 1..m.
    """
    s = first_axis_signs(m)
    return np.column_stack((s * theta_a, np.full(m, float(theta_b))))


def _physical_angles(theta_a: float, theta_b: float, m: int) -> np.ndarray:
    """(m, 2) physical rotations of the sub-joints about the segment x and y axes: eq. 6's D-H
    angles times the direction of their first axis, (-1)^(i+1) psi_{n,i,I} = theta_{2n-1}."""
    psi = subjoint_angles(theta_a, theta_b, m)
    return np.column_stack((first_axis_signs(m) * psi[:, 0], psi[:, 1]))


def segment_cable_lengths(
    theta_a: float,
    theta_b: float,
    beta: np.ndarray | float,
    rho: np.ndarray | float,
    d: float,
    m: int,
) -> np.ndarray:
    """Length of each cable across the m sub-joints of one segment (mm), eq. 5 with eq. 6.

    f_{n,k} = sum_i f_{n,i,k}: each sub-joint's D-H angles (eq. 6) are turned back into the
    physical rotation about the segment x axis, sign_i * psi_{n,i,I} = theta_{2n-1}, before eq. 4.
    All m sub-joints then turn alike (equal-angle linkage): the sum is m times the first term.
    """
    a, b = _physical_angles(theta_a, theta_b, m)[0]
    holes = HoleSet.from_holes(np.zeros(0, dtype=int), beta, rho, d, m)
    return _hole_lengths(holes, float(a), float(b))


def segment_cable_jacobian(
    theta_a: float,
    theta_b: float,
    beta: np.ndarray | float,
    rho: np.ndarray | float,
    d: float,
    m: int,
) -> tuple[np.ndarray, np.ndarray]:
    """(f, J_d) of one segment: lengths (K,) and the K x 2 matrix df_k/d(theta_{2n-1}, theta_{2n}).

    J_d is eq. 9 (NOTES: the printed eq. 9 is garbled; this is the 3 x 2 matrix of partials).
    Every sub-joint turns by the same physical angles, d(sign_i psi_I)/d theta_{2n-1} =
    sign_i^2 = 1, so J_d is the eq. 4 gradient summed over the m sub-joints.
    """
    a, b = _physical_angles(theta_a, theta_b, m)[0]
    holes = HoleSet.from_holes(np.zeros(0, dtype=int), beta, rho, d, m)
    f, g, _ = _hole_terms(holes, float(a), float(b))
    return f, g.T


# =========================================================================== eq. 7-12
def _as_theta(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    t = np.asarray(theta, dtype=float)
    if t.shape != (arm.n_segments, 2):
        raise ModelError(f"joint angles must have shape ({arm.n_segments}, 2), got {t.shape}")
    return t


def cable_path_lengths(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Per cable, its length across every joint gap it passes (mm), eq. 11 without the -2nMd.

    Cable k anchored in segment n_k: sum over i <= n_k of f_{i,k}(theta_{2i-1}, theta_{2i}).
    The rigid link tubes and the drive box add constant lengths and are left out.
    Every sub-joint of segment i turns by the physical angles (theta_{2i-1}, theta_{2i}) (eq. 6,
    :func:`segment_cable_lengths`), so eq. 5 is evaluated once per segment on its
    :attr:`UJointArm.hole_sets`.
    """
    t = _as_theta(arm, theta)
    L = np.zeros(arm.n_cables)
    for i, holes in enumerate(arm.hole_sets):
        L[holes.passing.index] += _hole_lengths(holes.passing, t[i, 0], t[i, 1])
    return L


def cable_displacements(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Ideal inverse kinematics: cable pulled in at the drive (mm) for joint angles ``theta``.

    q_k = -Delta l_k = sum_i 2 M_i d_i - sum_i f_{i,k}(theta_i), eq. 11 with this project's sign.
    """
    return arm.straight_path_mm - cable_path_lengths(arm, theta)


def cable_jacobian(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """d(path length)/d(theta) (C x 2N, mm/rad), columns (theta_1, theta_2, ..., theta_2N).

    Block (cable k, segment i) is the eq. 9 row of cable k in segment i when k passes i, else 0.
    """
    t = _as_theta(arm, theta)
    J = np.zeros((arm.n_cables, 2 * arm.n_segments))
    for i, holes in enumerate(arm.hole_sets):
        hs = holes.passing
        _, g, _ = _hole_terms(hs, t[i, 0], t[i, 1])
        J[hs.index, 2 * i] = g[0]
        J[hs.index, 2 * i + 1] = g[1]
    return J


def cable_jacobian_hessian(arm: UJointArm, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J, H): :func:`cable_jacobian` and d^2 (path length) / d theta^2 per cable
    (C x 2N x 2N, mm/rad^2; block diagonal: a segment's angles only change the cable's chords in
    that segment), analytically from eq. 4 (:func:`_hole_terms`)."""
    t = _as_theta(arm, theta)
    C, n = arm.n_cables, 2 * arm.n_segments
    J = np.zeros((C, n))
    H = np.zeros((C, n, n))
    for i, holes in enumerate(arm.hole_sets):
        hs = holes.passing
        _, g, h = _hole_terms(hs, t[i, 0], t[i, 1], second=True)
        J[hs.index, 2 * i] = g[0]
        J[hs.index, 2 * i + 1] = g[1]
        H[hs.index, 2 * i, 2 * i] = h[0]
        H[hs.index, 2 * i, 2 * i + 1] = h[1]
        H[hs.index, 2 * i + 1, 2 * i] = h[1]
        H[hs.index, 2 * i + 1, 2 * i + 1] = h[2]
    return J, H


def solve_segment_angles(
    lengths_mm: np.ndarray,
    beta: np.ndarray,
    rho: np.ndarray,
    d: float,
    m: int,
    guess: np.ndarray | None = None,
) -> np.ndarray:
    """Segment angles (theta_{2n-1}, theta_{2n}) from its cables' lengths (eq. 7-10, Fig. 8).

    Newton / Gauss-Newton: theta <- theta + J_d^+ (l_d - f(theta)) with the pseudo-inverse of the
    3 x 2 J_d (eq. 10) until the step is below :data:`NEWTON_STEP_TOL_RAD`. With 3 cables for 2
    unknowns, inconsistent lengths (stretched cables) give the least-squares angles.
    Raises :class:`ModelError` when the iteration does not converge (lengths out of reach).
    """
    holes = HoleSet.from_holes(np.zeros(0, dtype=int), beta, rho, d, m)
    return _solve_holes(holes, np.asarray(lengths_mm, dtype=float), guess)


def _solve_holes(holes: HoleSet, ld: np.ndarray, guess: np.ndarray | None) -> np.ndarray:
    """:func:`solve_segment_angles` on prepared holes. The step J_d^+ (l_d - f) is solved from
    the 2 x 2 normal equations (J_d^T J_d) step = J_d^T (l_d - f), which is the pseudo-inverse
    for a J_d of full column rank (holes not collinear with the centre, checked by
    :class:`UJointArm`); a numerically singular J_d falls back to :func:`numpy.linalg.pinv`."""
    a, b = (0.0, 0.0) if guess is None else (float(guess[0]), float(guess[1]))
    for _ in range(NEWTON_MAX_ITER):
        f, g, _ = _hole_terms(holes, a, b)
        r = ld - f
        (A00, A01), (A10, A11) = (g @ g.T).tolist()
        y0, y1 = (g @ r).tolist()
        det = A00 * A11 - A01 * A10
        if det > 1e-12 * A00 * A11:
            da = (A11 * y0 - A01 * y1) / det
            db = (A00 * y1 - A10 * y0) / det
        else:
            da, db = (float(x) for x in np.linalg.pinv(g.T) @ r)
        # the equal-angle joints reach at most ~pi/2 per sub-joint; damp wild first steps
        big = max(abs(da), abs(db))
        if big > 0.3:
            da, db = da * 0.3 / big, db * 0.3 / big
            big = 0.3
        a, b = a + da, b + db
        if big < NEWTON_STEP_TOL_RAD:
            return np.array([a, b])
    raise ModelError(
        f"eq. 10 iteration did not converge for lengths {ld.tolist()} mm (last angles {[a, b]} rad)"
    )


def angles_from_path_lengths(
    arm: UJointArm,
    lengths_mm: np.ndarray,
    guess: np.ndarray | None = None,
    offsets_rad: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Whole-arm joint angles from the cable path lengths, segment by segment (eq. 11-12, Fig. 9).

    Segment 1 from its own cables; the part of every distal cable inside segment 1 (the coupling
    length l_c) is computed at segment 1's angles and subtracted (eq. 12: l_d = l - l_c), and so on
    outwards. ``offsets_rad`` (N, 2) are added to each segment's solved angles before they are used
    for the coupling of distal cables (the deformation of eq. 14: the distal cables run through
    the deformed proximal segment). Returns (theta_kin, theta) with theta = theta_kin + offsets.
    """
    L = np.asarray(lengths_mm, dtype=float)
    N = arm.n_segments
    kin = np.zeros((N, 2))
    out = np.zeros((N, 2))
    used = np.zeros(arm.n_cables)  # coupling length consumed in proximal segments
    for n, holes in enumerate(arm.hole_sets):
        own = holes.own.index
        g = None if guess is None else np.asarray(guess, dtype=float)[n]
        kin[n] = _solve_holes(holes.own, L[own] - used[own], g)
        out[n] = kin[n] + (0.0 if offsets_rad is None else np.asarray(offsets_rad)[n])
        distal = holes.through
        if distal.index.size:
            used[distal.index] += _hole_lengths(distal, out[n, 0], out[n, 1])
    return kin, out


def angles_from_displacements(
    arm: UJointArm, q_mm: np.ndarray, guess: np.ndarray | None = None
) -> np.ndarray:
    """Ideal forward kinematics: joint angles (N, 2) from cable displacements pulled in (mm)."""
    return angles_from_path_lengths(arm, arm.straight_path_mm - np.asarray(q_mm), guess)[1]


def linearised_angle_error(
    arm: UJointArm, theta: np.ndarray, dq_out_mm: np.ndarray, dtheta_de: np.ndarray | None = None
) -> np.ndarray:
    """First-order joint-angle error (N, 2) from cable-output errors, eq. 13 and 15 (rad).

    Segment by segment: Delta theta_n = J_dn^+ (-dq_own - sum_{i<n} J_{own,i} Delta theta_i),
    where Delta theta_i of a proximal segment includes its deformation ``dtheta_de`` (eq. 15's
    J_dn Delta theta_de,n term). For a single segment this is eq. 13, Delta theta_h = J_d^+ l_h
    (l_h = -dq: a cable that lags while pulled in is longer in the arm).
    """
    J = cable_jacobian(arm, theta)
    dq = np.asarray(dq_out_mm, dtype=float)
    de = np.zeros((arm.n_segments, 2)) if dtheta_de is None else np.asarray(dtheta_de)
    out = np.zeros((arm.n_segments, 2))
    for n in range(arm.n_segments):
        own = arm.own_cables[n]
        rhs = -dq[own]
        for i in range(n):
            rhs = rhs - J[np.ix_(own, [2 * i, 2 * i + 1])] @ out[i]
        out[n] = np.linalg.pinv(J[np.ix_(own, [2 * n, 2 * n + 1])]) @ rhs + de[n]
    return out


# =========================================================================== eq. 1-2
def subjoint_transform(theta_a: float, theta_b: float, seg: UJointSegment) -> np.ndarray:
    """D1 of a sub-joint -> D1 of the next (4x4): Trans(z,d) Rx Ry Trans(z,d) Trans(z,link),
    i.e. rotation R = Rx Ry and translation d e_z + (d + link) R e_z."""
    R = _rotation_rows(theta_a, theta_b, 0).reshape(3, 3)
    d = seg.half_gap_mm
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = (d + seg.link_mm) * R[:, 2]
    T[2, 3] += d
    return T


def segment_transform(theta_a: float, theta_b: float, seg: UJointSegment) -> np.ndarray:
    """T_sn of eq. 2: segment base (first D1) -> segment tip (D1 after the last link), 4x4."""
    S = subjoint_transform(theta_a, theta_b, seg)
    T = S
    for _ in range(seg.n_subjoints - 1):
        T = T @ S
    return T


def tip_transform(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Robot base -> tip (end of the tip link), eq. 1: T_base T_s1 ... T_sN T_tip (4x4, mm)."""
    t = _as_theta(arm, theta)
    T = _trans_z(arm.base_link_mm)
    for n, seg in enumerate(arm.segments):
        T = T @ segment_transform(t[n, 0], t[n, 1], seg)
    return T @ _trans_z(arm.tip_link_mm)


def tip_position(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Tip position in the robot base frame (mm)."""
    return tip_transform(arm, theta)[:3, 3]


def mass_points(arm: UJointArm, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions (K, 3) mm, masses (K,) g) of every moving link and the tip mass, base frame.

    Link i of a segment (after sub-joint i) has its mass at the middle of its tube.
    """
    t = _as_theta(arm, theta)
    pts: list[np.ndarray] = []
    ms: list[float] = []
    T = _trans_z(arm.base_link_mm)
    for n, seg in enumerate(arm.segments):
        R = rot_x(t[n, 0]) @ rot_y(t[n, 1])
        d = seg.half_gap_mm
        for _ in range(seg.n_subjoints):
            T = T @ _trans_z(d) @ _homog(R, (0.0, 0.0, 0.0)) @ _trans_z(d)
            if seg.link_mass_g > 0:
                pts.append(T[:3, :3] @ np.array([0.0, 0.0, 0.5 * seg.link_mm]) + T[:3, 3])
                ms.append(seg.link_mass_g)
            T = T @ _trans_z(seg.link_mm)
    if arm.tip_mass_g > 0:
        pts.append(T[:3, :3] @ np.array([0.0, 0.0, 0.5 * arm.tip_link_mm]) + T[:3, 3])
        ms.append(arm.tip_mass_g)
    if not pts:
        return np.zeros((0, 3)), np.zeros(0)
    return np.array(pts), np.array(ms)


# =========================================================================== dead zone
def dead_zone_mm(
    pretension_N: float, length_mm: float, EA_N: float, friction_exponent_per_mm: float
) -> tuple[float, float]:
    """(pull_mm, release_mm): how far the cable output lags its input while pulled / released.

    Derivation (section 4.1's measurement; NOTES eq. 13-17). The cable of length L runs from the
    input (s = 0) to the output (s = L), where the load holds it at the pretension T0. Friction
    along the path (holes, guides) is capstan-like with kappa = mu * wrap angle per mm, so while
    the input pulls the tension falls towards the output, T(s) = T0 exp(kappa (L - s)), and while
    it releases T(s) = T0 exp(-kappa (L - s)). The output moves by the input minus the change of
    the cable's stretch, integral (T(s) - T0) / EA ds:

        pull:     e_p = T0 / EA * ((exp(kappa L) - 1) / kappa - L)
        release:  e_r = T0 / EA * (L - (1 - exp(-kappa L)) / kappa)

    Sliding while pulled in, output = input - e_p; while released, output = input + e_r; at a
    reversal the output stands still (stick) until the input has travelled the dead zone

        w = e_p + e_r = 2 T0 / (EA kappa) (cosh(kappa L) - 1)   (-> T0 kappa L^2 / EA)

    Both are exactly linear in the pretension T0 (the paper: "linear in pretension"), zero for a
    rigid cable or no friction. :func:`calibrate_friction_exponent` fits kappa to a measured w.
    """
    if pretension_N < 0 or length_mm <= 0 or EA_N <= 0 or friction_exponent_per_mm < 0:
        raise ModelError("dead zone needs pretension >= 0, length > 0, EA > 0, kappa >= 0")
    x = friction_exponent_per_mm * length_mm
    scale = pretension_N * length_mm / EA_N
    if x < 1e-5:  # series: (e^x - 1 - x)/x = x/2 + x^2/6, (x - 1 + e^-x)/x = x/2 - x^2/6
        return scale * (0.5 * x + x * x / 6.0), scale * (0.5 * x - x * x / 6.0)
    return scale * (math.expm1(x) - x) / x, scale * (x + math.expm1(-x)) / x


def dead_zone_width_mm(
    pretension_N: float, length_mm: float, EA_N: float, friction_exponent_per_mm: float
) -> float:
    """Full dead zone at a direction reversal, w = e_p + e_r (mm); see :func:`dead_zone_mm`."""
    p, r = dead_zone_mm(pretension_N, length_mm, EA_N, friction_exponent_per_mm)
    return p + r


def calibrate_friction_exponent(
    width_mm: float, pretension_N: float, length_mm: float, EA_N: float
) -> float:
    """kappa (1/mm) such that :func:`dead_zone_width_mm` gives ``width_mm`` for this cable.

    Solves 2 (cosh x - 1) / x = w EA / (T0 L) for x = kappa L (monotonic in x) by bisection.
    Yang et al. 2022 section 4.1: w = 3.4 mm at T0 = 100 N for L = 2877 mm of 1.2 mm steel cable.
    """
    if not (width_mm > 0 and pretension_N > 0 and length_mm > 0 and EA_N > 0):
        raise ModelError("calibration needs width, pretension, length and EA > 0")
    target = width_mm * EA_N / (pretension_N * length_mm)

    def h(x: float) -> float:
        return 2.0 * (math.cosh(x) - 1.0) / x

    lo, hi = 1e-12, 1.0
    while h(hi) < target:
        hi *= 2.0
        if hi > 700.0:
            raise ModelError("dead zone too large for any friction exponent")
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if h(mid) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi) / length_mm


def play_update(
    q_out_prev_mm: np.ndarray, q_in_mm: np.ndarray, pull_mm: np.ndarray, release_mm: np.ndarray
) -> np.ndarray:
    """Cable output after the dead zone (play operator), per cable (mm pulled in).

    q_out = clip(q_out_prev, q_in - e_p, q_in + e_r): sliding while pulled in the output trails
    by e_p, while released it leads by e_r, in between it sticks (:func:`dead_zone_mm`).
    """
    q_in = np.asarray(q_in_mm, dtype=float)
    return np.clip(np.asarray(q_out_prev_mm, dtype=float), q_in - pull_mm, q_in + release_mm)


def play_inverse(
    q_out_mm: np.ndarray, direction: np.ndarray, pull_mm: np.ndarray, release_mm: np.ndarray
) -> np.ndarray:
    """Input that puts the cable output at ``q_out_mm`` moving in ``direction`` (+1 pull, -1
    release, 0 never moved): q_in = q_out + e_p, q_out - e_r or q_out (inverse of the play)."""
    s = np.asarray(direction, dtype=float)
    return (
        np.asarray(q_out_mm, dtype=float)
        + np.where(s > 0, pull_mm, 0.0)
        - np.where(s < 0, release_mm, 0.0)
    )


# =========================================================================== eq. 14-17
def deformation_rad(
    arm: UJointArm, theta_n: np.ndarray, distal_direction: np.ndarray
) -> np.ndarray:
    """Deformation Delta theta_de (N, 2) of each segment by the drive torque of the distal ones,
    eq. 14 / 16-17 as set out in :class:`DeformationParams` (rad).

    ``theta_n`` (N, 2): the segments' (undeformed) angles; ``distal_direction`` (N, 2):
    sgn(theta_dot) of every segment coordinate (+1, -1, 0), or a friction state in [-1, 1]
    (:func:`segment_friction_direction`). The most distal segment never deforms
    (no cable drives through it).
    """
    p = arm.deformation
    t = np.asarray(theta_n, dtype=float)
    s = np.clip(np.asarray(distal_direction, dtype=float), -1.0, 1.0)  # sgn, or a friction state
    out = np.zeros_like(t)
    if p.kind == "off":
        return out
    for n in range(arm.n_segments - 1):
        for m in range(n + 1, arm.n_segments):
            if p.kind == "proportional":
                out[n] += s[m] * p.eta * np.abs(t[n])
            else:
                out[n] += (
                    s[m]
                    * np.abs(np.sign(t[n]))
                    * (p.friction_torque_Nmm[m] / p.stiffness_Nmm_per_rad[n])
                )
    return out


def undeform(arm: UJointArm, theta_target: np.ndarray, distal_direction: np.ndarray) -> np.ndarray:
    """Angles theta_kin with theta_kin + deformation(theta_kin) = ``theta_target`` (N, 2).

    Proportional: theta = theta_kin (1 + eta sgn(theta_kin) sum_m sgn(theta_dot_m)); theta_kin
    has the sign of theta (eta (N - 1) < 1), so theta_kin = theta / (1 + eta sgn(theta) sum_m
    sgn(theta_dot_m)). Torque: theta_kin = theta - sum_m sgn(theta_dot_m) tau_m / k_n where
    theta != 0 (exact when |theta| exceeds the deformation, below which eq. 14 itself jumps).
    """
    p = arm.deformation
    t = np.asarray(theta_target, dtype=float)
    if p.kind == "off":
        return t.copy()
    s = np.sign(np.asarray(distal_direction, dtype=float))
    out = t.copy()
    for n in range(arm.n_segments - 1):
        drive = sum(s[m] for m in range(n + 1, arm.n_segments))
        if p.kind == "proportional":
            out[n] = t[n] / (1.0 + p.eta * np.sign(t[n]) * drive)
        else:
            out[n] = t[n] - np.abs(np.sign(t[n])) * sum(
                s[m] * p.friction_torque_Nmm[m] / p.stiffness_Nmm_per_rad[n]
                for m in range(n + 1, arm.n_segments)
            )
    return out


def motion_direction(
    new: np.ndarray, old: np.ndarray | None, last: np.ndarray, hold: bool, eps: float
) -> np.ndarray:
    """sgn of (new - old) element-wise; where |new - old| <= eps: the last sign if ``hold`` else 0
    (eq. 17: eta = 0 while theta_dot = 0). ``old`` None (first call): all 0."""
    if old is None:
        return np.zeros_like(np.asarray(new, dtype=float))
    diff = np.asarray(new, dtype=float) - np.asarray(old, dtype=float)
    sign = np.where(np.abs(diff) > eps, np.sign(diff), 0.0)
    if hold:
        sign = np.where(sign == 0.0, last, sign)
    return sign


def cable_friction_state(
    q_in_mm: np.ndarray, q_out_mm: np.ndarray, pull_mm: np.ndarray, release_mm: np.ndarray
) -> np.ndarray:
    """Where each cable is in its dead zone, sigma in [-1, 1] (the sign and share of the full
    sliding friction it carries): +1 sliding while pulled in (q_in - q_out = e_p), -1 while
    released (q_in - q_out = -e_r), linear in between (stick: the friction force builds up
    along the cable as the input crosses the dead zone, :func:`dead_zone_mm`). A cable with no
    dead zone: 0."""
    half = 0.5 * (np.asarray(pull_mm) + np.asarray(release_mm))
    mid = 0.5 * (np.asarray(pull_mm) - np.asarray(release_mm))
    lag = np.asarray(q_in_mm, dtype=float) - np.asarray(q_out_mm, dtype=float)
    safe = np.where(half > 0, half, 1.0)
    return np.where(half > 0, np.clip((lag - mid) / safe, -1.0, 1.0), 0.0)


def segment_friction_direction(arm: UJointArm, theta: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Per segment and coordinate, the direction of its cables' friction torque (N, 2) in
    [-1, 1], the continuous stand-in for sgn(theta_dot_m) of eq. 14/17.

    A cable k pulled in (q_dot > 0) moves the segment with J_k . theta_dot < 0 (its path
    shortens, J = :func:`segment_cable_jacobian`), so sliding along theta_dot_j > 0 gives
    sigma_k = -sgn(J_kj) for the cables that carry coordinate j, and
    s_j = -(J^T sigma)_j / sum_k |J_kj| = +1; sliding back gives -1; in between (cables in their
    dead zone) s moves smoothly; at rest after a move it keeps its value (static friction).
    """
    t = np.asarray(theta, dtype=float)
    out = np.zeros((arm.n_segments, 2))
    for n, holes in enumerate(arm.hole_sets):
        _, g, _ = _hole_terms(holes.own, t[n, 0], t[n, 1])  # g = J^T (2, K)
        norm = np.abs(g).sum(axis=1)
        out[n] = np.where(
            norm > 0, -(g @ sigma[holes.own.index]) / np.where(norm > 0, norm, 1.0), 0.0
        )
    return np.clip(out, -1.0, 1.0)


# =========================================================================== statics
def _potential_batch(arm: UJointArm, thetas: np.ndarray) -> np.ndarray:
    """Gravity potential (B,) of B poses (B, N, 2) at once: the chain of :func:`mass_points`
    with batched 4x4 products (the finite differences below evaluate many poses)."""
    th = np.asarray(thetas, dtype=float)
    B = th.shape[0]
    g = np.asarray(arm.gravity_mm_s2, dtype=float)
    T = np.broadcast_to(np.eye(4), (B, 4, 4)).copy()
    T[:, 2, 3] = arm.base_link_mm
    V = np.zeros(B)
    for n, seg in enumerate(arm.segments):
        ca, sa = np.cos(th[:, n, 0]), np.sin(th[:, n, 0])
        cb, sb = np.cos(th[:, n, 1]), np.sin(th[:, n, 1])
        A = np.zeros((B, 4, 4))
        # Rx(a) Ry(b)
        A[:, 0, 0], A[:, 0, 2] = cb, sb
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2] = sa * sb, ca, -sa * cb
        A[:, 2, 0], A[:, 2, 1], A[:, 2, 2] = -ca * sb, sa, ca * cb
        A[:, 3, 3] = 1.0
        d = seg.half_gap_mm
        A[:, :3, 3] = d * A[:, :3, 2]
        A[:, 2, 3] += d  # Trans(z, d) R Trans(z, d)
        for _ in range(seg.n_subjoints):
            T = T @ A
            if seg.link_mass_g > 0:
                p = T[:, :3, 3] + 0.5 * seg.link_mm * T[:, :3, 2]
                V -= seg.link_mass_g * 1e-6 * (p @ g)
            T[:, :3, 3] += seg.link_mm * T[:, :3, 2]
    if arm.tip_mass_g > 0:
        p = T[:, :3, 3] + 0.5 * arm.tip_link_mm * T[:, :3, 2]
        V -= arm.tip_mass_g * 1e-6 * (p @ g)
    return V


def gravity_potential_Nmm(arm: UJointArm, theta: np.ndarray) -> float:
    """Gravity potential V = -sum m g . p of the moving links and tip mass (N*mm).

    Masses in g (* 1e-3 -> kg), gravity in mm/s^2 (* 1e-3 -> m/s^2), positions in mm.
    """
    return float(_potential_batch(arm, _as_theta(arm, theta)[None])[0])


def _has_gravity(arm: UJointArm) -> bool:
    return any(g != 0.0 for g in arm.gravity_mm_s2)


def gravity_torque(arm: UJointArm, theta: np.ndarray) -> np.ndarray:
    """Generalised gravity force Q = -dV/dtheta (2N,), N*mm per rad of sub-joint angle.

    Central differences of the potential (step :data:`GRAVITY_FD_STEP_RAD`).
    """
    t = _as_theta(arm, theta).ravel()
    n = t.size
    if not _has_gravity(arm):
        return np.zeros(n)
    E = np.eye(n) * GRAVITY_FD_STEP_RAD
    X = np.concatenate((t + E, t - E)).reshape(2 * n, -1, 2)
    V = _potential_batch(arm, X)
    return -(V[:n] - V[n:]) / (2.0 * GRAVITY_FD_STEP_RAD)


def gravity_hessian(arm: UJointArm, theta: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """d^2 V / dtheta^2 (2N x 2N, N*mm/rad^2) by the four-point stencil (the gravity stiffness,
    negative where gravity destabilises, e.g. an upright arm)."""
    t = _as_theta(arm, theta).ravel()
    return _fd_hessian(lambda X: _potential_batch(arm, X.reshape(X.shape[0], -1, 2)), t, h)


def _fd_hessian(potential: object, x: np.ndarray, h: float) -> np.ndarray:
    n = x.size
    pairs = [(j, k) for j in range(n) for k in range(j, n)]
    X = []
    for j, k in pairs:
        for sj, sk in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            y = x.copy()
            y[j] += sj * h
            y[k] += sk * h
            X.append(y)
    V = potential(np.array(X))  # type: ignore[operator]
    H = np.zeros((n, n))
    for p, (j, k) in enumerate(pairs):
        v = V[4 * p : 4 * p + 4]
        H[j, k] = H[k, j] = (v[0] - v[1] - v[2] + v[3]) / (4.0 * h * h)
    return H


def statics_angles(arm: UJointArm, theta_pre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Small-deflection equilibrium of the cable-held arm under gravity (N, 2) and cable tensions.

    The drives fix each cable's free length so that at ``theta_pre`` (the kinematic pose, from the
    cable lengths) every cable carries its pretension T0. Away from it, cable k stretches by
    J_k dtheta (J = :func:`cable_jacobian`) with stiffness k_k = EA / L_total, and the sub-joints
    have no elastic element of their own. Stationarity of
    V = sum_k [T0_k L_k(theta) + k_k/2 (L_k(theta) - L_k(theta_pre))^2] + V_gravity(theta):

        (J^T diag(k) J + K_g) dtheta = Q(theta_pre + dtheta) - J^T T0,
        K_g = sum_k T0_k d^2 L_k / dtheta^2   (geometric stiffness of the pretension,
                                               :func:`cable_jacobian_hessian`)

    with the cable lengths linearised at theta_pre and the gravity moment Q (:func:`gravity_torque`)
    taken at the sagged pose (quasi-Newton with the gravity stiffness of
    :func:`gravity_hessian`). A cable whose tension T0 + k J dtheta would go negative is slack and
    drops out (active set). Raises :class:`ModelError` if the equilibrium is not stable (the
    pretension or gravity buckles the arm, or slack cables leave a segment unheld).
    Returns (theta, tensions_N).
    """
    t0 = _as_theta(arm, theta_pre).ravel()
    J, L_hess = cable_jacobian_hessian(arm, t0.reshape(-1, 2))  # d^2 L_k / dtheta^2 per cable
    n = t0.size
    if _has_gravity(arm):
        H = gravity_hessian(arm, t0.reshape(-1, 2))

        def Q(x: np.ndarray) -> np.ndarray:
            return gravity_torque(arm, x.reshape(-1, 2))
    else:
        H = np.zeros((n, n))

        def Q(x: np.ndarray) -> np.ndarray:
            return np.zeros(n)

    x, tension = small_deflection(
        t0,
        J,
        arm.cable_stiffness_N_per_mm,
        arm.pretension_N,
        L_hess,
        np.zeros((n, n)),
        np.zeros(n),
        Q,
        H,
    )
    return x.reshape(-1, 2), tension


def small_deflection(
    x0: np.ndarray,
    J: np.ndarray,
    k: np.ndarray,
    T0: np.ndarray,
    L_hess: np.ndarray,
    K_rest: np.ndarray,
    f_rest: np.ndarray,
    Q: object,
    H: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve F(dx) = (J_a^T k_a J_a + K_g,a + K_rest) dx + J_a^T T0_a + f_rest - Q(x0 + dx) = 0.

    J_a, k_a, T0_a: the taut cables (tension T0 + k J dx >= 0; active set updated every
    iteration); K_g,a = sum over them of T0_k ``L_hess[k]`` (a slack cable loses its pretension
    and its geometric stiffness). Quasi-Newton with the fixed Jacobian K + H (H: the gravity
    Hessian at x0); raises :class:`ModelError` when K + H is not positive definite (no stable
    equilibrium).
    """
    active = np.ones(T0.shape, dtype=bool)  # every cable taut (a zero pretension too)
    dx = np.zeros_like(x0)
    n = x0.size
    # K, (K + H)^-1 and the pretension moment depend on the active set only: built (and the
    # stability checked) once per active set met
    built: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for _ in range(STATICS_MAX_ITER):
        key = active.tobytes()
        if key not in built:
            Ja, Ta, ka, La = J[active], T0[active], k[active], L_hess[active]
            Kg = (Ta @ La.reshape(Ta.size, n * n)).reshape(n, n)
            K = Ja.T @ (ka[:, None] * Ja) + Kg + K_rest
            A = K + H
            if np.linalg.eigvalsh(0.5 * (A + A.T)).min() <= 0.0:
                raise ModelError(
                    "statics: no stable equilibrium (slack cables, or pretension or "
                    "gravity buckling the arm)"
                )
            built[key] = (K, np.linalg.inv(A), Ja.T @ Ta + f_rest)
        K, A_inv, f0 = built[key]
        F = K @ dx + f0 - Q(x0 + dx)  # type: ignore[operator]
        step = A_inv @ F
        dx = dx - step
        new_active = (T0 + k * (J @ dx)) >= 0.0
        if (new_active == active).all() and float(np.abs(step).max()) < STATICS_TOL_RAD:
            break
        active = new_active
    else:
        raise ModelError("statics did not converge")
    tension = np.where(active, T0 + k * (J @ dx), 0.0)
    return x0 + dx, tension


def statics_inverse(
    arm: UJointArm,
    theta_target: np.ndarray,
    guess: np.ndarray | None = None,
    max_evals: int | None = None,
) -> np.ndarray:
    """theta_pre with :func:`statics_angles` (theta_pre) = ``theta_target`` (fixed point, N x 2).

    theta_pre <- theta_pre + (theta_target - statics(theta_pre)) from ``guess`` (default the
    target): the sag is small and smooth, so the iteration contracts by about |d sag/d theta|
    (~1e-2) per step. ``max_evals`` None: iterate to :data:`STATICS_TOL_RAD` (raises
    :class:`ModelError` if it does not get there); an integer: exactly that many statics
    evaluations (the control loop warm-starts from the last offset and takes one: its error is
    |d sag/d theta| times the change of the offset since the last tick).
    """
    target = _as_theta(arm, theta_target)
    pre = target.copy() if guess is None else np.array(guess, dtype=float)
    limit = STATICS_MAX_ITER if max_evals is None else max_evals
    for _ in range(limit):
        err = target - statics_angles(arm, pre)[0]
        pre = pre + err
        if max_evals is None and float(np.max(np.abs(err))) < STATICS_TOL_RAD:
            return pre
    if max_evals is None:
        raise ModelError("statics inverse did not converge (sag too large for small deflection)")
    return pre


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
