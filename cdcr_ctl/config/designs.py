"""Design-specific config sections and model builders for the two non-constant-curvature designs.

``design: ujoint`` - universal-joint segments (Yang et al. 2022): section ``ujoint:``
(:class:`UJointConfig`), model :class:`cdcr_ctl.model.ujoint.UJointArm`.
``design: vertebra`` - ball-jointed vertebrae on an elastic rod (fuel-tank arm): section
``vertebra:`` (:class:`VertebraConfig`), model :class:`cdcr_ctl.model.vertebra.VertebraArm`.

Hook into the rig config: ``RigConfig`` (:mod:`cdcr_ctl.config.schema`) carries the two optional
keys and checks that the section of the chosen design is present (and no other); this module must
therefore not import the schema or the loader at import time. :func:`check_design` returns
cross-section problems in the shape of ``loader.cross_check``; the builders run it, so a rig whose
drives do not match its design's transmission fails when its model is built (before any I/O).

How the shared ``robot:`` section reads for these designs (no key changes meaning silently; what
is unused is said so):

ujoint
    ``robot.segments[i]``: ``length_mm`` = M (2 d + link) (the link tube length is derived from it
    and ``ujoint.half_gap_mm`` d); ``disks.count`` = M sub-joints; ``disks.mass_g`` = mass of one
    moving link (cross, disk, tube); ``disks.thickness_mm`` and ``backbone`` are not used (the
    schema still requires a backbone; any valid value).
    ``robot.cables[k]``: ``segment`` (anchor), ``hole_angle_rad`` (beta), ``routing_radius_mm``
    (rho), ``E_MPa``/``EA_N`` with ``diameter_mm``, ``pretension_N``, ``free_length_mm`` (cable
    outside the arm: drive box; total length = free + base link + segments up to the anchor).
    ``mu_disk`` and ``pulleys`` are not used (friction enters as the dead zone).
vertebra
    ``robot.segments[i]`` = joints: ``length_mm`` = n (l0 + H); ``disks.count`` = n vertebra gaps
    per joint; ``disks.thickness_mm`` = H (hole length); l0 = length / n - H; ``disks.mass_g`` per
    vertebra disk (rod share included); ``backbone`` = the NiTi rod (its EI is used).
    ``robot.cables[k]``: ``segment`` (the joint it ends in), ``hole_angle_rad``,
    ``routing_radius_mm`` = r (eq. 3's d is the diameter 2 r), stiffness, ``pretension_N``,
    ``free_length_mm`` (module to arm base). ``mu_disk``/``pulleys`` are not used.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.keys import KeyPath, format_key
from cdcr_ctl.config.robot import NonNegativeFloat, PositiveFloat
from cdcr_ctl.errors import ConfigError, ConfigErrors
from cdcr_ctl.model.ujoint import (
    DeformationParams,
    LeadScrewDrive,
    UJointArm,
    UJointCable,
    UJointSegment,
    calibrate_friction_exponent,
)
from cdcr_ctl.model.vertebra import (
    AttitudeLoopParams,
    EndFollowPlanner,
    FollowParams,
    LinearModule,
    VertebraArm,
    VertebraCable,
    VertebraJoint,
    rotvec_matrix,
)
from cdcr_ctl.model.vertebra_follow import SPEED_FRACTION, plan_session

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]

#: Relative mismatch allowed between a drive's counts_per_mm and the design's transmission.
COUNTS_PER_MM_REL_TOL = 1e-3
#: Absolute mismatch allowed between segment length and its sub-joint geometry (mm).
LENGTH_TOL_MM = 1e-6


# =========================================================================== ujoint
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


# =========================================================================== vertebra
class LinearModuleConfig(Section):
    """A linear module (eq. 9): ``steps_per_rev`` s position units per screw turn (microsteps of
    a stepper driver, or encoder counts of a servo), ``lead_mm`` c, speed limit ``v_max_mm_s``.
    ``vertebra.linear_module`` applies to every cable; ``vertebra.module_overrides`` (by cable
    name) to single ones. Each drive's ``counts_per_mm`` must equal s / c."""

    steps_per_rev: PositiveFloat
    lead_mm: PositiveFloat
    v_max_mm_s: PositiveFloat


class FollowConfig(Section):
    """Joystick end-following (section 2.2): ``step_rad`` per synchronised step (0.05 in the
    paper), distal target increments per joystick tick at full deflection, bend limit.
    ``speed_fraction``: share of each linear module's ``v_max_mm_s`` the planned steps use
    (:class:`cdcr_ctl.model.vertebra_follow.EndFollowSource`; 1 is the paper's synchronisation
    at the limits); the rest is left for the compensation (``compensation_max_rate_mm_s``)."""

    step_rad: PositiveFloat = 0.05
    theta_increment_rad: NonNegativeFloat = 0.02
    phi_increment_rad: NonNegativeFloat = 0.05
    theta_max_rad: Annotated[float, Field(gt=0, le=math.pi)] = math.pi / 2
    speed_fraction: Annotated[float, Field(gt=0, le=1)] = SPEED_FRACTION


class AttitudeDecodeConfig(Section):
    """Decoding joint poses from the attitude sensors (eq. 6-8, yaw not used).

    ``base_up``: the world up vector in the robot base frame (upright base: [0, 0, 1]).
    ``sensor_mounts_rotvec_rad``: per sensor, its orientation in the joint-end frame as a rotation
    vector (the rotation maps sensor coordinates to joint-end coordinates; None: axes parallel,
    as the paper mounts them). ``singular_tol``: below this the
    bend direction is taken as undefined (kept from the last decode).
    Joint-space closed loop (compensation mode ``measured``,
    :class:`cdcr_ctl.model.vertebra.VertebraModel`): integral gain ``closed_loop_gain_per_s``
    (bending-vector correction per second per rad of error), correction bounded by
    ``max_correction_rad`` per joint, joints whose decode ``observability`` is below
    ``min_observability`` are not corrected.
    """

    base_up: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 1.0])
    sensor_mounts_rotvec_rad: list[Vec3] | None = None
    singular_tol: PositiveFloat = 1e-9
    closed_loop_gain_per_s: PositiveFloat = 5.0
    max_correction_rad: PositiveFloat = 0.3
    min_observability: Annotated[float, Field(ge=0, le=1)] = 0.2


class VertebraConfig(Section):
    """The vertebra design's own parameters (the rest is in ``robot:``, module docstring).

    ``compensation_max_rate_mm_s``: rate limit of the compensation offset q_cmd - q_nominal of
    every cable in modes ``model`` (sag compensation) and ``measured`` (attitude loop), mm/s
    (:class:`cdcr_ctl.model.vertebra.VertebraModel`). The planned motion runs at
    ``follow.speed_fraction`` of each module's speed; :func:`check_design` requires
    speed_fraction * v_max_mm_s + this <= ``limits.cable_velocity_mm_s`` for every cable, so
    plan plus compensation never trips the velocity limit. The default leaves 1 mm/s of the
    prototype's 10 mm/s for the trajectory's interpolation.
    """

    tip_mass_g: NonNegativeFloat = 0.0
    linear_module: LinearModuleConfig
    module_overrides: dict[str, LinearModuleConfig] = Field(default_factory=dict)
    follow: FollowConfig = Field(default_factory=FollowConfig)
    attitude: AttitudeDecodeConfig = Field(default_factory=AttitudeDecodeConfig)
    compensation_max_rate_mm_s: PositiveFloat = 1.0


# =========================================================================== checks
def check_design_section(design: str, key: str, section: object) -> None:
    """Section ``key`` (``ujoint``/``vertebra``) is present exactly when ``design`` is ``key``
    (ValueError otherwise); called by ``RigConfig``'s validator of that key."""
    if design == key and section is None:
        raise ValueError(f"design {key} needs a '{key}:' section")
    if design != key and section is not None:
        raise ValueError(f"a '{key}:' section is only for design {key}")


def check_design(cfg: Any) -> list[tuple[KeyPath, str, Any]]:
    """Cross-section checks of a ujoint / vertebra rig (shape of ``loader.cross_check``).

    ``cfg`` is a ``RigConfig``. Other designs: no problems.
    """
    problems: list[tuple[KeyPath, str, Any]] = []
    design = cfg.design
    robot = cfg.robot
    if design == "ujoint":
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
    elif design == "vertebra":
        vt = cfg.vertebra
        for i, s in enumerate(robot.segments):
            if s.length_mm / s.disks.count - s.disks.thickness_mm <= 0:
                problems.append(
                    (
                        ("robot", "segments", i, "disks", "thickness_mm"),
                        "hole length H must be shorter than length_mm / disks.count",
                        s.disks.thickness_mm,
                    )
                )
        names = {c.name for c in robot.cables}
        for name in vt.module_overrides:
            if name not in names:
                problems.append(
                    (("vertebra", "module_overrides", name), "no cable of that name", name)
                )
        mounts = vt.attitude.sensor_mounts_rotvec_rad
        if mounts is not None and len(mounts) != len(robot.segments):
            problems.append(
                (
                    ("vertebra", "attitude", "sensor_mounts_rotvec_rad"),
                    f"needs one mount per joint ({len(robot.segments)})",
                    len(mounts),
                )
            )
        att = cfg.sensors.attitude
        if att is not None and len(att.sensors) != len(robot.segments):
            problems.append(
                (
                    ("sensors", "attitude", "sensors"),
                    f"needs one sensor per joint ({len(robot.segments)})",
                    len(att.sensors),
                )
            )
        v_limit = cfg.limits.cable_velocity_mm_s
        for k, c in enumerate(robot.cables):
            m = _module_for(vt, c.name)
            problems += _check_counts(
                cfg, m.steps_per_rev / m.lead_mm, "vertebra.linear_module", only=c.name, index=k
            )
            planned = vt.follow.speed_fraction * m.v_max_mm_s
            if planned + vt.compensation_max_rate_mm_s > v_limit * (1.0 + 1e-12):
                problems.append(
                    (
                        ("vertebra", "compensation_max_rate_mm_s"),
                        f"cable {c.name}: follow.speed_fraction * v_max_mm_s = {planned:g} mm/s"
                        f" plus this exceeds limits.cable_velocity_mm_s = {v_limit:g} mm/s",
                        vt.compensation_max_rate_mm_s,
                    )
                )
                break
    return problems


def _check_counts(
    cfg: Any, expected: float, source: str, only: str | None = None, index: int | None = None
) -> list[tuple[KeyPath, str, Any]]:
    out: list[tuple[KeyPath, str, Any]] = []
    for i, drv in enumerate(cfg.drives):
        if only is not None and drv.cable != only:
            continue
        if abs(abs(drv.counts_per_mm) - expected) > COUNTS_PER_MM_REL_TOL * expected:
            out.append(
                (
                    ("drives", i, "counts_per_mm"),
                    f"does not match {source} ({expected:.6g} counts per mm)",
                    drv.counts_per_mm,
                )
            )
    return out


def _module_for(vt: VertebraConfig, cable: str) -> LinearModuleConfig:
    return vt.module_overrides.get(cable, vt.linear_module)


def _lead_screw(uj: UJointConfig) -> LeadScrewDrive:
    d = uj.drive
    return LeadScrewDrive(d.lead_mm, d.gear_ratio, d.gear_ratio_kind, d.pulley_factor)


def _raise_problems(problems: list[tuple[KeyPath, str, Any]], source: str) -> None:

    if problems:
        raise ConfigErrors([ConfigError(source, format_key(k), m, v) for k, m, v in problems])


# =========================================================================== builders
def ujoint_arm(cfg: Any, source: str = "rig config") -> UJointArm:
    """The universal-joint model (:class:`UJointArm`) of a ``design: ujoint`` rig config.

    Raises :class:`ConfigError` for another design or a failed :func:`check_design`.
    """
    if cfg.design != "ujoint" or getattr(cfg, "ujoint", None) is None:
        raise ConfigError(
            source,
            "design",
            "the universal-joint model needs design ujoint with a ujoint: section",
            cfg.design,
        )
    _raise_problems(check_design(cfg), source)
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


def vertebra_arm(cfg: Any, source: str = "rig config") -> VertebraArm:
    """The vertebra model (:class:`VertebraArm`) of a ``design: vertebra`` rig config.

    Raises :class:`ConfigError` for another design or a failed :func:`check_design`.
    """
    if cfg.design != "vertebra" or getattr(cfg, "vertebra", None) is None:
        raise ConfigError(
            source,
            "design",
            "the vertebra model needs design vertebra with a vertebra: section",
            cfg.design,
        )
    _raise_problems(check_design(cfg), source)
    vt: VertebraConfig = cfg.vertebra
    robot = cfg.robot
    seg_index = {s.name: i for i, s in enumerate(robot.segments)}
    joints = tuple(
        VertebraJoint(
            name=s.name,
            n_gaps=s.disks.count,
            gap_mm=s.length_mm / s.disks.count - s.disks.thickness_mm,
            hole_length_mm=s.disks.thickness_mm,
            rod_EI_Nmm2=s.backbone.EI,
            disk_mass_g=s.disks.mass_g,
        )
        for s in robot.segments
    )
    seg_len = np.cumsum([s.length_mm for s in robot.segments])
    cables = tuple(
        VertebraCable(
            name=c.name,
            joint=seg_index[c.segment],
            hole_angle_rad=c.hole_angle_rad,
            hole_radius_mm=c.routing_radius_mm,
            EA_N=c.EA,
            total_length_mm=c.free_length_mm + float(seg_len[seg_index[c.segment]]),
            pretension_N=c.pretension_N,
        )
        for c in robot.cables
    )
    modules = tuple(
        LinearModule(m.steps_per_rev, m.lead_mm, m.v_max_mm_s)
        for m in (_module_for(vt, c.name) for c in robot.cables)
    )
    g = robot.gravity_mm_s2
    return VertebraArm(joints, cables, modules, (g[0], g[1], g[2]), vt.tip_mass_g)


def follow_params(cfg: Any) -> FollowParams:
    """The end-following planner's parameters of a vertebra rig config."""
    f = cfg.vertebra.follow
    return FollowParams(f.step_rad, f.theta_increment_rad, f.phi_increment_rad, f.theta_max_rad)


def plan_follow_offline(
    cfg: Any, script: list[Any], planner: EndFollowPlanner | None = None
) -> tuple[np.ndarray, np.ndarray, EndFollowPlanner]:
    """A scripted joystick session planned offline at the rig's loop rate and follow speed
    (:func:`cdcr_ctl.model.vertebra_follow.plan_session`): (t_s (M,), psi (M, N, 2) rad, the
    planner, for planning on from where the session left it)."""
    if planner is None:
        planner = EndFollowPlanner(vertebra_arm(cfg), follow_params(cfg))
    t, psi, _ = plan_session(
        planner,
        script,
        1.0 / cfg.control.rate_hz,
        speed_fraction=cfg.vertebra.follow.speed_fraction,
    )
    return t, psi, planner


def sensor_mounts(cfg: Any) -> list[np.ndarray] | None:
    """Per joint, the sensor's orientation in the joint-end frame (3x3, sensor -> joint-end
    coordinates), or None when the axes are parallel."""
    rv = cfg.vertebra.attitude.sensor_mounts_rotvec_rad
    return None if rv is None else [rotvec_matrix(np.array(v)) for v in rv]


def attitude_loop_params(cfg: Any) -> AttitudeLoopParams:
    """The compensating modes' parameters of a vertebra rig config: the attitude loop's gain per
    control cycle (``closed_loop_gain_per_s / control.rate_hz``, at most 1), the sensors'
    staleness and the decode settings, and the compensation offset's largest step per cycle
    (``compensation_max_rate_mm_s / control.rate_hz``)."""
    att = cfg.vertebra.attitude
    sensors = cfg.sensors.attitude
    mounts = sensor_mounts(cfg)
    return AttitudeLoopParams(
        gain_per_tick=min(1.0, att.closed_loop_gain_per_s / cfg.control.rate_hz),
        max_correction_rad=att.max_correction_rad,
        min_observability=att.min_observability,
        stale_after_s=sensors.stale_after_s if sensors is not None else 0.1,
        base_up=(att.base_up[0], att.base_up[1], att.base_up[2]),
        mounts=None if mounts is None else tuple(mounts),
        singular_tol=att.singular_tol,
        max_offset_step_mm=cfg.vertebra.compensation_max_rate_mm_s / cfg.control.rate_hz,
    )
