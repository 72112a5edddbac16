"""What the master writes to and exchanges with an EPOS4/EPOS2: object indices, the PDO layout per
mode, the SDO configuration from the rig config, and the PDO payloads. Pure: no I/O.

PDO layout (written to every drive by SDO at start-up, so no EDS is needed). COB-IDs are the
CiA 301 defaults for the node id; "sync" = transmission type 1 (applied/sent on every SYNC),
"event" = 255 (applied on receipt / sent on change):

==========  ===============================  ============================================
mode        RPDO1 (0x200 + id), cyclic        RPDO2 (0x300 + id) / TPDO1 (0x180 + id)
==========  ===============================  ============================================
csp EPOS4   sync: 0x607A target (int32)       RPDO2 event: 0x6040 controlword (uint16)
pm  EPOS2   sync: 0x2062 set-point (int32)    TPDO1 sync: 0x6041 statusword (uint16),
pp  both    event: 0x607A target, 0x6040          0x6064 actual position (int32)
ip  EPOS2   event: 0x20C1 PVT record (8 B)
==========  ===============================  ============================================

Every other PDO (RPDO3-4, TPDO2-4) is switched off so that factory mappings add no bus load.
Units: positions in encoder counts, velocities in motor rpm, accelerations in rpm/s, times ms.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import NamedTuple

from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.drives.cia402 import MODE_BY_NAME, Mode
from cdcr_ctl.drives.limits import ObjectTable, shipped_table
from cdcr_ctl.errors import ConfigError

# CiA 301 communication objects
DEVICE_TYPE = 0x1000
ERROR_REGISTER = 0x1001
HEARTBEAT_CONSUMER = 0x1016
HEARTBEAT_PRODUCER = 0x1017
IDENTITY = 0x1018
RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00
# CiA 402 objects (both families)
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
QUICK_STOP_OPTION = 0x605A
MODES_OF_OPERATION = 0x6060
MODES_DISPLAY = 0x6061
POSITION_ACTUAL = 0x6064
FOLLOWING_ERROR_WINDOW = 0x6065
FOLLOWING_ERROR_TIMEOUT = 0x6066
VELOCITY_ACTUAL = 0x606C
TARGET_POSITION = 0x607A
SOFTWARE_POSITION_LIMIT = 0x607D
PROFILE_VELOCITY = 0x6081
PROFILE_ACCELERATION = 0x6083
PROFILE_DECELERATION = 0x6084
QUICK_STOP_DECELERATION = 0x6085
HOMING_METHOD = 0x6098
HOMING_SPEEDS = 0x6099
HOMING_ACCELERATION = 0x609A
INTERPOLATION_PERIOD = 0x60C2
IP_DATA_CONFIGURATION = 0x60C4
SUPPORTED_DRIVE_MODES = 0x6502
# EPOS4 only (maxon's EPOS4 device description: 0x30B0 Home position, 0x30B1 Home offset move
# distance; see cdcr_ctl.drives.limits for the source)
EPOS4_HOME_POSITION = 0x30B0
EPOS4_HOME_OFFSET_MOVE = 0x30B1
EPOS4_HOMING_CURRENT_THRESHOLD = 0x30B2
# EPOS2 only
EPOS2_POSITION_MODE_SETPOINT = 0x2062
EPOS2_HOMING_CURRENT_THRESHOLD = 0x2080
EPOS2_HOME_POSITION = 0x2081
EPOS2_HOME_OFFSET = 0x607C  # CiA 402 home offset; EPOS4 uses 0x30B1 instead
EPOS2_IP_SUBMODE = 0x60C0  # interpolation sub mode selection (CiA 402 index; -1 = PVT)
EPOS2_IP_DATA_RECORD = 0x20C1
EPOS2_IP_BUFFER_STATUS = 0x20C4

#: CiA vendor id of maxon motor ag (0x1018:1).
MAXON_VENDOR_ID = 0x000000FB
#: Interpolation sub mode 0x20C0 value for PVT (position, velocity, time) records.
IP_SUBMODE_PVT = -1
#: Data-record bits of a mapping entry: index << 16 | subindex << 8 | bit length.
PDO_DISABLED = 0x8000_0000


def map_entry(index: int, subindex: int, bits: int) -> int:
    """A PDO mapping entry (CiA 301): index, subindex and length in bits in one uint32."""
    return (index << 16) | (subindex << 8) | bits


@dataclass(frozen=True)
class PdoSpec:
    """One PDO: number (1-4), COB-ID, transmission type and mapping entries, in order."""

    number: int
    cob_id: int
    transmission: int
    entries: tuple[int, ...]

    @property
    def n_bytes(self) -> int:
        return sum(e & 0xFF for e in self.entries) // 8


@dataclass(frozen=True)
class PdoLayout:
    """RPDO1 (cyclic set-point), RPDO2 (controlword) and TPDO1 (feedback) of one drive."""

    setpoint: PdoSpec
    controlword: PdoSpec
    feedback: PdoSpec

    @property
    def setpoint_is_sync(self) -> bool:
        return self.setpoint.transmission <= 240


SYNC_EVERY = 1
ON_EVENT = 255
_SETPOINT_ENTRIES = {
    Mode.CYCLIC_SYNC_POSITION: (SYNC_EVERY, (map_entry(TARGET_POSITION, 0, 32),)),
    Mode.POSITION_MODE: (SYNC_EVERY, (map_entry(EPOS2_POSITION_MODE_SETPOINT, 0, 32),)),
    Mode.PROFILE_POSITION: (
        ON_EVENT,
        (map_entry(TARGET_POSITION, 0, 32), map_entry(CONTROLWORD, 0, 16)),
    ),
    Mode.INTERPOLATED_POSITION: (ON_EVENT, (map_entry(EPOS2_IP_DATA_RECORD, 0, 64),)),
}


def pdo_layout(node_id: int, mode: Mode) -> PdoLayout:
    """The PDO layout of the module docstring for a drive at ``node_id`` running ``mode``."""
    ttype, entries = _SETPOINT_ENTRIES[mode]
    return PdoLayout(
        setpoint=PdoSpec(1, 0x200 + node_id, ttype, entries),
        controlword=PdoSpec(2, 0x300 + node_id, ON_EVENT, (map_entry(CONTROLWORD, 0, 16),)),
        feedback=PdoSpec(
            1,
            0x180 + node_id,
            SYNC_EVERY,
            (map_entry(STATUSWORD, 0, 16), map_entry(POSITION_ACTUAL, 0, 32)),
        ),
    )


class SdoWrite(NamedTuple):
    """One expedited SDO download: object, subindex, little-endian data, what it sets, and the
    config key path whose value it carries (for errors; "" when no key made it)."""

    index: int
    sub: int
    data: bytes
    what: str = ""
    key: str = ""


def _u8(v: int) -> bytes:
    return struct.pack("<B", v)


def _i8(v: int) -> bytes:
    return struct.pack("<b", v)


def _u16(v: int) -> bytes:
    return struct.pack("<H", v)


def _i16(v: int) -> bytes:
    return struct.pack("<h", v)


def _u32(v: int) -> bytes:
    return struct.pack("<I", v)


def _i32(v: int) -> bytes:
    return struct.pack("<i", v)


def pdo_mapping_writes(node_id: int, mode: Mode = Mode.CYCLIC_SYNC_POSITION) -> list[SdoWrite]:
    """SDO writes that set up :func:`pdo_layout` and switch every other PDO off.

    Each used PDO is disabled (COB-ID bit 31), its mapping cleared (sub 0 = 0), filled, counted,
    given its transmission type and enabled again (CiA 301 PDO mapping procedure).
    """
    layout = pdo_layout(node_id, mode)
    w: list[SdoWrite] = []

    def pdo(comm: int, mapping: int, spec: PdoSpec, name: str) -> None:
        w.append(SdoWrite(comm, 1, _u32(PDO_DISABLED | spec.cob_id), f"{name} off"))
        w.append(SdoWrite(mapping, 0, _u8(0), f"{name} mapping cleared"))
        for i, e in enumerate(spec.entries, start=1):
            w.append(SdoWrite(mapping, i, _u32(e), f"{name} entry {i}"))
        w.append(SdoWrite(mapping, 0, _u8(len(spec.entries)), f"{name} mapping count"))
        w.append(SdoWrite(comm, 2, _u8(spec.transmission), f"{name} transmission type"))
        w.append(SdoWrite(comm, 1, _u32(spec.cob_id), f"{name} on"))

    pdo(RPDO_COMM, RPDO_MAP, layout.setpoint, "RPDO1")
    pdo(RPDO_COMM + 1, RPDO_MAP + 1, layout.controlword, "RPDO2")
    pdo(TPDO_COMM, TPDO_MAP, layout.feedback, "TPDO1")
    for n, base in ((3, 0x400), (4, 0x500)):
        w.append(
            SdoWrite(RPDO_COMM + n - 1, 1, _u32(PDO_DISABLED | (base + node_id)), f"RPDO{n} off")
        )
    for n, base in ((2, 0x280), (3, 0x380), (4, 0x480)):
        w.append(
            SdoWrite(TPDO_COMM + n - 1, 1, _u32(PDO_DISABLED | (base + node_id)), f"TPDO{n} off")
        )
    return w


#: Modes that interpolate between SYNC-periodic set-points (0x60C2 = SYNC period is required).
SYNCED_MODES = (Mode.CYCLIC_SYNC_POSITION,)


def _whole_ms(period_s: float) -> bool:
    ms = period_s * 1e3
    return abs(ms - round(ms)) <= 1e-6 and 1 <= round(ms) <= 255


def interpolation_period_ms(
    bus: CanBusConfig, file: str = "", table: ObjectTable | None = None
) -> int:
    """The SYNC period as the whole milliseconds 0x60C2:1 takes (index -3), or ConfigError when
    it is not whole milliseconds or outside the range ``table`` gives 0x60C2:1 (EPOS4: 0-100)."""
    period_ms = bus.sync_period_s * 1e3
    whole = round(period_ms)
    if abs(period_ms - whole) > 1e-6 or not 1 <= whole <= 255:
        raise ConfigError(
            file,
            "can.sync_period_s",
            "the EPOS interpolation period (0x60C2, index -3) takes whole milliseconds",
            bus.sync_period_s,
        )
    if table is not None and not table.accepts(INTERPOLATION_PERIOD, 1, whole):
        o = table.get(INTERPOLATION_PERIOD, 1)
        span = "no such object" if o is None else f"range {o.low}..{o.high} ms"
        raise ConfigError(
            file,
            "can.sync_period_s",
            f"the interpolation period 0x60C2:1 of a cyclic mode is the SYNC period; "
            f"{table.source} gives it {span}",
            bus.sync_period_s,
        )
    return whole


def _unset_and_absent(d: DriveConfig, field: str, table: ObjectTable, index: int) -> bool:
    """The drive has no object ``index`` and the config left ``field`` at its default: the
    write is left out (a value set on purpose is planned, and refused by the check)."""
    return not table.has(index, 0) and field not in d.model_fields_set


def configuration_writes(
    d: DriveConfig,
    bus: CanBusConfig,
    file: str = "",
    table: ObjectTable | None = None,
    key: str = "",
) -> list[SdoWrite]:
    """Every SDO write that configures drive ``d`` from the rig config, in order, each with the
    config key path its value comes from. ``table`` (default: the shipped table of ``d.type``)
    decides the writes the drive family may lack: 0x6066 and 0x605A (absent on the EPOS2) are
    planned only when the drive has them or the config sets them; 0x60C2 is planned for ``csp``
    (required: the SYNC period must be in its range) and otherwise only when in range."""
    table = table or shipped_table(d.type)
    k = key or f"drives[name={d.name}]"
    mode = MODE_BY_NAME[d.mode]
    lo, hi = d.software_limits_counts
    w = [
        SdoWrite(MODES_OF_OPERATION, 0, _i8(int(mode)), "modes of operation", f"{k}.mode"),
        SdoWrite(
            FOLLOWING_ERROR_WINDOW,
            0,
            _u32(d.following_error_window_counts),
            "following error window",
            f"{k}.following_error_window_counts",
        ),
    ]
    if not _unset_and_absent(d, "following_error_timeout_ms", table, FOLLOWING_ERROR_TIMEOUT):
        w.append(
            SdoWrite(
                FOLLOWING_ERROR_TIMEOUT,
                0,
                _u16(d.following_error_timeout_ms),
                "following error time out",
                f"{k}.following_error_timeout_ms",
            )
        )
    lim = f"{k}.software_limits_counts"
    w += [
        SdoWrite(SOFTWARE_POSITION_LIMIT, 1, _i32(lo), "software position limit min", lim),
        SdoWrite(SOFTWARE_POSITION_LIMIT, 2, _i32(hi), "software position limit max", lim),
        SdoWrite(
            PROFILE_VELOCITY,
            0,
            _u32(d.max_profile_velocity_rpm),
            "profile velocity",
            f"{k}.max_profile_velocity_rpm",
        ),
        SdoWrite(
            PROFILE_ACCELERATION,
            0,
            _u32(d.profile_acceleration_rpm_s),
            "profile acceleration",
            f"{k}.profile_acceleration_rpm_s",
        ),
        SdoWrite(
            PROFILE_DECELERATION,
            0,
            _u32(d.profile_acceleration_rpm_s),
            "profile deceleration",
            f"{k}.profile_acceleration_rpm_s",
        ),
        SdoWrite(
            QUICK_STOP_DECELERATION,
            0,
            _u32(d.quick_stop_deceleration_rpm_s),
            "quick stop deceleration",
            f"{k}.quick_stop_deceleration_rpm_s",
        ),
    ]
    if not _unset_and_absent(d, "quick_stop_option_code", table, QUICK_STOP_OPTION):
        w.append(
            SdoWrite(
                QUICK_STOP_OPTION,
                0,
                _i16(d.quick_stop_option_code),
                "quick stop option code",
                f"{k}.quick_stop_option_code",
            )
        )
    if mode in SYNCED_MODES:
        period = interpolation_period_ms(bus, file, table)
    elif _whole_ms(bus.sync_period_s) and table.accepts(
        INTERPOLATION_PERIOD, 1, round(bus.sync_period_s * 1e3)
    ):
        # Profile position ignores it, EPOS2 modes take their time elsewhere: written when the
        # drive accepts it, so every drive knows the period of its SYNCs.
        period = round(bus.sync_period_s * 1e3)
    else:
        period = None
    if period is not None:
        w.append(
            SdoWrite(
                INTERPOLATION_PERIOD,
                1,
                _u8(period),
                "interpolation time period (ms)",
                "can.sync_period_s",
            )
        )
    if mode is Mode.INTERPOLATED_POSITION:
        w += [
            SdoWrite(
                EPOS2_IP_SUBMODE, 0, _i16(IP_SUBMODE_PVT), "interpolation sub mode PVT", f"{k}.mode"
            ),
            SdoWrite(IP_DATA_CONFIGURATION, 6, _u8(0), "IP buffer clear", f"{k}.mode"),
            SdoWrite(IP_DATA_CONFIGURATION, 6, _u8(1), "IP buffer enable", f"{k}.mode"),
        ]
    w += [
        SdoWrite(
            HEARTBEAT_PRODUCER,
            0,
            _u16(d.heartbeat_producer_ms),
            "heartbeat producer time",
            f"{k}.heartbeat_producer_ms",
        ),
        SdoWrite(
            HEARTBEAT_CONSUMER,
            1,
            _u32((bus.master_node_id << 16) | d.heartbeat_consumer_ms),
            "heartbeat consumer of the master",
            f"{k}.heartbeat_consumer_ms",
        ),
    ]
    return w + [w_._replace(key=f"{k}.mode") for w_ in pdo_mapping_writes(d.node_id, mode)]


def homing_writes(d: DriveConfig, key: str = "") -> list[SdoWrite]:
    """SDO writes that prepare homing with ``d.homing`` (mode 6 is set by the caller).

    EPOS4: home position 0x30B0, home offset move distance 0x30B1, current threshold 0x30B2;
    EPOS2: home position 0x2081, home offset 0x607C, current threshold 0x2080 (maxon's files)."""
    h = d.homing
    k = f"{key or f'drives[name={d.name}]'}.homing"
    if d.type == "epos4":
        threshold, offset, home = (
            EPOS4_HOMING_CURRENT_THRESHOLD,
            EPOS4_HOME_OFFSET_MOVE,
            EPOS4_HOME_POSITION,
        )
    else:
        threshold, offset, home = (
            EPOS2_HOMING_CURRENT_THRESHOLD,
            EPOS2_HOME_OFFSET,
            EPOS2_HOME_POSITION,
        )
    w = [
        SdoWrite(HOMING_METHOD, 0, _i8(h.method), "homing method", f"{k}.method"),
        SdoWrite(HOMING_SPEEDS, 1, _u32(h.speed_rpm), "speed for switch search", f"{k}.speed_rpm"),
        SdoWrite(HOMING_SPEEDS, 2, _u32(h.speed_rpm), "speed for zero search", f"{k}.speed_rpm"),
        SdoWrite(
            HOMING_ACCELERATION,
            0,
            _u32(h.acceleration_rpm_s),
            "homing acceleration",
            f"{k}.acceleration_rpm_s",
        ),
        SdoWrite(
            offset, 0, _i32(h.offset_counts), "home offset move distance", f"{k}.offset_counts"
        ),
        SdoWrite(
            home, 0, _i32(h.home_position_counts), "home position", f"{k}.home_position_counts"
        ),
    ]
    if h.method in (-1, -2, -3, -4):
        w.append(
            SdoWrite(
                threshold,
                0,
                _u16(h.current_threshold_mA),
                "homing current threshold",
                f"{k}.current_threshold_mA",
            )
        )
    return w


# ---------------------------------------------------------------------------- payloads
_TARGET = struct.Struct("<i")
_CW = struct.Struct("<H")
_PP = struct.Struct("<iH")
_FEEDBACK = struct.Struct("<Hi")
INT24_MIN, INT24_MAX = -(1 << 23), (1 << 23) - 1


def target_payload(target_counts: int) -> bytes:
    """csp RPDO1 (0x607A) or pm RPDO1 (0x2062): int32 little endian."""
    return _TARGET.pack(target_counts)


def controlword_payload(controlword: int) -> bytes:
    """RPDO2: controlword 0x6040, uint16 little endian."""
    return _CW.pack(controlword & 0xFFFF)


def pp_setpoint_payload(target_counts: int, controlword: int) -> bytes:
    """pp RPDO1: target 0x607A (int32) then controlword 0x6040 (uint16), as mapped."""
    return _PP.pack(target_counts, controlword & 0xFFFF)


def pvt_payload(position_counts: int, velocity_rpm: int, time_ms: int) -> bytes:
    """EPOS2 interpolation data record 0x20C1: position int32, velocity int24 (rpm), time uint8
    (ms from the previous point), little endian, 8 bytes."""
    if not INT24_MIN <= velocity_rpm <= INT24_MAX:
        raise ValueError(f"PVT velocity {velocity_rpm} rpm does not fit 24 bits")
    if not 0 <= time_ms <= 255:
        raise ValueError(f"PVT time {time_ms} ms does not fit 8 bits")
    return (
        _TARGET.pack(position_counts)
        + velocity_rpm.to_bytes(3, "little", signed=True)
        + bytes((time_ms,))
    )


def parse_pvt(data: bytes) -> tuple[int, int, int] | None:
    """0x20C1 record -> (position counts, velocity rpm, time ms); None if not 8 bytes."""
    if len(data) != 8:
        return None
    (pos,) = _TARGET.unpack_from(data)
    vel = int.from_bytes(data[4:7], "little", signed=True)
    return pos, vel, data[7]


def parse_tpdo_feedback(data: bytes) -> tuple[int, int] | None:
    """TPDO1 data -> (statusword, actual position counts); None if the length is wrong."""
    if len(data) != _FEEDBACK.size:
        return None
    sw, pos = _FEEDBACK.unpack(data)
    return sw, pos


def counts_per_s_to_rpm(velocity_counts_s: float, counts_per_rev: int) -> int:
    """Motor velocity in counts/s -> whole rpm (EPOS velocity unit), rounded."""
    return round(velocity_counts_s * 60.0 / counts_per_rev)
