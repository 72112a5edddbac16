"""Parameters of the universal-joint arm (Yang et al. 2022): segments, cables, the lead-screw drive
(eq. 3), the deformation model's parameters (eq. 14, 16-17), the per-segment hole sets, the
simulator's effects switches, and the solvers' constants.

Units: mm, N, rad, g, N*mm. Pure data, no physics beyond eq. 3 and derived properties.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.ujoint.deadzone import dead_zone_mm

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
