"""Parameters of the constant-curvature disk robot (Qi et al. 2023) and the switchable effects.

Plain frozen dataclasses: the model never sees the YAML/pydantic config
(:func:`cdcr_ctl.config.build_model.robot_params` builds these from a validated ``RigConfig``).
The simulator's truth and the controller hold the same structures with different values.

Units: mm, N, rad, g (disk mass), N*mm^2 (EI), N (EA), mm/s^2 (gravity).
Frames: the robot base frame has z along the straight backbone and x towards the hole at angle 0.
Every disk frame of the constant-curvature chain (eq. 1) carries no net twist, so one hole angle
per cable holds in every disk it passes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from cdcr_ctl.errors import ModelError

Location = Literal["robot_base", "actuator"]
Geometry = Literal["cc", "chord"]


@dataclass(frozen=True)
class SegmentParams:
    """One bending segment, base to tip.

    ``n_disks`` spacer disks are equally spaced after the segment's base disk, the last one is the
    segment's tip disk (the base disk of segment 1 is the robot base; the base disk of segment i>1
    is the tip disk of segment i-1). ``disk_mass_g`` is the mass of each of those disks.
    """

    name: str
    length_mm: float
    EI_Nmm2: float
    n_disks: int
    disk_mass_g: float = 0.0
    disk_thickness_mm: float = 0.0

    def __post_init__(self) -> None:
        if not (self.length_mm > 0 and self.EI_Nmm2 > 0 and self.n_disks >= 1):
            raise ModelError(f"segment {self.name}: length, EI and disk count must be positive")
        if self.disk_mass_g < 0 or self.disk_thickness_mm < 0:
            raise ModelError(f"segment {self.name}: disk mass and thickness must be >= 0")


@dataclass(frozen=True)
class PulleyParams:
    """A guide pulley: radius R (mm), cable wrap (rad), friction law f = alpha N^n (eq. 25)."""

    name: str
    radius_mm: float
    wrap_angle_rad: float
    alpha: float
    n: float = 1.0

    def __post_init__(self) -> None:
        if not (self.radius_mm > 0 and self.wrap_angle_rad >= 0 and self.alpha >= 0):
            raise ModelError(f"pulley {self.name}: radius > 0, wrap >= 0, alpha >= 0 required")
        if not 0 < self.n <= 1:
            raise ModelError(f"pulley {self.name}: n must be in (0, 1] (eq. 25)")


@dataclass(frozen=True)
class CableParams:
    """One drive cable from its actuator, through ``pulleys`` (actuator -> robot order) and the disk
    holes, to the tip disk of segment ``segment`` (0-based index) where it is anchored.

    ``hole_angle_rad`` (gamma_k) and ``routing_radius_mm`` (r_k) place the hole in every disk frame.
    ``EA_N`` is the axial stiffness; ``math.inf`` means a rigid cable. ``free_length_mm`` is the
    straight cable between actuator and robot base, split equally over the straight runs between
    actuator, pulleys and base.
    """

    name: str
    segment: int
    hole_angle_rad: float
    routing_radius_mm: float
    diameter_mm: float
    EA_N: float
    pretension_N: float
    mu_disk: float = 0.0
    free_length_mm: float = 0.0
    pulleys: tuple[PulleyParams, ...] = ()
    backlash_mm: float = 0.0

    def __post_init__(self) -> None:
        if not (self.routing_radius_mm > 0 and self.diameter_mm > 0 and self.EA_N > 0):
            raise ModelError(f"cable {self.name}: radius, diameter and EA must be positive")
        if self.pretension_N < 0 or self.mu_disk < 0 or self.free_length_mm < 0:
            raise ModelError(f"cable {self.name}: pretension, mu and free length must be >= 0")
        if not (self.backlash_mm >= 0 and math.isfinite(self.backlash_mm)):
            raise ModelError(f"cable {self.name}: backlash_mm must be finite and >= 0")


@dataclass(frozen=True)
class RobotParams:
    """The whole robot: segments base to tip, cables, gravity in the base frame (mm/s^2).

    Tip load (a payload or a tool at the tip disk of the last segment): ``tip_mass_g`` (g, its
    weight m g acts at the tip with the gravity vector) and ``tip_force_N`` (N, base frame, a
    force at the tip, e.g. a contact or a tether). Both enter the statics as the generalised
    force J_tip^T F of the tip point (Qi et al. 2023 eq. 7-9, external load W_e).
    """

    segments: tuple[SegmentParams, ...]
    cables: tuple[CableParams, ...]
    gravity_mm_s2: tuple[float, float, float] = (0.0, 0.0, -9810.0)
    tip_mass_g: float = 0.0
    tip_force_N: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        S = len(self.segments)
        if S == 0 or not self.cables:
            raise ModelError("a robot needs at least one segment and one cable")
        for c in self.cables:
            if not 0 <= c.segment < S:
                raise ModelError(f"cable {c.name}: segment index {c.segment} not in 0..{S - 1}")
        for i, seg in enumerate(self.segments):
            if not any(c.segment == i for c in self.cables):
                raise ModelError(f"segment {seg.name}: no cable ends in it")
        if len(self.gravity_mm_s2) != 3:
            raise ModelError("gravity_mm_s2 must have 3 components")
        if not (self.tip_mass_g >= 0 and math.isfinite(self.tip_mass_g)):
            raise ModelError("tip_mass_g must be finite and >= 0")
        if len(self.tip_force_N) != 3 or not all(math.isfinite(f) for f in self.tip_force_N):
            raise ModelError("tip_force_N must be 3 finite components (N, base frame)")

    @property
    def has_tip_force(self) -> bool:
        """True when a tip force (not the payload's weight) acts."""
        return any(f != 0.0 for f in self.tip_force_N)

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    @property
    def n_cables(self) -> int:
        return len(self.cables)

    def cables_of(self, segment: int) -> tuple[int, ...]:
        """Indices of the cables anchored at the tip of ``segment``."""
        return tuple(k for k, c in enumerate(self.cables) if c.segment == segment)

    @property
    def lengths_mm(self) -> np.ndarray:
        return np.array([s.length_mm for s in self.segments])


@runtime_checkable
class ActuatorEffect(Protocol):
    """A transmission effect between the actuator and the cable leaving it (backlash, scale error).

    The simulator applies :meth:`to_cable` (what the cable sees for an actuator position); the
    compensation applies :meth:`to_actuator` (the actuator position that gives a wanted cable
    displacement). Both are in mm pulled in, shape (K,); ``state`` is the effect's own memory
    (from :meth:`new_state`, mutated in place by stateful effects), ``None`` for stateless ones.
    """

    def new_state(self, n_cables: int) -> object: ...

    def to_cable(self, q_act_mm: np.ndarray, state: object) -> np.ndarray: ...

    def to_actuator(self, q_cable_mm: np.ndarray, state: object) -> np.ndarray: ...


@dataclass(frozen=True)
class Effects:
    """Which physical effects the model includes, and the model's numerical parameters.

    ``disk_friction``: capstan friction in the disk holes (eq. 16-24).
    ``pulley_friction``: improved capstan on the guide pulleys (eq. 25-32).
    ``elongation``: elastic cables (eq. 33-36); off means rigid cables (delta = 0).
    ``coupling``: distal cables load proximal segments (eq. 11-15); off solves each segment alone.
    ``gravity``: disk weights as generalised forces.
    ``geometry``: ``"cc"`` cable displacement of eq. 4 (continuous routing), ``"chord"`` the exact
    straight spans between disk holes (eq. 20-22 geometry).
    ``actuator``: further transmission effects (:class:`ActuatorEffect`, one class per effect, e.g.
    backlash or a scale error), listed from the actuator outwards: the simulator applies their
    ``to_cable`` in this order, the compensation their ``to_actuator`` in reverse order.
    ``capstan_points``: size of the load-time tension table of each pulley (eq. 29).
    ``coupling_gain``: weight lambda of the distal cables' load on the proximal segments when
    ``coupling`` is on (1: eq. 11-15 as derived; the discrepancy workflow may fit another).
    """

    disk_friction: bool = True
    pulley_friction: bool = True
    elongation: bool = True
    coupling: bool = True
    gravity: bool = True
    geometry: Geometry = "cc"
    actuator: tuple[ActuatorEffect, ...] = field(default=())
    capstan_points: int = 121
    coupling_gain: float = 1.0

    @classmethod
    def none(cls) -> Effects:
        """Ideal robot: rigid cables, no friction, no gravity, decoupled segments."""
        return cls(
            disk_friction=False,
            pulley_friction=False,
            elongation=False,
            coupling=False,
            gravity=False,
        )


def cable_radius_mm(cable: CableParams) -> float:
    """r_s of eq. 29: half the cable diameter (mm)."""
    return 0.5 * cable.diameter_mm


def is_rigid(cable: CableParams, effects: Effects) -> bool:
    """True when the cable does not stretch in this model (elongation off or EA infinite)."""
    return (not effects.elongation) or math.isinf(cable.EA_N)
