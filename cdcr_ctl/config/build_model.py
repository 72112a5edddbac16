"""Build the design's model (the loop's ``RobotModelPort``) from a validated rig config.

:func:`build_model` looks the rig's ``design`` up in the design registry
(:mod:`cdcr_ctl.config.registry`) and calls its builder. The constant-curvature disk design's
builder and the helpers that turn its config sections into model parameters are
:mod:`cdcr_ctl.config.designs_cc_disk` (importable from here too).
"""

from __future__ import annotations

from typing import Any

from cdcr_ctl.config.designs_cc_disk import (
    DEAD_ZONE_STEP_FRACTION,
    build_cc_disk_model,
    cable_names,
    dead_zone_step_mm,
    friction_law,
    loadcell_locations,
    model_effects,
    reversal_hysteresis_mm,
    robot_params,
)
from cdcr_ctl.config.registry import design_of
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.model.port import RobotModelPort

__all__ = [
    "DEAD_ZONE_STEP_FRACTION",
    "build_cc_disk_model",
    "build_model",
    "cable_names",
    "dead_zone_step_mm",
    "friction_law",
    "loadcell_locations",
    "model_effects",
    "reversal_hysteresis_mm",
    "robot_params",
]


def build_model(
    cfg: RigConfig,
    effects: Any = None,
    reversal_band_mm: float | None = None,
    source: str = "rig config",
) -> RobotModelPort:
    """The control loop's model (``RobotModelPort``) for the rig's ``design``: its registered
    builder. ``effects`` and ``reversal_band_mm`` are cc_disk's options (see
    :func:`~cdcr_ctl.config.designs_cc_disk.build_cc_disk_model`; None: the config's); the other
    designs refuse them. ``source`` names the file in errors; a design section that contradicts
    the drives raises :class:`~cdcr_ctl.errors.ConfigError`."""
    return design_of(cfg.design).build(cfg, source, effects, reversal_band_mm)
