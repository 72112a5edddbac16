"""The whole rig config: one YAML file (plus optional overlays) is the single source of truth."""

from __future__ import annotations

from typing import Any

from pydantic import Field, ValidationInfo, field_validator

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.control import (
    ControlConfig,
    DaemonConfig,
    LimitsConfig,
    LiveViewConfig,
    LoggingConfig,
)
from cdcr_ctl.config.designs import UJointConfig, VertebraConfig
from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.config.loadcells import LoadCellsConfig
from cdcr_ctl.config.registry import check_design_section, design_of
from cdcr_ctl.config.robot import Name, RobotConfig
from cdcr_ctl.config.tracking import AttitudeSensorsConfig, JoystickConfig, TrackerConfig

#: A robot design's name: one registered in :data:`cdcr_ctl.config.registry.DESIGNS`
#: (``cc_disk``: constant-curvature segments with spacer disks, Qi et al. 2023; ``ujoint``:
#: universal-joint segments, Yang et al. 2022; ``vertebra``: ball-jointed vertebrae on an
#: elastic rod, the fuel-tank inspection arm).
Design = str


class SensorsConfig(Section):
    """Every sensor is optional: a rig may run without load cells or tracker."""

    load_cells: LoadCellsConfig | None = None
    tracker: TrackerConfig | None = None
    attitude: AttitudeSensorsConfig | None = None
    joystick: JoystickConfig | None = None


class RigConfig(Section):
    """Top level of a rig config file.

    ``ujoint``/``vertebra``: the design's own section (:mod:`cdcr_ctl.config.designs`), required
    for that design and refused for the others; ``cc_disk`` rigs have neither.
    """

    #: The rig's name: in run logs, ``status`` and the live view.
    name: Name
    #: The robot design, which picks the model: ``cc_disk`` (Qi et al. 2023), ``ujoint`` (Yang et
    #: al. 2022), ``vertebra`` (the vertebra arm), or another name registered in the design
    #: registry (:mod:`cdcr_ctl.config.registry`).
    design: Design = "cc_disk"
    robot: RobotConfig
    can: CanBusConfig = Field(default_factory=CanBusConfig)
    drives: list[DriveConfig]
    sensors: SensorsConfig = Field(default_factory=SensorsConfig)
    control: ControlConfig = Field(default_factory=ControlConfig)
    limits: LimitsConfig = Field(default_factory=LimitsConfig)
    logging: LoggingConfig = Field(default_factory=LoggingConfig)
    daemon: DaemonConfig = Field(default_factory=DaemonConfig)
    live: LiveViewConfig = Field(default_factory=LiveViewConfig)
    # validate_default: a missing section is checked too, and the error names its key
    ujoint: UJointConfig | None = Field(default=None, validate_default=True)
    vertebra: VertebraConfig | None = Field(default=None, validate_default=True)

    @field_validator("design")
    @classmethod
    def _registered(cls, value: str) -> str:
        design_of(value)  # ValueError naming the registered designs
        return value

    @field_validator("ujoint", "vertebra")
    @classmethod
    def _design_section(cls, value: Any, info: ValidationInfo) -> Any:
        design = info.data.get("design")
        if design is not None:  # else 'design' itself failed and is reported
            check_design_section(design, info.field_name or "", value)
        return value
