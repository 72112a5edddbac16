"""CAN bus and drive sections of the rig config.

A drive is counts and modes: the only robot knowledge here is which cable a drive pulls
(``cable``) and the transmission ratio ``counts_per_mm`` (encoder counts per mm of cable pulled in,
sign included: a negative ratio means the motor turns the other way to pull).

Modes (``mode``): ``csp`` cyclic synchronous position (EPOS4; a target per SYNC), ``pp`` profile
position (both; the drive plans each move), ``ip`` interpolated position with the PVT buffer 0x20C1
(EPOS2 only), ``pm`` maxon "position mode" with the set-point 0x2062 (EPOS2 only).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.robot import Name

#: Bit rates a CAN controller can run (CiA 301 table of standard bit rates).
STANDARD_BITRATES = (10_000, 20_000, 50_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)

#: Operation modes each drive family offers (see the module docstring).
MODES_BY_TYPE: dict[str, tuple[str, ...]] = {"epos4": ("csp", "pp"), "epos2": ("pp", "ip", "pm")}


class CanBusConfig(Section):
    """The CAN bus: python-can ``interface`` and ``channel``, bit rate and SYNC period.

    ``interface`` is any python-can interface name: ``virtual`` (tests, one process), ``slcan``
    (USB-CAN adapters and the simulated rig over a pty), ``socketcan`` (``can0`` on real rigs),
    ``udp_multicast`` (only inside a loopback-only network namespace), ``pcan``, ``kvaser``, ...
    ``bitrate`` is sent to adapters that set it themselves (slcan ``S8``, pcan, kvaser); a
    socketcan interface gets it from ``ip link`` before the daemon starts. The SYNC period is also
    the drives' interpolation period (0x60C2), so it must be a whole number of milliseconds for
    ``csp``/``ip``/``pm`` drives. ``max_bus_load`` bounds the cyclic PDO set (SYNC, RPDOs, TPDOs)
    as a fraction of the bus time at worst-case bit stuffing.
    """

    interface: Annotated[str, Field(min_length=1)] = "virtual"
    channel: Annotated[str, Field(min_length=1)] = "cdcr"
    bitrate: int = 1_000_000
    #: SYNC period = the control loop's period on the bus and the drives' interpolation period (s).
    sync_period_s: Annotated[float, Field(gt=0, le=1.0)] = 0.001
    #: The controller's own CANopen node id (its heartbeat's COB-ID 0x700 + id).
    master_node_id: Annotated[int, Field(ge=1, le=127)] = 127
    #: The controller's heartbeat the drives watch (0: none, and then no drive can see the
    #: controller die: refused). At most 5 s.
    master_heartbeat_ms: Annotated[int, Field(ge=1, le=5000)] = 100
    max_bus_load: Annotated[float, Field(gt=0, le=1.0)] = 0.70
    #: A drive whose TPDO feedback is older than this has stopped answering (s). Default: three
    #: SYNC periods. Links with more latency (an slcan pty between processes) need more.
    feedback_timeout_s: Annotated[float, Field(gt=0, le=10.0)] | None = None
    #: Log every CAN frame of a run (``can.asc`` and the MCAP ``/can`` channel).
    log_traffic: bool = True

    @field_validator("bitrate")
    @classmethod
    def _standard_bitrate(cls, value: int) -> int:
        if value not in STANDARD_BITRATES:
            raise ValueError(f"bitrate must be one of {STANDARD_BITRATES}")
        return value


class HomingConfig(Section):
    """CiA 402 homing (0x6098 method). 37 = actual position, -3/-4 = current threshold.

    ``current_threshold_mA`` goes to 0x30B2 (EPOS4) / 0x2080 (EPOS2) for methods -1..-4;
    ``offset_counts`` is the home offset move distance (0x30B1 EPOS4 / 0x607C EPOS2): how far the
    drive backs off the hard stop before it sets ``home_position_counts`` (0x30B0 / 0x2081), as
    maxon's device descriptions define the objects.
    Speeds go to 0x6099 (switch search, zero search), the acceleration to 0x609A.
    """

    #: CiA 402 homing method (0x6098): 37 = the actual position, -3/-4 = current threshold (hard
    #: stop).
    method: int = 37
    current_threshold_mA: Annotated[int, Field(gt=0, le=65_535)] = 500
    #: Homing speed for the switch and zero searches (0x6099), motor rpm.
    speed_rpm: Annotated[int, Field(gt=0, le=100_000)] = 100
    #: Homing acceleration (0x609A), motor rpm/s.
    acceleration_rpm_s: Annotated[int, Field(gt=0, le=10_000_000)] = 1000
    offset_counts: int = 0
    home_position_counts: int = 0
    #: A homing run at the slowest speed over the longest travel finishes well inside 10 min.
    timeout_s: Annotated[float, Field(gt=0, le=600, allow_inf_nan=False)] = 20.0

    @model_validator(mode="after")
    def _known_method(self) -> HomingConfig:
        allowed = {-4, -3, -2, -1, 1, 2, 7, 11, 17, 18, 23, 27, 33, 34, 35, 37}
        if self.method not in allowed:
            raise ValueError(f"method {self.method} is not an EPOS method {sorted(allowed)}")
        return self


class DriveConfig(Section):
    """One maxon EPOS drive on the bus, pulling one cable.

    Velocities are motor rpm and accelerations motor rpm/s (the EPOS default units);
    ``encoder_counts_per_rev`` (quadrature counts per motor turn) converts counts/s to rpm where
    the protocol needs it (EPOS2 PVT velocities). The following error window is counts, its
    timeout (0x6066) ms: maxon's EPOS4 file gives 0x6066 the range 0..0 (the drive faults as soon
    as the error leaves the window), so the default is 0; the EPOS2 has no 0x6066 (not written
    unless set). ``quick_stop_option_code`` (0x605A; not on the EPOS2, whose quick stop ends
    powered off): 2 = stop on the quick-stop ramp, then power off (SWITCH ON DISABLED); 6 = stop on
    the ramp and hold position powered (QUICK STOP ACTIVE).

    ``eds``: the drive's device description (EDS, DCF or XDD; relative to the config file). Every
    SDO write the configuration plans is checked against it before the first CAN frame; without
    it, against the project's EPOS4/EPOS2 limits table (:mod:`cdcr_ctl.drives.limits`).
    """

    #: The drive's name in status, logs and errors.
    name: Name
    #: Name of the cable (``robot.cables[].name``) this drive pulls.
    cable: Name
    #: CANopen node id of the drive (set on the EPOS with its DIP switches or EPOS Studio).
    node_id: Annotated[int, Field(ge=1, le=127)]
    #: Drive family: ``epos4`` or ``epos2`` (objects, modes and limits differ).
    type: Literal["epos4", "epos2"] = "epos4"
    #: Operation mode: ``csp``, ``pp``, ``ip`` or ``pm`` (module docstring of
    #: :mod:`cdcr_ctl.config.drives`).
    mode: Literal["csp", "pp", "ip", "pm"] = "csp"
    #: Encoder counts per mm of cable pulled in, sign included (negative: the motor turns the other
    #: way to pull).
    counts_per_mm: float
    encoder_counts_per_rev: Annotated[int, Field(gt=0, le=2**24)] = 2048
    #: Following error window (0x6065): the drive faults when its position leaves the target by
    #: more.
    following_error_window_counts: Annotated[int, Field(ge=0, le=2**31 - 1)] = 20_000
    #: Following error timeout (0x6066): EPOS4 takes only 0; the EPOS2 has no such object.
    following_error_timeout_ms: Annotated[int, Field(ge=0, le=65535)] = 0
    #: Software position limits [min, max] (0x607D) the drive enforces itself.
    software_limits_counts: Annotated[list[int], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [-2_000_000, 2_000_000]
    )
    #: Maximum profile velocity (0x607F), motor rpm.
    max_profile_velocity_rpm: Annotated[int, Field(gt=0, le=100_000)] = 5000
    #: Profile acceleration and deceleration (0x6083/0x6084), motor rpm/s.
    profile_acceleration_rpm_s: Annotated[int, Field(gt=0, le=10_000_000)] = 10_000
    #: Quick-stop deceleration (0x6085), motor rpm/s: the ramp of every quick stop.
    quick_stop_deceleration_rpm_s: Annotated[int, Field(gt=0, le=10_000_000)] = 50_000
    quick_stop_option_code: Literal[1, 2, 5, 6] = 2
    #: The drive's heartbeat period (0x1017); the controller trips when it misses 3 (0: none).
    heartbeat_producer_ms: Annotated[int, Field(ge=0, le=65535)] = 50
    #: The drive's watch on the master's heartbeat (0x1016). 0 would switch it off: a dead
    #: controller would leave the drive following its last target. At least twice the master's
    #: period (checked against ``can.master_heartbeat_ms``), at most 10 s.
    heartbeat_consumer_ms: Annotated[int, Field(ge=1, le=10_000)] = 300
    homing: HomingConfig = Field(default_factory=HomingConfig)
    eds: Annotated[str, Field(min_length=1)] | None = None

    @model_validator(mode="after")
    def _checks(self) -> DriveConfig:
        if self.counts_per_mm == 0:
            raise ValueError("counts_per_mm must not be 0")
        lo, hi = self.software_limits_counts
        if lo >= hi:
            raise ValueError("software_limits_counts must be [min, max] with min < max")
        if self.mode not in MODES_BY_TYPE[self.type]:
            hint = {
                "epos2": "EPOS2 has no cyclic synchronous position mode: use pp, ip or pm",
                "epos4": "EPOS4 has neither interpolated position nor position mode: use csp or pp",
            }[self.type]
            raise ValueError(f"mode {self.mode!r}: {hint}")
        return self
