"""A CRC-16/MODBUS written here from its definition (poly 0xA001 reflected, init 0xFFFF, low byte
first), so the tests do not trust pymodbus to check pymodbus."""

from __future__ import annotations


def ref_crc16_modbus(data: bytes) -> bytes:
    """CRC-16/MODBUS of ``data``, as the two bytes a frame appends (low byte first)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes((crc & 0xFF, crc >> 8))
