"""A Modbus RTU register-read reply, checked and decoded (pure bytes): its CRC-16/MODBUS, two
bytes a step (the value of pymodbus's ``FramerRTU.compute_CRC``), and the PDU pymodbus's decoder
builds of it.

The CRC register is 16 bits wide and reflected, so two message bytes ``b0, b1`` move it from
``crc`` to a value that depends on ``crc ^ (b0 | b1 << 8)`` alone: one look-up in a 65536-entry
table (built once from the byte table, 128 KiB) replaces two byte steps. The result is the CRC
with its bytes swapped, as pymodbus returns it: ``crc16(body).to_bytes(2, "big")`` is what goes
on the wire after ``body`` (``tests/sensors/test_loadcell_crc.py`` compares it with pymodbus
over every length and many frames).
"""

from __future__ import annotations

import struct
from array import array

from pymodbus.pdu import ModbusPDU
from pymodbus.pdu.register_message import ReadHoldingRegistersResponse, ReadInputRegistersResponse

#: The reflected CRC-16 polynomial of Modbus (0x8005 bit-reversed).
POLY = 0xA001

#: Longest RTU frame (bytes, Modbus over Serial Line V1.02 section 2.5.1.1).
MAX_FRAME_BYTES = 256


def _byte_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ POLY if crc & 1 else crc >> 1
        table.append(crc)
    return table


_T8 = _byte_table()
#: One step over two bytes: the register after them, by ``crc ^ (b0 | b1 << 8)``.
_T16 = array("H", [(t >> 8) ^ _T8[(hi ^ t) & 0xFF] for hi in range(256) for t in _T8])
#: Little-endian 16-bit words, by count.
_WORDS = [struct.Struct(f"<{k}H") for k in range(MAX_FRAME_BYTES // 2 + 1)]


def crc16(data: bytes | bytearray) -> int:
    """CRC-16/MODBUS of ``data`` (initial 0xFFFF), bytes swapped: high byte = the CRC's low
    byte, the first sent (pymodbus's ``compute_CRC``)."""
    n = len(data)
    words = n >> 1
    crc = 0xFFFF
    t16 = _T16
    if words < len(_WORDS):
        for w in _WORDS[words].unpack_from(data):
            crc = t16[crc ^ w]
    else:
        for w in struct.unpack_from(f"<{words}H", data):
            crc = t16[crc ^ w]
    if n & 1:
        crc = (crc >> 8) ^ _T8[(crc ^ data[n - 1]) & 0xFF]
    return ((crc << 8) & 0xFF00) | (crc >> 8)


#: Register-read reply PDUs by function code (what pymodbus's client decoder builds).
READ_REPLY_CLASS: dict[int, type[ModbusPDU]] = {
    3: ReadHoldingRegistersResponse,
    4: ReadInputRegistersResponse,
}


#: Big-endian register words by count (a read reply carries at most 125).
_REGISTERS = [struct.Struct(f">{k}H") for k in range(126)]


def exact_read_reply(
    buf: bytearray, slave: int, function_code: int, reply_bytes: int
) -> ModbusPDU | None:
    """The reply when ``buf`` is exactly the register-read reply ``loadcell_modbus.scan_reply``
    tries first (its candidate at byte 0: address, function code, byte count and length all
    match), decoded as it decodes that candidate; None otherwise, and ``scan_reply`` decides
    (the same answer: what it returns when its first candidate passes)."""
    if (
        len(buf) == reply_bytes
        and buf[0] == slave
        and buf[1] == function_code
        and function_code in READ_REPLY_CLASS
        and buf[2] == reply_bytes - 5
        and reply_bytes % 2 == 1
    ):
        return decode_read_reply(bytes(buf), slave)
    return None


def decode_read_reply(frame: bytes, slave: int) -> ModbusPDU | None:
    """``loadcell_modbus._decode_exact`` (pymodbus's framer and decoder) for a normal
    register-read reply (function code 3 or 4) whose address, function code, byte count and even
    length ``scan_reply`` has checked: the CRC (:func:`crc16`; its last two bytes read high byte
    first, as pymodbus's ``FramerRTU.decode`` reads them), the registers as big-endian words, the
    PDU of the class pymodbus's decoder builds. The same answer (None on a bad CRC), without
    their per-frame class look-ups; the real rig's reader runs it on every poll
    (``tests/sensors/test_modbus_read_reply.py`` compares the two on every kind of frame)."""
    end = len(frame) - 2
    if crc16(frame[:end]) != (frame[end] << 8) | frame[end + 1]:
        return None
    registers = list(_REGISTERS[(end - 3) // 2].unpack_from(frame, 3))
    return READ_REPLY_CLASS[frame[1]](dev_id=slave, registers=registers)
