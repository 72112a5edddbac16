"""CAN bus and drive sections of the rig config.

A drive is counts and modes: the only robot knowledge here is which cable a drive pulls
(``cable``) and the transmission ratio ``counts_per_mm`` (encoder counts per mm of cable pulled in,
sign included: a negative ratio means the motor turns the other way to pull).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.robot import Name, PositiveFloat

#: Bit rates a CAN controller can run (CiA 301 table of standard bit rates).
STANDARD_BITRATES = (10_000, 20_000, 50_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)


class CanBusConfig(Section):
    """The CAN bus: python-can ``interface`` and ``channel``, bit rate and SYNC period.

    ``interface`` is any python-can interface name: ``virtual`` (tests, one process), ``slcan``
    (USB-CAN adapters and the simulated rig over a pty), ``socketcan`` (``can0`` on real rigs),
    ``udp_multicast`` (only inside a loopback-only network namespace), ``pcan``, ``kvaser``, ...
    """

    interface: Annotated[str, Field(min_length=1)] = "virtual"
    channel: Annotated[str, Field(min_length=1)] = "cdcr"
    bitrate: int = 1_000_000
    sync_period_s: Annotated[float, Field(gt=0, le=1.0)] = 0.001
    master_node_id: Annotated[int, Field(ge=1, le=127)] = 127
    master_heartbeat_ms: Annotated[int, Field(ge=0, le=65535)] = 100
    max_bus_load: Annotated[float, Field(gt=0, le=1.0)] = 0.70
    #: A drive whose TPDO feedback is older than this has stopped answering (s). Default: three
    #: SYNC periods. Links with more latency (an slcan pty between processes) need more.
    feedback_timeout_s: Annotated[float, Field(gt=0, le=10.0)] | None = None
    log_traffic: bool = True

    @field_validator("bitrate")
    @classmethod
    def _standard_bitrate(cls, value: int) -> int:
        if value not in STANDARD_BITRATES:
            raise ValueError(f"bitrate must be one of {STANDARD_BITRATES}")
        return value


class HomingConfig(Section):
    """CiA 402 homing (0x6098 method). 37 = actual position, -3/-4 = current threshold (EPOS4)."""

    method: int = 37
    current_threshold_mA: Annotated[int, Field(gt=0, le=100_000)] = 500
    speed_rpm: Annotated[int, Field(gt=0, le=100_000)] = 100
    acceleration_rpm_s: Annotated[int, Field(gt=0, le=10_000_000)] = 1000
    offset_counts: int = 0
    timeout_s: PositiveFloat = 20.0

    @model_validator(mode="after")
    def _known_method(self) -> HomingConfig:
        allowed = {-4, -3, -2, -1, 1, 2, 7, 11, 17, 18, 23, 27, 33, 34, 35, 37}
        if self.method not in allowed:
            raise ValueError(f"method {self.method} is not an EPOS4 method {sorted(allowed)}")
        return self


class DriveConfig(Section):
    """One maxon EPOS drive on the bus, pulling one cable."""

    name: Name
    cable: Name
    node_id: Annotated[int, Field(ge=1, le=127)]
    type: Literal["epos4", "epos2"] = "epos4"
    mode: Literal["csp", "pp", "ip"] = "csp"
    counts_per_mm: float
    following_error_window_counts: Annotated[int, Field(ge=0, le=2**31 - 1)] = 20_000
    software_limits_counts: Annotated[list[int], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [-2_000_000, 2_000_000]
    )
    max_profile_velocity_rpm: Annotated[int, Field(gt=0, le=100_000)] = 5000
    profile_acceleration_rpm_s: Annotated[int, Field(gt=0, le=10_000_000)] = 10_000
    quick_stop_deceleration_rpm_s: Annotated[int, Field(gt=0, le=10_000_000)] = 50_000
    heartbeat_producer_ms: Annotated[int, Field(ge=0, le=65535)] = 50
    heartbeat_consumer_ms: Annotated[int, Field(ge=0, le=65535)] = 300
    homing: HomingConfig = Field(default_factory=HomingConfig)

    @model_validator(mode="after")
    def _checks(self) -> DriveConfig:
        if self.counts_per_mm == 0:
            raise ValueError("counts_per_mm must not be 0")
        lo, hi = self.software_limits_counts
        if lo >= hi:
            raise ValueError("software_limits_counts must be [min, max] with min < max")
        if self.type == "epos2" and self.mode == "csp":
            raise ValueError("EPOS2 has no cyclic synchronous position mode: use pp or ip")
        return self
