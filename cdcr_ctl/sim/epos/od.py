"""The simulated EPOS's object dictionary: the real EPOS4/EPOS2 indices the controller uses."""

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
    ODArray,
    ODRecord,
    ODVariable,
)

#: maxon motor ag vendor id (CiA) and product codes as the EPOS4 / EPOS2 report them in 0x1018.
MAXON_VENDOR_ID = 0x000000FB
PRODUCT_CODE = {"epos4": 0x65520000, "epos2": 0x63500000}
#: 0x1000 device type: CiA 402 drive (0x0192) with servo drive bits.
DEVICE_TYPE = 0x00020192


def _var(index: int, sub: int, name: str, dtype: int, default: int, access: str = "rw"):
    v = ODVariable(name, index, sub)
    v.data_type = dtype
    v.access_type = access
    v.default = default
    return v


def _simple(od: ObjectDictionary, index: int, name: str, dtype: int, default: int, access="rw"):
    od.add_object(_var(index, 0, name, dtype, default, access))


def _record(od, index: int, name: str, members: list[tuple[int, str, int, int, str]]):
    rec = ODRecord(name, index)
    for sub, mname, dtype, default, access in members:
        rec.add_member(_var(index, sub, mname, dtype, default, access))
    od.add_object(rec)


def _array(od, index: int, name: str, n: int, dtype: int, default: int, access="rw", used=None):
    arr = ODArray(name, index)
    count = n if used is None else used
    arr.add_member(_var(index, 0, "Number of entries", UNSIGNED8, count, "rw"))
    for sub in range(1, n + 1):
        arr.add_member(_var(index, sub, f"{name} {sub}", dtype, default, access))
    od.add_object(arr)


def build_od(node_id: int, kind: str) -> ObjectDictionary:
    """Object dictionary of one simulated drive (``kind`` ``epos4`` or ``epos2``)."""
    od = ObjectDictionary()
    od.node_id = node_id
    _simple(od, 0x1000, "Device type", UNSIGNED32, DEVICE_TYPE, "ro")
    _simple(od, 0x1001, "Error register", UNSIGNED8, 0, "ro")
    _array(od, 0x1016, "Consumer heartbeat time", 1, UNSIGNED32, 0)
    _simple(od, 0x1017, "Producer heartbeat time", UNSIGNED16, 0)
    _record(
        od,
        0x1018,
        "Identity object",
        [
            (0, "Highest sub-index supported", UNSIGNED8, 4, "ro"),
            (1, "Vendor-ID", UNSIGNED32, MAXON_VENDOR_ID, "ro"),
            (2, "Product code", UNSIGNED32, PRODUCT_CODE[kind], "ro"),
            (3, "Revision number", UNSIGNED32, 0x01700000, "ro"),
            (4, "Serial number", UNSIGNED32, 0x1000 + node_id, "ro"),
        ],
    )
    # PDO communication and mapping parameters: defaults as an EPOS leaves the factory
    # (RPDO1 controlword + target, TPDO1 statusword + actual position), rewritten by the master.
    for i, (cob, ttype) in enumerate([(0x200, 255), (0x300, 255), (0x400, 255), (0x500, 255)]):
        _record(
            od,
            0x1400 + i,
            f"RPDO{i + 1} communication parameter",
            [
                (0, "Highest sub-index supported", UNSIGNED8, 2, "ro"),
                (1, "COB-ID", UNSIGNED32, cob + node_id, "rw"),
                (2, "Transmission type", UNSIGNED8, ttype, "rw"),
            ],
        )
        _array(od, 0x1600 + i, f"RPDO{i + 1} mapping", 8, UNSIGNED32, 0, used=0)
    for i, cob in enumerate([0x180, 0x280, 0x380, 0x480]):
        _record(
            od,
            0x1800 + i,
            f"TPDO{i + 1} communication parameter",
            [
                (0, "Highest sub-index supported", UNSIGNED8, 5, "ro"),
                (1, "COB-ID", UNSIGNED32, cob + node_id, "rw"),
                (2, "Transmission type", UNSIGNED8, 1, "rw"),
                (3, "Inhibit time", UNSIGNED16, 0, "rw"),
                (5, "Event timer", UNSIGNED16, 0, "rw"),
            ],
        )
        _array(od, 0x1A00 + i, f"TPDO{i + 1} mapping", 8, UNSIGNED32, 0, used=0)
    od[0x1600][0].default = 2
    od[0x1600][1].default = 0x60400010
    od[0x1600][2].default = 0x607A0020
    od[0x1A00][0].default = 2
    od[0x1A00][1].default = 0x60410010
    od[0x1A00][2].default = 0x60640020
    for index, name, dtype, default in [
        (0x6040, "Controlword", UNSIGNED16, 0),
        (0x6041, "Statusword", UNSIGNED16, 0),
        (0x6060, "Modes of operation", INTEGER8, 0),
        (0x6061, "Modes of operation display", INTEGER8, 0),
        (0x6064, "Position actual value", INTEGER32, 0),
        (0x6065, "Following error window", UNSIGNED32, 2000),
        (0x6066, "Following error time out", UNSIGNED16, 0),
        (0x607A, "Target position", INTEGER32, 0),
        (0x607C, "Home offset", INTEGER32, 0),
        (0x6081, "Profile velocity", UNSIGNED32, 1000),
        (0x6083, "Profile acceleration", UNSIGNED32, 10000),
        (0x6084, "Profile deceleration", UNSIGNED32, 10000),
        (0x6085, "Quick stop deceleration", UNSIGNED32, 50000),
        (0x6098, "Homing method", INTEGER8, 37),
        (0x609A, "Homing acceleration", UNSIGNED32, 1000),
        (0x6502, "Supported drive modes", UNSIGNED32, 0x000003ED if kind == "epos4" else 0x6D),
    ]:
        _simple(
            od,
            index,
            name,
            dtype,
            default,
            "ro" if index in (0x6041, 0x6061, 0x6064, 0x6502) else "rw",
        )
    _record(
        od,
        0x607D,
        "Software position limit",
        [
            (0, "Highest sub-index supported", UNSIGNED8, 2, "ro"),
            (1, "Min position limit", INTEGER32, -2_147_483_648, "rw"),
            (2, "Max position limit", INTEGER32, 2_147_483_647, "rw"),
        ],
    )
    _array(od, 0x6099, "Homing speeds", 2, UNSIGNED32, 100)
    _record(
        od,
        0x60C2,
        "Interpolation time period",
        [
            (0, "Highest sub-index supported", UNSIGNED8, 2, "ro"),
            (1, "Interpolation time period value", UNSIGNED8, 1, "rw"),
            (2, "Interpolation time index", INTEGER8, -3, "rw"),
        ],
    )
    if kind == "epos4":
        _simple(od, 0x30B2, "Homing current threshold", UNSIGNED16, 500)
    else:
        # EPOS2 objects: position mode setting value, homing current threshold, home position.
        _simple(od, 0x2062, "Position mode setting value", INTEGER32, 0)
        _simple(od, 0x2080, "Current threshold for homing mode", UNSIGNED16, 500)
        _simple(od, 0x2081, "Home position", INTEGER32, 0)
        # Interpolated position mode: sub mode (-1 = PVT), the data record a PDO carries
        # (position int32, velocity int24 rpm, time uint8 ms), and the buffer status.
        _simple(od, 0x20C0, "Interpolation sub mode select", INTEGER16, 0)
        _record(
            od,
            0x20C1,
            "Interpolation data record",
            [
                (0, "Highest sub-index supported", UNSIGNED8, 1, "ro"),
                (1, "PVT reference point", UNSIGNED64, 0, "wo"),
            ],
        )
        _simple(od, 0x20C4, "Interpolation buffer status", UNSIGNED16, 0, "ro")
    return od
