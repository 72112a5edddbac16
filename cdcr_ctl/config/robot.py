"""Robot section of the rig config: segments, cables, pulleys, gravity.

Frames: the robot base frame has z along the straight backbone, x towards the hole at angle 0.
Hole angles are measured about z from x, in every disk (the constant-curvature frames of Qi et al.
2023 eq. 1 carry no net twist, so one angle per cable holds along the whole robot).
Units are in the key names: mm, N, rad, MPa (= N/mm^2), g.
"""

from __future__ import annotations

import math
from typing import Annotated

from pydantic import Field, model_validator

from cdcr_ctl.config.base import Section
from cdcr_ctl.model.cc_disk.friction_shape import BREAKAWAY_MM_S

PositiveFloat = Annotated[float, Field(gt=0)]
NonNegativeFloat = Annotated[float, Field(ge=0)]
Name = Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")]


class BackboneConfig(Section):
    """Elastic backbone of one segment: give ``EI_Nmm2`` or both ``E_MPa`` and ``diameter_mm``."""

    E_MPa: PositiveFloat | None = None
    diameter_mm: PositiveFloat | None = None
    EI_Nmm2: PositiveFloat | None = None

    @model_validator(mode="after")
    def _one_stiffness(self) -> BackboneConfig:
        has_ed = self.E_MPa is not None and self.diameter_mm is not None
        if self.EI_Nmm2 is None and not has_ed:
            raise ValueError("give EI_Nmm2, or both E_MPa and diameter_mm")
        if self.EI_Nmm2 is not None and (self.E_MPa is not None or self.diameter_mm is not None):
            raise ValueError("give EI_Nmm2 or E_MPa + diameter_mm, not both")
        return self

    @property
    def EI(self) -> float:
        """Bending stiffness E*I in N*mm^2 (solid round rod: I = pi d^4 / 64)."""
        if self.EI_Nmm2 is not None:
            return self.EI_Nmm2
        assert self.E_MPa is not None and self.diameter_mm is not None  # checked by validator
        return self.E_MPa * math.pi * self.diameter_mm**4 / 64.0


class DisksConfig(Section):
    """Spacer disks of a segment, equally spaced; ``count`` disks after the base disk."""

    count: Annotated[int, Field(ge=1, le=200)]
    #: Mass of each disk (gravity in the statics).
    mass_g: NonNegativeFloat = 0.0
    #: Thickness of each disk along the backbone.
    thickness_mm: NonNegativeFloat = 0.0


class SegmentConfig(Section):
    """One bending segment, base to tip. ``length_mm`` is the backbone arc length."""

    #: The segment's name, which cables name in ``segment``.
    name: Name
    length_mm: PositiveFloat
    backbone: BackboneConfig
    disks: DisksConfig


class PulleyConfig(Section):
    """A guide pulley between actuator and robot base (Qi et al. 2023 eq. 25-32).

    ``alpha`` and ``n`` are the non-linear friction law f = alpha * N^n (eq. 25); n = 1 and
    alpha = mu is Amontons' law. ``wrap_angle_rad`` is the contact angle of the cable on the pulley.
    """

    #: The pulley's name, which cables list in ``pulleys``.
    name: Name
    #: Pulley radius.
    radius_mm: PositiveFloat
    wrap_angle_rad: Annotated[float, Field(ge=0, le=2 * math.pi)]
    alpha: NonNegativeFloat
    n: Annotated[float, Field(gt=0, le=1)] = 1.0


class CableConfig(Section):
    """One drive cable, from its actuator through pulleys and disk holes to the disk it ends on.

    ``segment`` names the segment whose tip disk the cable is fixed to; it runs through every
    proximal segment. ``pulleys`` lists pulley names from the actuator towards the robot.
    ``free_length_mm`` is the straight cable between actuator and robot base (it stretches too).
    ``mu_disk`` is the Coulomb friction coefficient in the disk holes (eq. 16-24).
    Give the axial stiffness as ``E_MPa`` (with ``diameter_mm``, solid section) or ``EA_N``.
    ``backlash_mm`` is the lost motion between drive and cable (total width of the dead zone a
    reversal crosses: slack, sheath, gear play; Yang et al. 2022 eq. 13-17), mm; the
    controller's command pre-travels it at every reversal, ``cdcr-ctl identify`` fits it.
    """

    #: The cable's name, which drives and load cells name in ``cable``.
    name: Name
    segment: Name
    #: Angle of the cable's hole about the base z axis, from x (same in every disk).
    hole_angle_rad: Annotated[float, Field(ge=-2 * math.pi, le=2 * math.pi)]
    #: Distance of the hole from the backbone axis.
    routing_radius_mm: PositiveFloat
    diameter_mm: PositiveFloat
    E_MPa: PositiveFloat | None = None
    EA_N: PositiveFloat | None = None
    #: Tension of the cable at the straight pose.
    pretension_N: NonNegativeFloat
    mu_disk: NonNegativeFloat = 0.0
    free_length_mm: NonNegativeFloat = 0.0
    pulleys: list[Name] = Field(default_factory=list)
    backlash_mm: Annotated[float, Field(ge=0, le=20)] = 0.0

    @model_validator(mode="after")
    def _one_axial_stiffness(self) -> CableConfig:
        if (self.E_MPa is None) == (self.EA_N is None):
            raise ValueError("give exactly one of E_MPa or EA_N")
        return self

    @property
    def EA(self) -> float:
        """Axial stiffness E*A in N (solid round section of ``diameter_mm``)."""
        if self.EA_N is not None:
            return self.EA_N
        assert self.E_MPa is not None
        return self.E_MPa * math.pi * self.diameter_mm**2 / 4.0


#: Largest payload (kg) and tip force (N) a config may name: 5 kg / 100 N are above any load a
#: continuum arm of this controller carries (the shipped rigs bend under 2-10 g at the tip);
#: beyond them the value is a typo (grams written as kg), not a rig.
TIP_PAYLOAD_MAX_KG = 5.0
TIP_FORCE_MAX_N = 100.0


class TipLoadConfig(Section):
    """A load at the tip disk of the last segment (a camera, a tool, a tether).

    ``payload_kg``: a point mass at the tip, kg; its weight acts along ``robot.gravity_mm_s2``.
    ``force_N``: a force at the tip in the robot base frame, N (x, y, z). Both enter the statics
    and the compensation as the generalised force J_tip^T F (Qi et al. 2023 eq. 7-9, W_e).
    """

    payload_kg: Annotated[float, Field(ge=0, le=TIP_PAYLOAD_MAX_KG, allow_inf_nan=False)] = 0.0
    force_N: Annotated[
        list[Annotated[float, Field(ge=-TIP_FORCE_MAX_N, le=TIP_FORCE_MAX_N, allow_inf_nan=False)]],
        Field(min_length=3, max_length=3),
    ] = Field(default_factory=lambda: [0.0, 0.0, 0.0])


#: Largest wrap exponent of the disk friction law: with p = 4 the friction at 2 rad of wrap is
#: 8 x the capstan law's; beyond it no hole of a disk robot rubs, the value is a typo.
WRAP_EXPONENT_MAX = 4.0
#: Largest Stribeck speed (mm/s): a breakaway that lasts up to 1 m/s of cable speed is no stick.
STRIBECK_MAX_MM_S = 1000.0


class FrictionLawConfig(Section):
    """The disk-hole friction law (cdcr_ctl/model/cc_disk/friction_law.py); the defaults are the
    capstan law of Qi et al. 2023 eq. 16-24, ln(T(z)/T_anchor) = s mu_disk z.

    With other values: ln(T(z)/T_anchor) = s mu_disk m(v) (z / 1 rad)^p, the wrap z (rad)
    accumulated from the cable's anchor, p = ``wrap_exponent``, m(v) = 1 + ``viscous_s_per_mm``
    v + ``breakaway`` exp(-(v / ``stribeck_mm_s``)^2), v the cable's speed (mm/s). The
    compensation and the discrepancy workflow's model both use it; ``cdcr-ctl discrepancy
    --apply`` writes it when it names the ``friction_law`` effect.
    """

    #: p: > 1 the holes near the base (more wrap behind them) rub more; < 1 those near the tip.
    wrap_exponent: Annotated[float, Field(gt=0, le=WRAP_EXPONENT_MAX, allow_inf_nan=False)] = 1.0
    #: c_v: friction growing with the cable's speed, per mm/s.
    viscous_s_per_mm: Annotated[float, Field(ge=0, le=5, allow_inf_nan=False)] = 0.0
    #: b: the static excess at rest, a fraction of mu_disk.
    breakaway: Annotated[float, Field(ge=0, le=4, allow_inf_nan=False)] = 0.0
    #: v_b: the cable speed over which the breakaway excess decays (mm/s).
    stribeck_mm_s: Annotated[float, Field(gt=0, le=STRIBECK_MAX_MM_S, allow_inf_nan=False)] = (
        BREAKAWAY_MM_S
    )


class RobotConfig(Section):
    """The robot: segments base to tip, cables, guide pulleys, gravity and the tip load.

    ``gravity_mm_s2`` is gravity in the base frame, any direction (a mount turned sideways or
    upside down is a gravity vector along x or +z); ``tip_load`` the payload and tip force.
    ``friction_law``: the law of every cable's disk-hole friction (``mu_disk`` its coefficient).
    """

    segments: Annotated[list[SegmentConfig], Field(min_length=1)]
    cables: Annotated[list[CableConfig], Field(min_length=1)]
    pulleys: list[PulleyConfig] = Field(default_factory=list)
    #: Gravity in the robot base frame (mm/s^2): straight down for a robot mounted upright; ``cdcr-
    #: ctl identify`` fits its direction (the mount tilt).
    gravity_mm_s2: Annotated[list[float], Field(min_length=3, max_length=3)] = Field(
        default_factory=lambda: [0.0, 0.0, -9810.0]
    )
    tip_load: TipLoadConfig = Field(default_factory=TipLoadConfig)
    friction_law: FrictionLawConfig = Field(default_factory=FrictionLawConfig)
