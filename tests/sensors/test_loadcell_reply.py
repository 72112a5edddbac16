"""CRC-16/MODBUS two bytes a step (``loadcell_reply.crc16``) against pymodbus's byte-wise
``FramerRTU.compute_CRC``: every length of an RTU frame and past it, random and edge bytes."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st
from pymodbus.framer import FramerRTU

from cdcr_ctl.sensors.loadcell_reply import crc16


def test_crc16_is_pymodbus_at_every_length() -> None:
    rng = random.Random(22)
    for n in range(0, 300):
        for _ in range(8):
            data = bytes(rng.randrange(256) for _ in range(n))
            assert crc16(data) == FramerRTU.compute_CRC(data), n
            assert crc16(bytearray(data)) == FramerRTU.compute_CRC(data), n
        for fill in (0x00, 0xFF, 0x55):
            data = bytes([fill]) * n
            assert crc16(data) == FramerRTU.compute_CRC(data), (n, fill)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=260))
def test_crc16_is_pymodbus(data: bytes) -> None:
    assert crc16(data) == FramerRTU.compute_CRC(data)


def test_crc16_of_a_known_frame() -> None:
    # read holding registers 0..2 of slave 1 (Modbus over Serial Line's example CRC layout)
    assert crc16(bytes.fromhex("010300000003")).to_bytes(2, "big") == bytes.fromhex("05cb")
