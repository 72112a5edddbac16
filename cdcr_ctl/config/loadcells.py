"""Load-cell section of the rig config (JLBS-type cells behind a serial transmitter)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.robot import Name, PositiveFloat


class SerialPortConfig(Section):
    """A serial port: device path or pyserial URL (``/dev/ttyUSB0``, ``/dev/pts/5``, ``loop://``)."""

    port: Annotated[str, Field(min_length=1)]
    baudrate: Annotated[int, Field(gt=0, le=4_000_000)] = 115200
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    timeout_s: PositiveFloat = 0.05


class ModbusRegisterMap(Section):
    """Where a Modbus transmitter keeps its reading (holding registers, 0-based addresses)."""

    value_register: Annotated[int, Field(ge=0, le=65535)] = 0
    value_type: Literal["int16", "int32"] = "int32"
    decimals_register: Annotated[int, Field(ge=0, le=65535)] | None = 2
    decimals: Annotated[int, Field(ge=0, le=6)] = 3
    unit: Literal["kg", "N", "g"] = "kg"
    tare_register: Annotated[int, Field(ge=0, le=65535)] | None = None


class LoadCellConfig(Section):
    """One cell: which cable it measures, its Modbus slave address, and its calibration.

    force_N = span * (reading_in_N - zero_N). ``location`` says where on the cable path it sits.
    """

    cable: Name
    slave: Annotated[int, Field(ge=1, le=247)] = 1
    zero_N: float = 0.0
    span: PositiveFloat = 1.0
    location: Literal["robot_base", "actuator"] = "robot_base"


class LoadCellsConfig(Section):
    """All load cells on one serial bus: Modbus RTU (several slaves) or ASCII stream (one cell)."""

    protocol: Literal["modbus_rtu", "ascii"] = "modbus_rtu"
    serial: SerialPortConfig
    register_map: ModbusRegisterMap = Field(default_factory=ModbusRegisterMap)
    cells: Annotated[list[LoadCellConfig], Field(min_length=1)]
    stale_after_s: PositiveFloat = 0.1
