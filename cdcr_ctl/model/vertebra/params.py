"""Parameters of the vertebra arm (fuel-tank vertebra robot paper): joints, cables, the linear
modules (eq. 9), the arm with its derived per-cable arrays, and the solvers' constants.

Units: mm, N, rad, g, N*mm^2 (EI), mm/s^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
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
