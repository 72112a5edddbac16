"""EMCY (CiA 301 emergency) codes of maxon EPOS4/EPOS2 drives as text: one table.

The error code is the first two bytes of an EMCY frame (little endian), the error register the
third; EPOS drives add a device-specific code in bytes 3-4. Codes from the EPOS4 firmware
specification's error-code list; unknown codes fall back to their CiA 301 class.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

EPOS_ERRORS: dict[int, str] = {
    0x0000: "no error",
    0x1000: "generic error",
    0x1080: "generic initialization error",
    0x1090: "firmware incompatibility error",
    0x2310: "over-current error",
    0x2320: "power stage protection error",
    0x3210: "over-voltage error",
    0x3220: "under-voltage error",
    0x4210: "thermal overload error",
    0x5113: "logic supply voltage too low",
    0x5280: "supply voltage output stage too low",
    0x6100: "internal software error",
    0x6320: "software parameter error",
    0x7320: "position sensor error",
    0x7380: "position sensor breach error",
    0x8110: "CAN overrun error (objects lost)",
    0x8111: "CAN overrun error",
    0x8120: "CAN passive mode error",
    0x8130: "CAN heartbeat error (life guard)",
    0x8150: "CAN PDO COB-ID collision",
    0x81FD: "CAN bus off",
    0x81FE: "CAN Rx queue overflow",
    0x81FF: "CAN Tx queue overflow",
    0x8210: "CAN PDO length error",
    0x8250: "RPDO timeout",
    0x8611: "following error",
    0x8A80: "negative limit switch error",
    0x8A81: "positive limit switch error",
    0x8A82: "software position limit error",
    0x8A88: "interpolated position mode error",
    0x8A89: "auto tuning current limit error",
    0xFF01: "hall sensor error",
    0xFF02: "index processing error",
    0xFF0B: "system overloaded",
}

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
    0xF: "additional function error",
}


def emcy_text(code: int) -> str:
    """Text of an EMCY error code (EPOS table, else its CiA 301 class)."""
    if code in EPOS_ERRORS:
        return EPOS_ERRORS[code]
    return f"unknown error ({_CLASSES.get(code >> 12, 'unclassified')})"


@dataclass(frozen=True)
class Emcy:
    """One decoded EMCY frame."""

    node: int
    code: int
    register: int
    data: bytes
    text: str


def decode_emcy(node: int, data: bytes) -> Emcy | None:
    """Decode an EMCY payload (8 bytes expected); None for a malformed one."""
    if len(data) < 3:
        return None
    code, register = struct.unpack_from("<HB", data)
    return Emcy(node, code, register, bytes(data[3:8]), emcy_text(code))
