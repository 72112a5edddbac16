"""The constant-curvature disk design's part of the rig config (Qi et al. 2023): its model
(:class:`~cdcr_ctl.model.cc_disk.compensation.CCDiskModel`) built from a validated rig config.

The model never imports the config: this module turns the pydantic sections into the model's
frozen dataclasses, once, at start-up. Cable order is the config's ``robot.cables`` order
everywhere. ``cfg`` is a ``RigConfig`` (this module is below the schema: the design registry,
which the schema consults, names its builder).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from cdcr_ctl.config.robot import RobotConfig
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.params import (
    CableParams,
    Effects,
    Location,
    PulleyParams,
    RobotParams,
    SegmentParams,
)

if TYPE_CHECKING:
    from cdcr_ctl.model.cc_disk.compensation import CCDiskModel

#: Share of the cable velocity limit the dead-zone inverse may add to the command while it
#: pre-travels the play after a reversal (cdcr_ctl.model.shared.deadzone). The loop's offset ramp
#: takes half of the limit (control.loop.OFFSET_RAMP_FRACTION); a quarter leaves the trajectory its
#: own quarter: 0.3 mm of play at 40 mm/s and 250 Hz is crossed in 8 cycles (32 ms).
DEAD_ZONE_STEP_FRACTION = 0.25


def dead_zone_step_mm(cfg: Any) -> float:
    """Largest pre-travel step of the dead-zone inverse per control cycle (mm)."""
    return DEAD_ZONE_STEP_FRACTION * cfg.limits.cable_velocity_mm_s / cfg.control.rate_hz


def reversal_hysteresis_mm(cfg: Any) -> float:
    """Reversal threshold of the dead-zone inverse (mm of wanted cable position): one drive count
    of the finest drive, 1/max(counts_per_mm). A wanted-position dip smaller than a count is no
    motion the drive can make, so it must not flip the pre-travel across the play; declaring a
    real reversal one count late costs at most one count of cable travel (0.8 um on the Qi et
    al. 2023 rig, 1238.6 counts/mm)."""
    return 1.0 / max(abs(d.counts_per_mm) for d in cfg.drives)


def robot_params(robot: RobotConfig) -> RobotParams:
    """Segments, cables (with their pulleys in actuator -> robot order) and gravity, in model units.

    Names are resolved to indices here (the loader's cross-check guarantees they exist).
    """
    seg_index = {s.name: i for i, s in enumerate(robot.segments)}
    pulleys = {
        p.name: PulleyParams(
            name=p.name,
            radius_mm=p.radius_mm,
            wrap_angle_rad=p.wrap_angle_rad,
            alpha=p.alpha,
            n=p.n,
        )
        for p in robot.pulleys
    }
    segments = tuple(
        SegmentParams(
            name=s.name,
            length_mm=s.length_mm,
            EI_Nmm2=s.backbone.EI,
            n_disks=s.disks.count,
            disk_mass_g=s.disks.mass_g,
            disk_thickness_mm=s.disks.thickness_mm,
        )
        for s in robot.segments
    )
    cables = tuple(
        CableParams(
            name=c.name,
            segment=seg_index[c.segment],
            hole_angle_rad=c.hole_angle_rad,
            routing_radius_mm=c.routing_radius_mm,
            diameter_mm=c.diameter_mm,
            EA_N=c.EA,
            pretension_N=c.pretension_N,
            mu_disk=c.mu_disk,
            free_length_mm=c.free_length_mm,
            pulleys=tuple(pulleys[name] for name in c.pulleys),
            backlash_mm=c.backlash_mm,
        )
        for c in robot.cables
    )
    g = robot.gravity_mm_s2
    f = robot.tip_load.force_N
    return RobotParams(
        segments=segments,
        cables=cables,
        gravity_mm_s2=(g[0], g[1], g[2]),
        tip_mass_g=1000.0 * robot.tip_load.payload_kg,
        tip_force_N=(f[0], f[1], f[2]),
    )


def model_effects(cfg: Any) -> Effects:
    """The controller model's effects from ``control.model_effects`` and ``control.geometry``."""
    # the section's keys are the Effects fields of the same names (switches, coupling_gain)
    return Effects(**cfg.control.model_effects.model_dump(), geometry=cfg.control.geometry)


def friction_law(robot: RobotConfig) -> FrictionLawShape | None:
    """The disk friction's law of ``robot.friction_law``; None for the capstan law (the
    defaults), so a config without the key builds the model it always built."""
    f = robot.friction_law
    shape = FrictionLawShape(
        exponent=f.wrap_exponent,
        viscous_s_per_mm=f.viscous_s_per_mm,
        breakaway=f.breakaway,
        breakaway_mm_s=f.stribeck_mm_s,
    )
    return None if shape.capstan else shape


def loadcell_locations(cfg: Any) -> list[Location]:
    """Per cable (config order): where its load cell sits; ``robot_base`` when it has none."""
    where: dict[str, Location] = {}
    if cfg.sensors.load_cells is not None:
        for cell in cfg.sensors.load_cells.cells:
            where[cell.cable] = cell.location
    return [where.get(c.name, "robot_base") for c in cfg.robot.cables]


def build_cc_disk_model(
    cfg: Any,
    effects: Effects | None = None,
    reversal_band_mm: float | None = None,
    source: str = "rig config",
) -> CCDiskModel:
    """The constant-curvature disk model of a ``cc_disk`` rig: ``effects`` defaults to the
    switches of ``control.model_effects`` (every effect on unless the config says otherwise),
    with the cable geometry of ``control.geometry``; the cables' lost motion (``backlash_mm``) is
    added to it as the first transmission effect, its inverse bounded by
    :func:`dead_zone_step_mm`; ``reversal_band_mm`` defaults to ``control.reversal_band_mm``;
    the disk friction follows ``robot.friction_law`` (:func:`friction_law`), a speed-dependent
    law on cable speeds taken over the loop's period 1 / ``control.rate_hz``.
    ``source`` names the file in errors."""
    # Imported here: the model's solvers bring scipy (0.5 s of CPU), which loading and checking
    # a config (every `cdcr-ctl -c RIG ...` command) never needs.
    from cdcr_ctl.model.cc_disk.compensation import CCDiskModel
    from cdcr_ctl.model.cc_disk.effects import with_cable_play

    if effects is None:
        effects = model_effects(cfg)
    if reversal_band_mm is None:
        reversal_band_mm = cfg.control.reversal_band_mm
    params = robot_params(cfg.robot)
    # The cables' lost motion (robot.cables[].backlash_mm) is part of every cc_disk model.
    effects = with_cable_play(params, effects, dead_zone_step_mm(cfg), reversal_hysteresis_mm(cfg))
    return CCDiskModel(
        params,
        effects,
        locations=loadcell_locations(cfg),
        reversal_band_mm=reversal_band_mm,
        friction_law=friction_law(cfg.robot),
        cycle_s=1.0 / cfg.control.rate_hz,
    )


def cable_names(cfg: Any) -> Sequence[str]:
    """Cable names in model order."""
    return [c.name for c in cfg.robot.cables]
