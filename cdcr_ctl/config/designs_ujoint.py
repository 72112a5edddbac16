"""The ``ujoint:`` section of a ``design: ujoint`` rig config (universal-joint segments, Yang
et al. 2022: lead-screw drive eq. 3, dead zone of section 4.1, deformation eq. 14, 16-17), its
cross-section checks and the model builder :func:`ujoint_arm`
(:class:`cdcr_ctl.model.ujoint.UJointArm`). How the shared ``robot:`` section reads for this
design: :mod:`cdcr_ctl.config.designs`."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.designs_common import LENGTH_TOL_MM, _check_counts, _raise_problems
from cdcr_ctl.config.keys import KeyPath
from cdcr_ctl.config.robot import NonNegativeFloat, PositiveFloat
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.model.ujoint import (
    DeformationParams,
    LeadScrewDrive,
    UJointArm,
    UJointCable,
    UJointSegment,
    calibrate_friction_exponent,
)


class LeadScrewDriveConfig(Section):
    """Motor -> lead screw -> moving pulley (Yang et al. 2022 eq. 3).

    ``lead_mm`` S per screw turn; ``gear_ratio`` lambda; ``gear_ratio_kind``: ``reduction`` (motor
    turns lambda times per screw turn: lambda divides) or ``multiplier`` (screw turns per motor
    turn: lambda multiplies, eq. 3 as printed); ``pulley_factor``: cable per nut travel (2 for
    the moving pulley). ``encoder_counts_per_rev``: motor encoder counts per motor turn; when
    given, every drive's ``counts_per_mm`` must match it (:func:`check_design`).
    """

    lead_mm: PositiveFloat
    gear_ratio: PositiveFloat = 1.0
    gear_ratio_kind: Literal["reduction", "multiplier"] = "reduction"
    pulley_factor: PositiveFloat = 2.0
    encoder_counts_per_rev: PositiveFloat | None = None


class DeadZoneCalibrationConfig(Section):
    """A measured dead zone (Yang section 4.1) from which kappa is fitted at load time.

    ``width_mm`` at ``pretension_N`` for ``length_mm`` of cable with axial stiffness ``EA_N`` (or
    ``E_MPa`` and ``diameter_mm``, solid section).
    """

    width_mm: PositiveFloat
    pretension_N: PositiveFloat
    length_mm: PositiveFloat
    diameter_mm: PositiveFloat | None = None
    E_MPa: PositiveFloat | None = None
    EA_N: PositiveFloat | None = None

    @model_validator(mode="after")
    def _one_stiffness(self) -> DeadZoneCalibrationConfig:
        has_ed = self.E_MPa is not None and self.diameter_mm is not None
        if (self.EA_N is None) == (not has_ed):
            raise ValueError("give EA_N, or E_MPa with diameter_mm (not both)")
        return self

    @property
    def EA(self) -> float:
        if self.EA_N is not None:
            return self.EA_N
        assert self.E_MPa is not None and self.diameter_mm is not None
        return self.E_MPa * math.pi * self.diameter_mm**2 / 4.0

    @property
    def friction_exponent_per_mm(self) -> float:
        return calibrate_friction_exponent(
            self.width_mm, self.pretension_N, self.length_mm, self.EA
        )


class DeadZoneConfig(Section):
    """Cable dead zone at direction reversal: give ``friction_exponent_per_mm`` (kappa, 1/mm) or a
    ``calibration`` measurement it is fitted to (:func:`cdcr_ctl.model.ujoint.dead_zone_mm`)."""

    friction_exponent_per_mm: NonNegativeFloat | None = None
    calibration: DeadZoneCalibrationConfig | None = None

    @model_validator(mode="after")
    def _one_source(self) -> DeadZoneConfig:
        if (self.friction_exponent_per_mm is None) == (self.calibration is None):
            raise ValueError("give exactly one of friction_exponent_per_mm or calibration")
        return self

    @property
    def kappa_per_mm(self) -> float:
        if self.friction_exponent_per_mm is not None:
            return self.friction_exponent_per_mm
        assert self.calibration is not None
        return self.calibration.friction_exponent_per_mm


class DeformationConfig(Section):
    """Proximal deformation by the distal drive torque (Yang eq. 14, 16-17).

    ``kind``: ``proportional`` (eq. 16, ``eta``), ``torque`` (eq. 14, one ``friction_torque_Nmm``
    tau_f and one ``stiffness_Nmm_per_rad`` k per segment) or ``off``. ``hold_when_stopped``:
    False follows eq. 17 (no deformation while the distal segment stands still).
    """

    kind: Literal["off", "proportional", "torque"] = "proportional"
    eta: Annotated[float, Field(ge=0, lt=1)] = 0.1
    friction_torque_Nmm: list[NonNegativeFloat] = Field(default_factory=list)
    stiffness_Nmm_per_rad: list[PositiveFloat] = Field(default_factory=list)
    hold_when_stopped: bool = False


class UJointConfig(Section):
    """The universal-joint design's own parameters (the rest is in ``robot:``, module docstring).

    ``half_gap_mm`` d: disk face to joint centre (eq. 4); ``base_link_mm``: rigid base from the
    robot base frame to the first sub-joint; ``tip_link_mm``/``tip_mass_g``: rigid end effector
    after the last segment anchor and its mass (at its middle).
    """

    half_gap_mm: PositiveFloat
    base_link_mm: NonNegativeFloat = 0.0
    tip_link_mm: NonNegativeFloat = 0.0
    tip_mass_g: NonNegativeFloat = 0.0
    drive: LeadScrewDriveConfig
    dead_zone: DeadZoneConfig = Field(
        default_factory=lambda: DeadZoneConfig(friction_exponent_per_mm=0.0)
    )
    deformation: DeformationConfig = Field(default_factory=DeformationConfig)


def _lead_screw(uj: UJointConfig) -> LeadScrewDrive:
    d = uj.drive
    return LeadScrewDrive(d.lead_mm, d.gear_ratio, d.gear_ratio_kind, d.pulley_factor)


def check_ujoint(cfg: Any) -> list[tuple[KeyPath, str, Any]]:
    """Cross-section checks of a ``design: ujoint`` rig config (shape of ``loader.cross_check``):
    segment lengths vs the sub-joint geometry, one torque-model value per segment, the drives'
    counts_per_mm vs the lead-screw transmission."""
    problems: list[tuple[KeyPath, str, Any]] = []
    robot = cfg.robot
    uj = cfg.ujoint
    for i, s in enumerate(robot.segments):
        link = s.length_mm / s.disks.count - 2.0 * uj.half_gap_mm
        if link < -LENGTH_TOL_MM:
            problems.append(
                (
                    ("robot", "segments", i, "length_mm"),
                    f"shorter than disks.count * 2 * ujoint.half_gap_mm "
                    f"= {s.disks.count * 2 * uj.half_gap_mm} mm",
                    s.length_mm,
                )
            )
    d = uj.deformation
    if d.kind == "torque":
        for key in ("friction_torque_Nmm", "stiffness_Nmm_per_rad"):
            if len(getattr(d, key)) != len(robot.segments):
                problems.append(
                    (
                        ("ujoint", "deformation", key),
                        f"needs one value per segment ({len(robot.segments)})",
                        getattr(d, key),
                    )
                )
    if uj.drive.encoder_counts_per_rev is not None:
        expected = _lead_screw(uj).counts_per_mm(uj.drive.encoder_counts_per_rev)
        problems += _check_counts(cfg, expected, "ujoint.drive")
    return problems


def ujoint_arm(cfg: Any, source: str = "rig config") -> UJointArm:
    """The universal-joint model (:class:`UJointArm`) of a ``design: ujoint`` rig config.

    Raises :class:`ConfigError` for another design or a failed :func:`check_design`.
    """
    if getattr(cfg, "ujoint", None) is None:  # the schema allows it for design ujoint alone
        raise ConfigError(
            source,
            "design",
            "the universal-joint model needs design ujoint with a ujoint: section",
            cfg.design,
        )
    _raise_problems(check_ujoint(cfg), source)
    uj: UJointConfig = cfg.ujoint
    robot = cfg.robot
    seg_index = {s.name: i for i, s in enumerate(robot.segments)}
    segments = tuple(
        UJointSegment(
            name=s.name,
            n_subjoints=s.disks.count,
            half_gap_mm=uj.half_gap_mm,
            link_mm=max(0.0, s.length_mm / s.disks.count - 2.0 * uj.half_gap_mm),
            link_mass_g=s.disks.mass_g,
        )
        for s in robot.segments
    )
    seg_len = np.cumsum([s.length_mm for s in robot.segments])
    cables = tuple(
        UJointCable(
            name=c.name,
            segment=seg_index[c.segment],
            hole_angle_rad=c.hole_angle_rad,
            hole_radius_mm=c.routing_radius_mm,
            EA_N=c.EA,
            total_length_mm=c.free_length_mm
            + uj.base_link_mm
            + float(seg_len[seg_index[c.segment]]),
            pretension_N=c.pretension_N,
        )
        for c in robot.cables
    )
    d = uj.deformation
    g = robot.gravity_mm_s2
    return UJointArm(
        segments=segments,
        cables=cables,
        drive=_lead_screw(uj),
        friction_exponent_per_mm=uj.dead_zone.kappa_per_mm,
        deformation=DeformationParams(
            kind=d.kind,
            eta=d.eta,
            friction_torque_Nmm=tuple(d.friction_torque_Nmm),
            stiffness_Nmm_per_rad=tuple(d.stiffness_Nmm_per_rad),
            hold_when_stopped=d.hold_when_stopped,
        ),
        base_link_mm=uj.base_link_mm,
        tip_link_mm=uj.tip_link_mm,
        tip_mass_g=uj.tip_mass_g,
        gravity_mm_s2=(g[0], g[1], g[2]),
    )
