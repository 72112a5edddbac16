"""What an EPOS4 / EPOS2 accepts: every object the master reads or writes, with its data type,
access and value range, as maxon's device description files state them. Pure: no I/O.

The table is this project's own summary, written from maxon's published electronic data sheets
(read, not copied; only the objects a master of this rig touches):

- EPOS4: "Electronic Data Sheet for EPOS4 Module 50/5", firmware 0x0150, maxon motor ag 2018,
  as carried by github.com/Pejman712/CRF, ``modules/Devices/CANopenDrivers/config/MaxonEPOS4/
  MaxonEPOS4.eds``;
- EPOS2: "Electronic Data Sheet for EPOS2 70/10", revision 0x2122, same repository,
  ``modules/Devices/CANopenDrivers/config/MaxonEPOS2/MaxonEPOS2.eds``.

What the files say that a master must respect (and the simulated drive enforces):

- EPOS4 0x6066 following error timeout has the range 0..0: the drive faults as soon as the
  following error leaves the window; any other value is refused (abort 0x06090031).
- EPOS4 0x60C2:1 interpolation time period is 0..100 (units of 10^0x60C2:2 s, index -3: ms);
  the EPOS2 file allows 1..1 only (its interpolated position mode takes the time per PVT record).
- EPOS4 homing: 0x30B0 is the home position, 0x30B1 the home offset move distance.
- EPOS2 has no 0x6066, no 0x605A and no 0x603F; its interpolation sub mode is 0x60C0 (-1, PVT).
- 0x1003 error history has 5 entries on both.

A drive config may name its own device description (``eds:``): :func:`table_from_od` turns what
canopen's :func:`~canopen.objectdictionary.import_od` read into the same kind of table.
:func:`check_write` is the one check, for both tables.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import NamedTuple

from canopen.objectdictionary import (
    BOOLEAN,
    INTEGER8,
    INTEGER16,
    INTEGER32,
    INTEGER64,
    UNSIGNED8,
    UNSIGNED16,
    UNSIGNED32,
    UNSIGNED64,
    ODArray,
    ODRecord,
    ODVariable,
)

#: CiA 301 data types this table knows: code -> (name, struct format).
DATA_TYPES: dict[int, tuple[str, str]] = {
    BOOLEAN: ("BOOLEAN", "<?"),
    INTEGER8: ("INTEGER8", "<b"),
    INTEGER16: ("INTEGER16", "<h"),
    INTEGER32: ("INTEGER32", "<i"),
    INTEGER64: ("INTEGER64", "<q"),
    UNSIGNED8: ("UNSIGNED8", "<B"),
    UNSIGNED16: ("UNSIGNED16", "<H"),
    UNSIGNED32: ("UNSIGNED32", "<I"),
    UNSIGNED64: ("UNSIGNED64", "<Q"),
    0x1B: ("UNSIGNED64", "<Q"),  # EPOS2 files give the 8-byte PVT record type 0x1B
}

#: SDO abort codes (CiA 301) a drive answers for what :func:`check_write` refuses.
ABORT_NO_OBJECT = 0x06020000
ABORT_NO_SUBINDEX = 0x06090011
ABORT_READ_ONLY = 0x06010002
ABORT_WRITE_ONLY = 0x06010001
ABORT_LENGTH = 0x06070010
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_VALUE_TOO_LOW = 0x06090032


@dataclass(frozen=True)
class ObjectLimit:
    """One object (index, subindex): data type code, access (ro, wo, rw, rww, rwr, const), the
    inclusive value range (None: the type's whole range) and its name."""

    index: int
    sub: int
    dtype: int
    access: str
    name: str
    low: int | None = None
    high: int | None = None

    @property
    def writable(self) -> bool:
        return self.access in ("rw", "rww", "rwr", "wo")

    @property
    def readable(self) -> bool:
        return self.access != "wo"

    @property
    def size(self) -> int:
        return struct.calcsize(DATA_TYPES[self.dtype][1])

    def decode(self, data: bytes) -> int:
        return int(struct.unpack(DATA_TYPES[self.dtype][1], data)[0])


class Refusal(NamedTuple):
    """Why a write would be refused: the SDO abort code a drive answers and the text."""

    code: int
    text: str


class ObjectTable:
    """Objects by (index, subindex); ``source`` says where the table came from."""

    def __init__(self, objects: Iterable[ObjectLimit], source: str) -> None:
        self.objects: dict[tuple[int, int], ObjectLimit] = {(o.index, o.sub): o for o in objects}
        self.indices = {o.index for o in self.objects.values()}
        self.source = source

    def get(self, index: int, sub: int) -> ObjectLimit | None:
        return self.objects.get((index, sub))

    def has(self, index: int, sub: int = 0) -> bool:
        return (index, sub) in self.objects

    def accepts(self, index: int, sub: int, value: int) -> bool:
        """Is ``value`` inside the object's range (False when the object does not exist)?"""
        o = self.get(index, sub)
        if o is None:
            return False
        return (o.low is None or value >= o.low) and (o.high is None or value <= o.high)


def check_write(table: ObjectTable, index: int, sub: int, data: bytes) -> Refusal | None:
    """What a drive with ``table`` answers to an SDO download of ``data`` to ``index:sub``:
    None (accepted) or the refusal (existence, access, data length/type, range)."""
    o = table.get(index, sub)
    if o is not None and o.writable and o.dtype in DATA_TYPES and len(data) == o.size:
        value = o.decode(data)
        if (o.low is None or value >= o.low) and (o.high is None or value <= o.high):
            return None  # accepted (the common case: no text to format)
    where = f"0x{index:04X}:{sub:02X}"
    if o is None:
        if index in table.indices:
            return Refusal(ABORT_NO_SUBINDEX, f"{where}: no such subindex ({table.source})")
        return Refusal(ABORT_NO_OBJECT, f"{where}: no such object ({table.source})")
    if not o.writable:
        return Refusal(ABORT_READ_ONLY, f"{where} {o.name!r} is {o.access}, not writable")
    if o.dtype not in DATA_TYPES:
        return None  # strings and domains: nothing the master plans
    if len(data) != o.size:
        return Refusal(
            ABORT_LENGTH,
            f"{where} {o.name!r} is {DATA_TYPES[o.dtype][0]} ({o.size} bytes), "
            f"not {len(data)} bytes",
        )
    value = o.decode(data)
    if o.low is not None and value < o.low:
        return Refusal(
            ABORT_VALUE_TOO_LOW, f"{where} {o.name!r}: {value} below its range {o.low}..{o.high}"
        )
    if o.high is not None and value > o.high:
        return Refusal(
            ABORT_VALUE_TOO_HIGH,
            f"{where} {o.name!r}: {value} above its range {o.low}..{o.high}",
        )
    return None


# ------------------------------------------------------------------------------ the shipped table
_U8, _U16, _U32, _I8, _I16, _I32 = UNSIGNED8, UNSIGNED16, UNSIGNED32, INTEGER8, INTEGER16, INTEGER32


def _pdo_objects(map_entries: int) -> list[ObjectLimit]:
    """RPDO/TPDO 1-4 communication and mapping parameters (the same shape in both files; the
    EPOS4 maps up to 12 objects per PDO, the EPOS2 up to 8)."""
    out: list[ObjectLimit] = []
    for i in range(4):
        for comm, mapping, kind in (
            (0x1400 + i, 0x1600 + i, "RxPDO"),
            (0x1800 + i, 0x1A00 + i, "TxPDO"),
        ):
            out += [
                ObjectLimit(comm, 0, _U8, "ro", "Highest sub-index supported"),
                ObjectLimit(comm, 1, _U32, "rw", f"COB-ID used by {kind} {i + 1}"),
                ObjectLimit(comm, 2, _U8, "rw", f"Transmission type {kind} {i + 1}"),
                ObjectLimit(
                    mapping, 0, _U8, "rw", f"Mapped objects in {kind} {i + 1}", 0, map_entries
                ),
            ]
            if kind == "TxPDO":
                out.append(ObjectLimit(comm, 3, _U16, "rw", f"Inhibit time {kind} {i + 1}"))
            out += [
                ObjectLimit(mapping, s, _U32, "rw", f"Mapped object {s} in {kind} {i + 1}")
                for s in range(1, map_entries + 1)
            ]
    return out


def _common() -> list[ObjectLimit]:
    """Objects both files give the same type and access (names as in the EPOS4 file)."""
    return [
        ObjectLimit(0x1000, 0, _U32, "ro", "Device type"),
        ObjectLimit(0x1001, 0, _U8, "ro", "Error register"),
        ObjectLimit(0x1003, 0, _U8, "rw", "Number of errors"),
        *(ObjectLimit(0x1003, s, _U32, "ro", f"Error history {s}") for s in range(1, 6)),
        ObjectLimit(0x1016, 0, _U8, "ro", "Highest sub-index supported"),
        ObjectLimit(0x1016, 1, _U32, "rw", "Consumer 1 heartbeat time"),
        ObjectLimit(0x1016, 2, _U32, "rw", "Consumer 2 heartbeat time"),
        ObjectLimit(0x1017, 0, _U16, "rw", "Producer heartbeat time"),
        ObjectLimit(0x1018, 0, _U8, "ro", "Highest sub-index supported"),
        ObjectLimit(0x1018, 1, _U32, "ro", "Vendor-ID"),
        ObjectLimit(0x1018, 2, _U32, "ro", "Product code"),
        ObjectLimit(0x1018, 3, _U32, "ro", "Revision number"),
        ObjectLimit(0x1018, 4, _U32, "ro", "Serial number"),
        ObjectLimit(0x6040, 0, _U16, "rww", "Controlword"),
        ObjectLimit(0x6041, 0, _U16, "ro", "Statusword"),
        ObjectLimit(0x6060, 0, _I8, "rww", "Modes of operation"),
        ObjectLimit(0x6061, 0, _I8, "ro", "Modes of operation display"),
        ObjectLimit(0x6064, 0, _I32, "ro", "Position actual value"),
        ObjectLimit(0x6065, 0, _U32, "rww", "Following error window"),
        ObjectLimit(0x607A, 0, _I32, "rww", "Target position"),
        ObjectLimit(0x607D, 0, _U8, "const", "Highest sub-index supported"),
        ObjectLimit(0x6081, 0, _U32, "rww", "Profile velocity"),
        ObjectLimit(0x6098, 0, _I8, "rww", "Homing method"),
        ObjectLimit(0x6099, 0, _U8, "const", "Highest sub-index supported"),
        ObjectLimit(0x6099, 1, _U32, "rww", "Speed for switch search"),
        ObjectLimit(0x6099, 2, _U32, "rww", "Speed for zero search"),
        ObjectLimit(0x60C2, 0, _U8, "const", "Highest sub-index supported"),
        ObjectLimit(0x6502, 0, _U32, "ro", "Supported drive modes"),
    ]


_U32_MAX = 0xFFFF_FFFF

#: EPOS4 (MaxonEPOS4.eds, see the module docstring).
EPOS4_OBJECTS: tuple[ObjectLimit, ...] = (
    *_common(),
    *_pdo_objects(12),
    ObjectLimit(0x603F, 0, _U16, "ro", "Error code"),
    ObjectLimit(0x605A, 0, _I16, "rw", "Quick stop option code"),
    ObjectLimit(0x6066, 0, _U16, "rww", "Following error timeout", 0, 0),
    ObjectLimit(0x607D, 1, _I32, "rww", "Min position limit"),
    ObjectLimit(0x607D, 2, _I32, "rww", "Max position limit"),
    ObjectLimit(0x607F, 0, _U32, "rww", "Max profile velocity"),
    ObjectLimit(0x6083, 0, _U32, "rww", "Profile acceleration", 1, _U32_MAX),
    ObjectLimit(0x6084, 0, _U32, "rww", "Profile deceleration", 1, _U32_MAX),
    ObjectLimit(0x6085, 0, _U32, "rww", "Quick stop deceleration", 1, _U32_MAX),
    ObjectLimit(0x609A, 0, _U32, "rww", "Homing acceleration", 1, _U32_MAX),
    ObjectLimit(0x60C2, 1, _U8, "rww", "Interpolation time period value", 0, 100),
    ObjectLimit(0x60C2, 2, _I8, "rww", "Interpolation time index"),
    ObjectLimit(0x30B0, 0, _I32, "rww", "Home position"),
    ObjectLimit(0x30B1, 0, _I32, "rw", "Home offset move distance"),
    ObjectLimit(0x30B2, 0, _U16, "rww", "Current threshold for homing mode", 0, 5000),
)

#: EPOS2 (MaxonEPOS2.eds, see the module docstring).
EPOS2_OBJECTS: tuple[ObjectLimit, ...] = (
    *_common(),
    *_pdo_objects(8),
    ObjectLimit(0x6067, 0, _U32, "rw", "Position window"),
    ObjectLimit(0x607C, 0, _I32, "rww", "Home offset"),
    ObjectLimit(0x607D, 1, _I32, "rw", "Min position limit"),
    ObjectLimit(0x607D, 2, _I32, "rw", "Max position limit"),
    ObjectLimit(0x607F, 0, _U32, "rw", "Max profile velocity", 0, 25000),
    ObjectLimit(0x6083, 0, _U32, "rww", "Profile acceleration"),
    ObjectLimit(0x6084, 0, _U32, "rww", "Profile deceleration"),
    ObjectLimit(0x6085, 0, _U32, "rww", "Quick stop deceleration"),
    ObjectLimit(0x609A, 0, _U32, "rww", "Homing acceleration"),
    ObjectLimit(0x60C0, 0, _I16, "rw", "Interpolation sub mode selection", -1, -1),
    ObjectLimit(0x60C2, 1, _U8, "rw", "Interpolation time period value", 1, 1),
    ObjectLimit(0x60C2, 2, _I8, "rw", "Interpolation time index", -3, -3),
    ObjectLimit(0x60C4, 0, _U8, "const", "Highest sub-index supported"),
    ObjectLimit(0x60C4, 1, _U32, "ro", "Maximum buffer size"),
    ObjectLimit(0x60C4, 2, _U32, "ro", "Actual buffer size"),
    ObjectLimit(0x60C4, 3, _U8, "rw", "Buffer organisation", 0, 0),
    ObjectLimit(0x60C4, 4, _U16, "rw", "Buffer position", 0, 64),
    ObjectLimit(0x60C4, 5, _U8, "wo", "Size of data record", 8, 8),
    ObjectLimit(0x60C4, 6, _U8, "wo", "Buffer clear", 0, 1),
    ObjectLimit(0x2062, 0, _I32, "rww", "Position mode setting value"),
    ObjectLimit(0x2080, 0, _U16, "rww", "Current threshold for homing mode"),
    ObjectLimit(0x2081, 0, _I32, "rww", "Home position"),
    ObjectLimit(0x20C1, 0, UNSIGNED64, "wo", "Interpolation data record"),
    ObjectLimit(0x20C4, 0, _U8, "ro", "Highest sub-index supported"),
    ObjectLimit(0x20C4, 1, _U16, "ro", "Interpolation buffer status"),
    ObjectLimit(0x20C4, 2, _U16, "rw", "Interpolation buffer underflow warning", 0, 63),
    ObjectLimit(0x20C4, 3, _U16, "rw", "Interpolation buffer overflow warning", 1, 64),
)

SHIPPED: Mapping[str, ObjectTable] = {
    "epos4": ObjectTable(EPOS4_OBJECTS, "the EPOS4 limits table"),
    "epos2": ObjectTable(EPOS2_OBJECTS, "the EPOS2 limits table"),
}


def shipped_table(family: str) -> ObjectTable:
    """The project's table for ``family`` (``epos4`` / ``epos2``)."""
    return SHIPPED[family]


def table_from_od(od: object, source: str) -> ObjectTable:
    """A table from a canopen ObjectDictionary (what ``import_od`` read from an EDS/DCF/XDD)."""
    objects: list[ObjectLimit] = []
    for obj in od.values():  # type: ignore[attr-defined]
        members = [obj] if isinstance(obj, ODVariable) else []
        if isinstance(obj, (ODRecord, ODArray)):
            members = list(obj.values())
        for v in members:
            low = None if v.min is None else int(v.min)
            high = None if v.max is None else int(v.max)
            objects.append(
                ObjectLimit(v.index, v.subindex, v.data_type or 0, v.access_type, v.name, low, high)
            )
    return ObjectTable(objects, source)
