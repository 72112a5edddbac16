"""The simulated Modbus transmitter's register-read replies, built with one ``struct`` and
pymodbus's CRC (the lock-step rig's hot path), byte for byte against the frame pymodbus builds
from the response PDU, and against a CRC-16/MODBUS written from its definition
(``modbus_ref.py``, checked against the catalogue in ``test_loadcell_modbus.py``), so pymodbus
is not trusted to check pymodbus."""

from __future__ import annotations

import pytest
from modbus_ref import ref_crc16_modbus
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersResponse,
    ReadInputRegistersResponse,
)

from cdcr_ctl.config.loadcells import ModbusRegisterMap
from cdcr_ctl.sensors.loadcell_modbus import ReadPlan, build_read_request
from cdcr_ctl.sim.loadcells import ModbusLoadCellSim


@pytest.mark.parametrize("value_type", ["int32", "int16"])
@pytest.mark.parametrize("fc", [3, 4])
@pytest.mark.parametrize("force_N", [0.0, 12.345, -3.2, 1e6, -1e6])
def test_read_reply_is_the_frame_pymodbus_builds(value_type, fc, force_N):
    rm = ModbusRegisterMap(value_type=value_type, tare_register=0x10)
    forces = [force_N, 2.5]
    sim = ModbusLoadCellSim(lambda: forces, (7, 9), rm, emulate_baud=False)
    try:
        for slave in (7, 9):
            for address, count in ((0, 3), (0, 1), (1, 4), (5, 2)):
                plan = ReadPlan(fc, address, count, 0, 1, 0)
                request = build_read_request(slave, plan)
                got = sim.handle_bytes(request, 0.0)
                assert len(got) == 1
                frame, used = got[0]
                assert used == len(request)
                regs = sim._read_registers(slave, address, count)
                cls = ReadHoldingRegistersResponse if fc == 3 else ReadInputRegistersResponse
                expected = sim._framer.buildFrame(cls(registers=regs, dev_id=slave))
                assert frame == expected
                body = bytes([slave, fc, 2 * count]) + b"".join(r.to_bytes(2, "big") for r in regs)
                assert frame == body + ref_crc16_modbus(body)
        assert sim.stats.requests == 8
    finally:
        sim.stop()
