"""EMCY (CiA 301 emergency) codes of maxon EPOS4/EPOS2 drives as text: one table.

An EMCY frame (COB-ID 0x080 + node) carries the error code in bytes 0-1 (little endian), the error
register 0x1001 in byte 2 and five manufacturer-specific bytes. The table below lists the codes of
the EPOS4 and EPOS2 firmware specifications' error-code lists that a rig is likely to meet, per
family where the two differ (the 0xFFxx device-specific range and the limit-switch codes moved
between generations). A code missing from the table still decodes, to its CiA 301 class, and the
hexadecimal code is always part of the text a user sees.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Literal

Family = Literal["epos4", "epos2"]

#: (code, family or "both", text). One table: the EPOS codes the rig's errors are reported with.
EPOS_ERROR_TABLE: tuple[tuple[int, str, str], ...] = (
    (0x0000, "both", "no error (error reset)"),
    (0x1000, "both", "generic error"),
    (0x1080, "epos4", "generic initialization error"),
    (0x1090, "epos4", "firmware incompatibility error"),
    (0x2310, "both", "over-current error"),
    (0x2320, "both", "power stage protection error"),
    (0x3210, "both", "over-voltage error"),
    (0x3220, "both", "under-voltage error"),
    (0x4210, "both", "thermal overload error (power stage over temperature)"),
    (0x4380, "epos4", "thermal motor overload error"),
    (0x5113, "both", "logic supply voltage too low"),
    (0x5114, "epos2", "supply voltage output stage too low"),
    (0x5280, "epos4", "hardware defect error"),
    (0x5281, "epos4", "hardware incompatibility error"),
    (0x6080, "epos4", "sign of life error"),
    (0x6100, "both", "internal software error"),
    (0x6320, "both", "software parameter error"),
    (0x6380, "epos4", "persistent parameter corrupt error"),
    (0x7320, "both", "position sensor error"),
    (0x7380, "epos4", "position sensor breach error"),
    (0x7381, "epos4", "position sensor resolution error"),
    (0x7382, "epos4", "position sensor index error"),
    (0x7388, "epos4", "hall sensor error"),
    (0x7389, "epos4", "hall sensor not found error"),
    (0x738A, "epos4", "hall angle detection error"),
    (0x8110, "both", "CAN overrun error (objects lost)"),
    (0x8111, "both", "CAN overrun error"),
    (0x8120, "both", "CAN passive mode error"),
    (0x8130, "both", "CAN heartbeat error (life guard: the master went silent)"),
    (0x8150, "both", "CAN PDO COB-ID collision"),
    (0x81FD, "both", "CAN bus off"),
    (0x81FE, "both", "CAN Rx queue overflow"),
    (0x81FF, "both", "CAN Tx queue overflow"),
    (0x8210, "both", "CAN PDO length error"),
    (0x8250, "epos4", "RPDO timeout"),
    (0x8611, "both", "following error"),
    (0x8A80, "epos4", "negative limit switch error"),
    (0x8A81, "epos4", "positive limit switch error"),
    (0x8A82, "epos4", "software position limit error"),
    (0x8A88, "epos4", "STO error (safe torque off)"),
    (0xFF01, "epos4", "system overloaded error"),
    (0xFF02, "epos4", "watchdog error"),
    (0xFF0B, "epos4", "system peak overloaded error"),
    (0xFF10, "epos4", "controller gain error"),
    (0xFF11, "epos4", "auto tuning identification error"),
    (0xFF12, "epos4", "auto tuning current limit error"),
    (0xFF01, "epos2", "hall sensor error"),
    (0xFF02, "epos2", "index processing error"),
    (0xFF03, "epos2", "encoder resolution error"),
    (0xFF04, "epos2", "hall sensor not found error"),
    (0xFF06, "epos2", "negative limit switch error"),
    (0xFF07, "epos2", "positive limit switch error"),
    (0xFF08, "epos2", "hall angle detection error"),
    (0xFF09, "epos2", "software position limit error"),
    (0xFF0A, "epos2", "position sensor breach"),
    (0xFF0B, "epos2", "system overloaded"),
    (0xFF0C, "epos2", "interpolated position mode error (PVT buffer underflow/overflow)"),
    (0xFF0D, "epos2", "auto tuning identification error"),
)

_BY_FAMILY: dict[str, dict[int, str]] = {"epos4": {}, "epos2": {}}
for _code, _fam, _text in EPOS_ERROR_TABLE:
    for _f in ("epos4", "epos2") if _fam == "both" else (_fam,):
        _BY_FAMILY[_f][_code] = _text

#: Well-known codes by name (the fault-injection hooks and tests use these).
FOLLOWING_ERROR = 0x8611
OVER_CURRENT = 0x2310
OVER_VOLTAGE = 0x3210
HEARTBEAT_ERROR = 0x8130
BUS_OFF = 0x81FD
PDO_LENGTH_ERROR = 0x8210
SOFTWARE_LIMIT = {"epos4": 0x8A82, "epos2": 0xFF09}
NEGATIVE_LIMIT_SWITCH = {"epos4": 0x8A80, "epos2": 0xFF06}
POSITIVE_LIMIT_SWITCH = {"epos4": 0x8A81, "epos2": 0xFF07}
IP_MODE_ERROR = 0xFF0C  # EPOS2

_CLASSES: dict[int, str] = {
    0x1: "generic error",
    0x2: "current error",
    0x3: "voltage error",
    0x4: "temperature error",
    0x5: "device hardware error",
    0x6: "device software error",
    0x7: "additional module error",
    0x8: "monitoring / communication error",
    0x9: "external error",
    0xF: "additional function / device-specific error",
}

#: Error register 0x1001 bit per CiA 301 error class (bit 0 generic is always set with an error).
_REGISTER_BITS = {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10, 0xF: 0x80}


def emcy_text(code: int, family: Family = "epos4") -> str:
    """Text of an EMCY error code for a drive ``family`` (table, else its CiA 301 class)."""
    text = _BY_FAMILY[family].get(code)
    if text is not None:
        return text
    return f"unknown error ({_CLASSES.get(code >> 12, 'unclassified')})"


def error_register_for(code: int) -> int:
    """The 0x1001 error register a drive reports with error ``code`` (0 for "no error")."""
    if code == 0:
        return 0
    return 0x01 | _REGISTER_BITS.get(code >> 12, 0)


@dataclass(frozen=True)
class Emcy:
    """One decoded EMCY frame."""

    node: int
    code: int
    register: int
    data: bytes
    text: str

    def __str__(self) -> str:
        return f"node {self.node}: EMCY 0x{self.code:04X} {self.text}"


def decode_emcy(node: int, data: bytes, family: Family = "epos4") -> Emcy | None:
    """Decode an EMCY payload (8 bytes expected, 3 at least); None for a malformed one."""
    if len(data) < 3:
        return None
    code, register = struct.unpack_from("<HB", data)
    return Emcy(node, code, register, bytes(data[3:8]), emcy_text(code, family))


def encode_emcy(code: int, register: int | None = None, data: bytes = b"") -> bytes:
    """An 8-byte EMCY payload (the simulated drives send these)."""
    reg = error_register_for(code) if register is None else register
    return struct.pack("<HB5s", code, reg, bytes(data[:5]))
