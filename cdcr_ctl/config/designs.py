"""Design-specific config sections and model builders for the two non-constant-curvature designs.

``design: ujoint`` - universal-joint segments (Yang et al. 2022): section ``ujoint:``
(:class:`UJointConfig`), model :class:`cdcr_ctl.model.ujoint.UJointArm`.
``design: vertebra`` - ball-jointed vertebrae on an elastic rod (fuel-tank arm): section
``vertebra:`` (:class:`VertebraConfig`), model :class:`cdcr_ctl.model.vertebra.VertebraArm`.

The sections, checks and builders live in :mod:`cdcr_ctl.config.designs_ujoint` and
:mod:`cdcr_ctl.config.designs_vertebra` (the shared bits in :mod:`cdcr_ctl.config.designs_common`);
this module re-exports them; the design registry (:mod:`cdcr_ctl.config.registry`) names them
for each design. Hook into the rig config: ``RigConfig`` (:mod:`cdcr_ctl.config.schema`) carries
the optional keys and checks that the section of the chosen design is present (and no other);
these modules must therefore not import the schema or the loader. :func:`check_design` returns
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

from typing import Any

from cdcr_ctl.config.designs_common import COUNTS_PER_MM_REL_TOL, LENGTH_TOL_MM, Vec3
from cdcr_ctl.config.designs_ujoint import (
    DeadZoneCalibrationConfig,
    DeadZoneConfig,
    DeformationConfig,
    LeadScrewDriveConfig,
    UJointConfig,
    check_ujoint,
    ujoint_arm,
)
from cdcr_ctl.config.designs_vertebra import (
    AttitudeDecodeConfig,
    FollowConfig,
    LinearModuleConfig,
    VertebraConfig,
    attitude_loop_params,
    check_vertebra,
    follow_params,
    plan_follow_offline,
    sensor_mounts,
    vertebra_arm,
)
from cdcr_ctl.config.keys import KeyPath
from cdcr_ctl.config.registry import check_design_section, design_of

__all__ = [
    "COUNTS_PER_MM_REL_TOL",
    "LENGTH_TOL_MM",
    "AttitudeDecodeConfig",
    "DeadZoneCalibrationConfig",
    "DeadZoneConfig",
    "DeformationConfig",
    "FollowConfig",
    "LeadScrewDriveConfig",
    "LinearModuleConfig",
    "UJointConfig",
    "Vec3",
    "VertebraConfig",
    "attitude_loop_params",
    "check_design",
    "check_design_section",
    "check_ujoint",
    "check_vertebra",
    "follow_params",
    "plan_follow_offline",
    "sensor_mounts",
    "ujoint_arm",
    "vertebra_arm",
]


def check_design(cfg: Any) -> list[tuple[KeyPath, str, Any]]:
    """Cross-section checks of a rig (shape of ``loader.cross_check``): its design's registered
    ``check`` (:func:`check_ujoint`, :func:`check_vertebra`; none for cc_disk).

    ``cfg`` is a ``RigConfig``.
    """
    return design_of(cfg.design).check(cfg)
