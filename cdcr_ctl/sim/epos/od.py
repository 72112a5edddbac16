"""The simulated EPOS's object dictionary, written here in code: the real EPOS4/EPOS2 indices a
master uses (CiA 301 communication objects, CiA 402 objects, and the maxon-specific ones of each
family), with the access rights and PDO mappability a master relies on.

Factory defaults as a drive leaves the factory (not as the rig config wants it), so a master has
to configure it: RPDO1 controlword + target position (event-driven), TPDO1 statusword + actual
position on every SYNC, and TPDO2 statusword + actual velocity on every SYNC too (extra bus load a
master should switch off). NMT reset communication brings 0x1000-0x1FFF back to these values.
"""

from __future__ import annotations

from canopen import ObjectDictionary
from canopen.objectdictionary import (
    INTEGER8,
    INTEGER16,
    INTEGER32,
    UNSIGNED8,
    UNSIGNED16,
    UNSIGNED32,
    UNSIGNED64,
    VISIBLE_STRING,
    ODArray,
    ODRecord,
    ODVariable,
)

from cdcr_ctl.drives import epos

#: Product codes the simulated drives report in 0x1018:2 (simulator values, not maxon's list).
PRODUCT_CODE = {"epos4": 0x65520000, "epos2": 0x63500000}
#: 0x1000 device type: CiA 402 drive (0x0192) with the servo-drive bit in the additional info.
DEVICE_TYPE = 0x00020192
#: 0x6502 supported drive modes (bit 0 PP, 2 PV, 5 HM, 6 IP, 7 CSP, 8 CSV, 9 CST; EPOS2's
#: maxon-specific position/velocity/current modes in bits 16-18).
SUPPORTED_MODES = {"epos4": 0x000003A5, "epos2": 0x00070065}
#: Modes of operation (0x6060) each family accepts.
ACCEPTED_MODES = {"epos4": {1, 3, 6, 8, 9, 10}, "epos2": {1, 3, 6, 7, -1, -2, -3, -5, -6}}
#: Entries of the 0x1003 error history (both families' device descriptions give 5).
ERROR_HISTORY = 5
#: Objects maxon's EPOS2 description does not have (error code, quick stop option, following
#: error timeout): the simulated EPOS2 lacks them too.
EPOS2_ABSENT = (0x603F, epos.QUICK_STOP_OPTION, epos.FOLLOWING_ERROR_TIMEOUT)
#: EPOS2 PVT buffer depth (0x60C4:1).
IP_BUFFER_SIZE = 64


def _var(
    index: int,
    sub: int,
    name: str,
    dtype: int,
    default: object,
    access: str = "rw",
    mappable: bool = False,
) -> ODVariable:
    v = ODVariable(name, index, sub)
    v.data_type = dtype
    v.access_type = access
    v.default = default
    v.pdo_mappable = mappable
    return v


def _simple(
    od: ObjectDictionary,
    index: int,
    name: str,
    dtype: int,
    default: object,
    access: str = "rw",
    mappable: bool = False,
) -> None:
    od.add_object(_var(index, 0, name, dtype, default, access, mappable))


def _record(
    od: ObjectDictionary,
    index: int,
    name: str,
    members: list[tuple[int, str, int, object, str]],
    mappable: bool = False,
) -> None:
    rec = ODRecord(name, index)
    for sub, mname, dtype, default, access in members:
        rec.add_member(_var(index, sub, mname, dtype, default, access, mappable and sub > 0))
    od.add_object(rec)


def _array(
    od: ObjectDictionary,
    index: int,
    name: str,
    n: int,
    dtype: int,
    default: object,
    access: str = "rw",
    used: int | None = None,
    count_access: str = "rw",
) -> None:
    arr = ODArray(name, index)
    arr.add_member(
        _var(index, 0, "Number of entries", UNSIGNED8, n if used is None else used, count_access)
    )
    for sub in range(1, n + 1):
        arr.add_member(_var(index, sub, f"{name} {sub}", dtype, default, access))
    od.add_object(arr)


def build_od(node_id: int, kind: str) -> ObjectDictionary:
    """Object dictionary of one simulated drive (``kind`` ``epos4`` or ``epos2``)."""
    if kind not in PRODUCT_CODE:
        raise ValueError(f"kind must be 'epos4' or 'epos2', not {kind!r}")
    od = ObjectDictionary()
    od.node_id = node_id
    od.device_information.vendor_name = "maxon motor ag (simulated)"
    od.device_information.product_name = kind.upper()
    _simple(od, epos.DEVICE_TYPE, "Device type", UNSIGNED32, DEVICE_TYPE, "ro")
    _simple(od, epos.ERROR_REGISTER, "Error register", UNSIGNED8, 0, "ro", mappable=True)
    _array(od, 0x1003, "Pre-defined error field", ERROR_HISTORY, UNSIGNED32, 0, "ro", used=0)
    _simple(od, 0x1005, "COB-ID SYNC", UNSIGNED32, 0x80)
    _simple(od, 0x1008, "Manufacturer device name", VISIBLE_STRING, kind.upper(), "const")
    _simple(od, 0x1014, "COB-ID EMCY", UNSIGNED32, 0x80 + node_id, "ro")
    _array(
        od, epos.HEARTBEAT_CONSUMER, "Consumer heartbeat time", 2, UNSIGNED32, 0, count_access="ro"
    )
    _simple(od, epos.HEARTBEAT_PRODUCER, "Producer heartbeat time", UNSIGNED16, 0)
    _record(
        od,
        epos.IDENTITY,
        "Identity object",
        [
            (0, "Highest sub-index supported", UNSIGNED8, 4, "ro"),
            (1, "Vendor-ID", UNSIGNED32, epos.MAXON_VENDOR_ID, "ro"),
            (2, "Product code", UNSIGNED32, PRODUCT_CODE[kind], "ro"),
            (3, "Revision number", UNSIGNED32, 0x01700000, "ro"),
            (4, "Serial number", UNSIGNED32, 0x1000 + node_id, "ro"),
        ],
    )
    for i in range(4):
        _record(
            od,
            epos.RPDO_COMM + i,
            f"RPDO{i + 1} communication parameter",
            [
                (0, "Highest sub-index supported", UNSIGNED8, 2, "ro"),
                (
                    1,
                    "COB-ID",
                    UNSIGNED32,
                    (0x200 + 0x100 * i + node_id) | (0 if i == 0 else epos.PDO_DISABLED),
                    "rw",
                ),
                (2, "Transmission type", UNSIGNED8, 255, "rw"),
            ],
        )
        _array(od, epos.RPDO_MAP + i, f"RPDO{i + 1} mapping", 8, UNSIGNED32, 0, used=0)
        _record(
            od,
            epos.TPDO_COMM + i,
            f"TPDO{i + 1} communication parameter",
            [
                (0, "Highest sub-index supported", UNSIGNED8, 5, "ro"),
                (
                    1,
                    "COB-ID",
                    UNSIGNED32,
                    (0x180 + 0x100 * i + node_id) | (0 if i < 2 else epos.PDO_DISABLED),
                    "rw",
                ),
                (2, "Transmission type", UNSIGNED8, 1, "rw"),
                (3, "Inhibit time", UNSIGNED16, 0, "rw"),
                (5, "Event timer", UNSIGNED16, 0, "rw"),
            ],
        )
        _array(od, epos.TPDO_MAP + i, f"TPDO{i + 1} mapping", 8, UNSIGNED32, 0, used=0)
    for index, entries in (
        (
            epos.RPDO_MAP,
            (epos.map_entry(epos.CONTROLWORD, 0, 16), epos.map_entry(epos.TARGET_POSITION, 0, 32)),
        ),
        (
            epos.TPDO_MAP,
            (epos.map_entry(epos.STATUSWORD, 0, 16), epos.map_entry(epos.POSITION_ACTUAL, 0, 32)),
        ),
        (
            epos.TPDO_MAP + 1,
            (epos.map_entry(epos.STATUSWORD, 0, 16), epos.map_entry(epos.VELOCITY_ACTUAL, 0, 32)),
        ),
    ):
        od[index][0].default = len(entries)
        for sub, e in enumerate(entries, start=1):
            od[index][sub].default = e

    for index, name, dtype, default, access, mappable in (
        (0x603F, "Error code", UNSIGNED16, 0, "ro", True),
        (epos.CONTROLWORD, "Controlword", UNSIGNED16, 0, "rw", True),
        (epos.STATUSWORD, "Statusword", UNSIGNED16, 0, "ro", True),
        (epos.QUICK_STOP_OPTION, "Quick stop option code", INTEGER16, 2, "rw", False),
        (epos.MODES_OF_OPERATION, "Modes of operation", INTEGER8, 0, "rw", True),
        (epos.MODES_DISPLAY, "Modes of operation display", INTEGER8, 0, "ro", True),
        (0x6062, "Position demand value", INTEGER32, 0, "ro", True),
        (epos.POSITION_ACTUAL, "Position actual value", INTEGER32, 0, "ro", True),
        (epos.FOLLOWING_ERROR_WINDOW, "Following error window", UNSIGNED32, 2000, "rw", False),
        (epos.FOLLOWING_ERROR_TIMEOUT, "Following error time out", UNSIGNED16, 0, "rw", False),
        (0x6067, "Position window", UNSIGNED32, 4, "rw", False),
        (epos.VELOCITY_ACTUAL, "Velocity actual value", INTEGER32, 0, "ro", True),
        (epos.TARGET_POSITION, "Target position", INTEGER32, 0, "rw", True),
        (0x607F, "Max profile velocity", UNSIGNED32, 25000, "rw", False),
        (epos.PROFILE_VELOCITY, "Profile velocity", UNSIGNED32, 1000, "rw", True),
        (epos.PROFILE_ACCELERATION, "Profile acceleration", UNSIGNED32, 10000, "rw", True),
        (epos.PROFILE_DECELERATION, "Profile deceleration", UNSIGNED32, 10000, "rw", True),
        (epos.QUICK_STOP_DECELERATION, "Quick stop deceleration", UNSIGNED32, 50000, "rw", False),
        (epos.HOMING_METHOD, "Homing method", INTEGER8, 37, "rw", False),
        (epos.HOMING_ACCELERATION, "Homing acceleration", UNSIGNED32, 1000, "rw", False),
        (
            epos.SUPPORTED_DRIVE_MODES,
            "Supported drive modes",
            UNSIGNED32,
            SUPPORTED_MODES[kind],
            "ro",
            False,
        ),
    ):
        if kind == "epos2" and index in EPOS2_ABSENT:
            continue
        _simple(od, index, name, dtype, default, access, mappable)
    _record(
        od,
        epos.SOFTWARE_POSITION_LIMIT,
        "Software position limit",
        [
            (0, "Highest sub-index supported", UNSIGNED8, 2, "ro"),
            (1, "Min position limit", INTEGER32, -2_147_483_648, "rw"),
            (2, "Max position limit", INTEGER32, 2_147_483_647, "rw"),
        ],
    )
    _array(od, epos.HOMING_SPEEDS, "Homing speeds", 2, UNSIGNED32, 100, count_access="ro")
    _record(
        od,
        epos.INTERPOLATION_PERIOD,
        "Interpolation time period",
        [
            (0, "Highest sub-index supported", UNSIGNED8, 2, "ro"),
            (1, "Interpolation time period value", UNSIGNED8, 1, "rw"),
            (2, "Interpolation time index", INTEGER8, -3, "ro"),
        ],
    )
    if kind == "epos4":
        _simple(od, epos.EPOS4_HOME_OFFSET_MOVE, "Home offset move distance", INTEGER32, 0)
        _simple(od, epos.EPOS4_HOME_POSITION, "Home position", INTEGER32, 0)
        _simple(
            od,
            epos.EPOS4_HOMING_CURRENT_THRESHOLD,
            "Current threshold for homing mode",
            UNSIGNED16,
            500,
        )
    else:
        _simple(
            od,
            epos.EPOS2_POSITION_MODE_SETPOINT,
            "Position mode setting value",
            INTEGER32,
            0,
            "rw",
            True,
        )
        _simple(
            od,
            epos.EPOS2_HOMING_CURRENT_THRESHOLD,
            "Current threshold for homing mode",
            UNSIGNED16,
            500,
        )
        _simple(od, epos.EPOS2_HOME_POSITION, "Home position", INTEGER32, 0)
        _simple(od, epos.EPOS2_HOME_OFFSET, "Home offset", INTEGER32, 0)
        _simple(od, epos.EPOS2_IP_SUBMODE, "Interpolation sub mode selection", INTEGER16, -1)
        _simple(
            od, epos.EPOS2_IP_DATA_RECORD, "Interpolation data record", UNSIGNED64, 0, "wo", True
        )
        _record(
            od,
            epos.EPOS2_IP_BUFFER_STATUS,
            "Interpolation buffer",
            [
                (0, "Highest sub-index supported", UNSIGNED8, 3, "ro"),
                (1, "Buffer underflow warning", UNSIGNED16, 0, "rw"),
                (2, "Buffer overflow warning", UNSIGNED16, IP_BUFFER_SIZE, "rw"),
                (3, "Buffer status (points in the buffer)", UNSIGNED16, 0, "ro"),
            ],
        )
        _record(
            od,
            epos.IP_DATA_CONFIGURATION,
            "Interpolation data configuration",
            [
                (0, "Highest sub-index supported", UNSIGNED8, 6, "ro"),
                (1, "Maximum buffer size", UNSIGNED32, IP_BUFFER_SIZE, "ro"),
                (2, "Actual buffer size", UNSIGNED32, IP_BUFFER_SIZE, "ro"),
                (3, "Buffer organization", UNSIGNED8, 0, "ro"),
                (4, "Buffer position", UNSIGNED16, 0, "ro"),
                (5, "Size of data record", UNSIGNED8, 8, "ro"),
                (6, "Buffer clear", UNSIGNED8, 1, "rw"),
            ],
        )
    return od
