"""Tracker, attitude-sensor and joystick sections of the rig config."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.loadcells import SerialPortConfig
from cdcr_ctl.config.robot import PositiveFloat

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class RigidTransformConfig(Section):
    """A rigid transform: rotation vector (axis * angle, rad), then translation (mm)."""

    rotvec_rad: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])
    translation_mm: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])


class TrackerConfig(Section):
    """Tip tracker: OptiTrack NatNet rigid body, or a plain UDP/TCP stream from a laser tracker.

    ``base_from_tracker`` maps tracker-frame points into the robot base frame;
    ``marker_to_tip`` is the tip point in the rigid body's own frame.
    """

    kind: Literal["natnet", "udp_stream", "tcp_stream"] = "natnet"
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 1511
    command_port: Annotated[int, Field(ge=1, le=65535)] = 1510
    rigid_body_id: int = 1
    units_to_mm: PositiveFloat = 1000.0
    base_from_tracker: RigidTransformConfig = Field(default_factory=RigidTransformConfig)
    marker_to_tip: RigidTransformConfig = Field(default_factory=RigidTransformConfig)
    stale_after_s: PositiveFloat = 0.1


class AttitudeSensorsConfig(Section):
    """WitMotion JY901/WT901 attitude sensors, one per joint (vertebra design), each on a port."""

    sensors: Annotated[list[SerialPortConfig], Field(min_length=1)]
    stale_after_s: PositiveFloat = 0.1


class JoystickConfig(Section):
    """Joystick through Linux evdev: device path and axis codes for the two steering axes."""

    device: str = "/dev/input/js0"
    axis_x: str = "ABS_X"
    axis_y: str = "ABS_Y"
    deadband: Annotated[float, Field(ge=0, lt=1)] = 0.05
