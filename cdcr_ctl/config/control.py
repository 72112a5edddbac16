"""Control-loop, limit, logging and daemon sections of the rig config."""

from __future__ import annotations

import ipaddress
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.robot import PositiveFloat


class ControlConfig(Section):
    """The real-time loop.

    ``compensation``: ``off`` sends the ideal inverse kinematics; ``model`` adds the force-transfer
    feedforward delta of Qi et al. 2023 eq. 37 from modelled tensions; ``measured`` uses the
    load-cell tensions in place of modelled ones.
    """

    rate_hz: Annotated[float, Field(gt=0, le=4000)] = 1000.0
    compensation: Literal["off", "model", "measured"] = "model"

    @field_validator("compensation", mode="before")
    @classmethod
    def _yaml_off(cls, value: object) -> object:
        # YAML 1.1 reads a bare `off` as false: accept it as the mode it was meant to be.
        return "off" if value is False else value

    #: Cable geometry of the model: ``chord`` the straight spans between disk holes (exact for a
    #: disk robot), ``cc`` the continuous routing of Qi et al. 2023 eq. 4.
    geometry: Literal["chord", "cc"] = "chord"
    #: Actuator travel over which friction reverses in the compensation (0: the model's stick rule).
    reversal_band_mm: Annotated[float, Field(ge=0, le=10)] = 0.0
    realtime_priority: Annotated[int, Field(ge=0, le=99)] = 0
    lock_memory: bool = False


class LimitsConfig(Section):
    """Safety limits, checked every cycle by the supervisor."""

    cable_displacement_mm: Annotated[list[float], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [-20.0, 20.0]
    )
    cable_velocity_mm_s: PositiveFloat = 50.0
    tension_N: Annotated[list[float], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [0.2, 60.0]
    )
    bend_rad: PositiveFloat = 2.0
    tracker_divergence_mm: PositiveFloat = 30.0
    sensor_timeout_s: PositiveFloat = 0.2

    @model_validator(mode="after")
    def _ordered(self) -> LimitsConfig:
        for key in ("cable_displacement_mm", "tension_N"):
            lo, hi = getattr(self, key)
            if lo >= hi:
                raise ValueError(f"{key} must be [min, max] with min < max")
        return self


class LoggingConfig(Section):
    """Run logs: one directory per run below ``directory``."""

    directory: str = "runs"
    fsync_every_s: PositiveFloat = 0.5
    #: Also write the run as ``run.mcap`` (Foxglove, PlotJuggler): one channel per stream, zstd
    #: chunks closed and flushed every ``fsync_every_s``. ``samples.csv`` is written either way.
    mcap: bool = True


class LiveViewConfig(Section):
    """The live view: the loop's channels over the Foxglove WebSocket protocol while it runs.

    Off unless ``enabled``. There is no authentication, so the server binds ``host``
    (127.0.0.1 unless the config names another address). ``rate_hz``: messages per second on
    each sample channel (commands, cables, tensions, tips, loop timing), taken from the latest
    cycle; ``scene_hz``: backbone 3D scene updates per second.
    """

    enabled: bool = False
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=0, le=65535)] = 8765
    rate_hz: Annotated[float, Field(gt=0, le=200)] = 50.0
    scene_hz: Annotated[float, Field(gt=0, le=60)] = 10.0

    @field_validator("host")
    @classmethod
    def _address(cls, value: str) -> str:
        # An IP address, not a name: what the server listens on must be plain in the config.
        try:
            ipaddress.ip_address(value)
        except ValueError:
            raise ValueError(f"{value!r} is not an IP address (e.g. 127.0.0.1)") from None
        return value


class DaemonConfig(Section):
    """The daemon's control socket (Unix domain, mode 0660; no TCP listener)."""

    socket_path: str = "/run/cdcr-ctl/control.sock"
    socket_mode: Annotated[int, Field(ge=0, le=0o777)] = 0o660
    watchdog: bool = True
