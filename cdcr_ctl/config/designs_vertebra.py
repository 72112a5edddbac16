"""The ``vertebra:`` section of a ``design: vertebra`` rig config (ball-jointed vertebrae on an
elastic rod, the fuel-tank vertebra robot paper: linear modules eq. 9, end-following section 2.2,
attitude decode eq. 6-8), its cross-section checks and the builders of the model
(:func:`vertebra_arm`, :class:`cdcr_ctl.model.vertebra.VertebraArm`), the planner's and the
attitude loop's parameters. How the shared ``robot:`` section reads for this design:
:mod:`cdcr_ctl.config.designs`."""

from __future__ import annotations

import math
from typing import Annotated, Any

import numpy as np
from pydantic import Field

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.designs_common import Vec3, _check_counts, _raise_problems
from cdcr_ctl.config.keys import KeyPath
from cdcr_ctl.config.robot import NonNegativeFloat, PositiveFloat
from cdcr_ctl.errors import ConfigError
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
from cdcr_ctl.model.vertebra.follow import SPEED_FRACTION, plan_session


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
    (:class:`cdcr_ctl.model.vertebra.follow.EndFollowSource`; 1 is the paper's synchronisation
    at the limits); the rest is left for the compensation (``compensation_max_rate_mm_s``)."""

    step_rad: PositiveFloat = 0.05
    #: Distal bend change per joystick tick at full deflection.
    theta_increment_rad: NonNegativeFloat = 0.02
    #: Distal direction change per joystick tick at full deflection.
    phi_increment_rad: NonNegativeFloat = 0.05
    #: Largest distal bend the joystick may ask for.
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

    #: Mass carried at the tip (g), in the gravity sag model.
    tip_mass_g: NonNegativeFloat = 0.0
    linear_module: LinearModuleConfig
    module_overrides: dict[str, LinearModuleConfig] = Field(default_factory=dict)
    follow: FollowConfig = Field(default_factory=FollowConfig)
    attitude: AttitudeDecodeConfig = Field(default_factory=AttitudeDecodeConfig)
    compensation_max_rate_mm_s: PositiveFloat = 1.0


def _module_for(vt: VertebraConfig, cable: str) -> LinearModuleConfig:
    return vt.module_overrides.get(cable, vt.linear_module)


def check_vertebra(cfg: Any) -> list[tuple[KeyPath, str, Any]]:
    """Cross-section checks of a ``design: vertebra`` rig config (shape of
    ``loader.cross_check``): hole length vs gap, module overrides, one sensor and mount per
    joint, the drives' counts_per_mm vs the linear modules, the follow and compensation rates
    vs the cable velocity limit."""
    problems: list[tuple[KeyPath, str, Any]] = []
    robot = cfg.robot
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
            problems.append((("vertebra", "module_overrides", name), "no cable of that name", name))
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


def vertebra_arm(cfg: Any, source: str = "rig config") -> VertebraArm:
    """The vertebra model (:class:`VertebraArm`) of a ``design: vertebra`` rig config.

    Raises :class:`ConfigError` for another design or a failed :func:`check_design`.
    """
    if getattr(cfg, "vertebra", None) is None:  # the schema allows it for design vertebra alone
        raise ConfigError(
            source,
            "design",
            "the vertebra model needs design vertebra with a vertebra: section",
            cfg.design,
        )
    _raise_problems(check_vertebra(cfg), source)
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
    (:func:`cdcr_ctl.model.vertebra.follow.plan_session`): (t_s (M,), psi (M, N, 2) rad, the
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
