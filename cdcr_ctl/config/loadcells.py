"""Load-cell section of the rig config (JLBS-type cells behind a serial transmitter)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from cdcr_ctl.config.base import Section, Timeout
from cdcr_ctl.config.robot import Name, PositiveFloat


class SerialPortConfig(Section):
    """A serial port: device path or pyserial URL (``/dev/ttyUSB0``, ``/dev/pts/5``, ``loop://``).

    ``timeout_s``: how long the Modbus master waits for a reply to one request (s).
    """

    #: Device path or pyserial URL of the port.
    port: Annotated[str, Field(min_length=1)]
    #: Bit rate of the line (bit/s).
    baudrate: Annotated[int, Field(gt=0, le=4_000_000)] = 115200
    #: Parity: ``N`` none, ``E`` even, ``O`` odd.
    parity: Literal["N", "E", "O"] = "N"
    #: Stop bits per character.
    stopbits: Literal[1, 2] = 1
    timeout_s: Timeout = 0.05


class ModbusRegisterMap(Section):
    """Where a Modbus transmitter keeps its reading (0-based register addresses).

    ``register_kind``: holding registers (function 3) or input registers (function 4).
    ``value_type``: int16, or int32 with the high word in the lower register.
    ``decimals_register``: register holding the number of decimals of the value (read with the
    value when within 8 registers of it, else once per cell); None: ``decimals`` is fixed.
    ``unit``: what the value counts (kg and lb mean kilogram-/pound-force; g = 9.80665 m/s^2).
    ``tare_register``/``tare_value``: writing the value there (function 6) tares the transmitter;
    None: the transmitter cannot be tared over the bus (zero in software instead).
    """

    register_kind: Literal["holding", "input"] = "holding"
    #: Register of the reading (0-based; int32 takes it and the next one).
    value_register: Annotated[int, Field(ge=0, le=65535)] = 0
    value_type: Literal["int16", "int32"] = "int32"
    decimals_register: Annotated[int, Field(ge=0, le=65535)] | None = 2
    decimals: Annotated[int, Field(ge=0, le=6)] = 3
    unit: Literal["kg", "g", "N", "lb"] = "kg"
    tare_register: Annotated[int, Field(ge=0, le=65535)] | None = None
    tare_value: Annotated[int, Field(ge=0, le=65535)] = 1


class LoadCellConfig(Section):
    """One cell: which cable it measures, its Modbus slave address, and its calibration.

    force_N = span * (reading_in_N - zero_N). ``location`` says where on the cable path it sits.
    """

    #: Name of the cable this cell measures.
    cable: Name
    #: Modbus slave address of the cell's transmitter (1-247).
    slave: Annotated[int, Field(ge=1, le=247)] = 1
    #: Reading at zero tension (N), subtracted before ``span``.
    zero_N: float = 0.0
    #: Scale from the zeroed reading to the cable force.
    span: PositiveFloat = 1.0
    location: Literal["robot_base", "actuator"] = "robot_base"


class LoadCellsConfig(Section):
    """All load cells on one serial bus: Modbus RTU (several slaves) or ASCII stream (one cell).

    ``stale_after_s``: a sample older than this is flagged stale (s).
    ``inter_frame_s``: Modbus bus silence before each request (s); None: the spec's t3.5
    (3.5 characters, fixed 1.75 ms above 19200 bit/s). Raise it for slow transmitters.
    """

    #: How the transmitter talks: ``modbus_rtu`` (polled, several slaves on one RS-485 bus) or
    #: ``ascii`` (one cell streaming lines).
    protocol: Literal["modbus_rtu", "ascii"] = "modbus_rtu"
    serial: SerialPortConfig
    register_map: ModbusRegisterMap = Field(default_factory=ModbusRegisterMap)
    cells: Annotated[list[LoadCellConfig], Field(min_length=1)]
    stale_after_s: Timeout = 0.1
    inter_frame_s: Annotated[float, Field(ge=0, le=1.0)] | None = None
