"""The whole rig config: one YAML file (plus optional overlays) is the single source of truth."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.control import ControlConfig, DaemonConfig, LimitsConfig, LoggingConfig
from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.config.loadcells import LoadCellsConfig
from cdcr_ctl.config.robot import Name, RobotConfig
from cdcr_ctl.config.tracking import AttitudeSensorsConfig, JoystickConfig, TrackerConfig

#: Robot designs the controller serves.
#: ``cc_disk``: constant-curvature segments with spacer disks (Qi et al. 2023);
#: ``ujoint``: universal-joint segments (Yang et al. 2022);
#: ``vertebra``: ball-jointed vertebrae on an elastic rod (fuel-tank inspection arm).
Design = Literal["cc_disk", "ujoint", "vertebra"]


class SensorsConfig(Section):
    """Every sensor is optional: a rig may run without load cells or tracker."""

    load_cells: LoadCellsConfig | None = None
    tracker: TrackerConfig | None = None
    attitude: AttitudeSensorsConfig | None = None
    joystick: JoystickConfig | None = None


class RigConfig(Section):
    """Top level of a rig config file."""

    name: Name
    design: Design = "cc_disk"
    robot: RobotConfig
    can: CanBusConfig = Field(default_factory=CanBusConfig)
    drives: list[DriveConfig]
    sensors: SensorsConfig = Field(default_factory=SensorsConfig)
    control: ControlConfig = Field(default_factory=ControlConfig)
    limits: LimitsConfig = Field(default_factory=LimitsConfig)
    logging: LoggingConfig = Field(default_factory=LoggingConfig)
    daemon: DaemonConfig = Field(default_factory=DaemonConfig)
