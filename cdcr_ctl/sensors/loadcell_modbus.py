"""Modbus RTU load-cell transmitters: several cells on one RS485 bus, one slave address each.

Framing, CRC and PDU encoding/decoding are pymodbus's (``FramerRTU``, ``DecodePDU``, the register
PDUs); this module only decides what to ask, reads the reply off an injected pyserial port and
rejects anything that is not the exact reply to the request just sent. The one frame every poll
gets, a register-read reply, is checked with pymodbus's CRC (computed two bytes a step) and
unpacked with one ``struct`` into the PDU pymodbus's decoder would build (the same answer,
without its per-frame class look-ups; :mod:`~cdcr_ctl.sensors.loadcell_reply`).

Reply hunting: a reply is accepted only if it starts with the polled slave address, carries the
request's function code (or its exception code), has the expected length and a valid CRC
(checked by pymodbus). Bytes before it (line noise, a late reply, the local echo of an RS485
adapter) are counted in :class:`~cdcr_ctl.sensors.loadcell.LinkStats` ``discarded_bytes`` and
skipped; a reply with a bad CRC or wrong length is counted in ``bad_frames`` and never returned.
A transport error (port closed, USB adapter unplugged, pty hung up) raises
:class:`~cdcr_ctl.errors.SensorError` naming the port, with the last frames in the message.

Timing (Modbus over Serial Line V1.02, section 2.5.1.1): a frame is delimited by a silence of
3.5 character times (t3.5); above 19200 bit/s the spec fixes t3.5 at 1.75 ms. The master waits
``inter_frame_s`` after the end of each reply before sending the next request.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import serial
from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadInputRegistersRequest,
    WriteSingleRegisterRequest,
)

from cdcr_ctl.config.loadcells import ModbusRegisterMap
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.loadcell import LinkStats, LoadCellReading, TrafficLog, to_newtons
from cdcr_ctl.sensors.loadcell_reply import READ_REPLY_CLASS, decode_read_reply, exact_read_reply

#: How long to wait for a reply after the request is written (s); overridable per bus.
RESPONSE_TIMEOUT_S = 0.05

#: Longest single blocking read while a reply is awaited (s): the port's read timeout.
READ_POLL_S = 0.005

#: t3.5 above 19200 bit/s, fixed by Modbus over Serial Line V1.02 section 2.5.1.1 (s).
SPEC_T35_FIXED_S = 1.75e-3

#: Read-request ADU: address + function + start (2) + count (2) + CRC (2) bytes.
READ_REQUEST_BYTES = 8

#: Read-reply ADU overhead: address + function + byte count + CRC (2); plus 2 bytes per register.
READ_REPLY_OVERHEAD_BYTES = 5

#: Exception-reply ADU: address + function|0x80 + exception code + CRC (2).
EXCEPTION_REPLY_BYTES = 5

#: Write-single-register request and its echo reply: address + function + reg (2) + value (2) + CRC.
WRITE_SINGLE_BYTES = 8

#: Most registers one block read may span to fetch value and decimals together.
MAX_BLOCK_REGISTERS = 8

#: Largest decimals count a reading may carry; a register saying more is a corrupt reply.
MAX_DECIMALS = 6

#: Modbus exception codes (Modbus Application Protocol V1.1b3 section 7) as text.
EXCEPTION_TEXT = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge (busy with a long command)",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}

R = TypeVar("R")

#: What a failing port raises (a transport error: :class:`SensorError`).
_PORT_ERRORS = (serial.SerialException, OSError)

_INT_LIMITS = {"int16": (-(2**15), 2**15 - 1), "int32": (-(2**31), 2**31 - 1)}
_BITS = {"int16": 16, "int32": 32}


def char_time_s(baudrate: int, parity: str = "N", stopbits: int = 1) -> float:
    """Time on the wire of one character (s): start bit, 8 data bits, parity bit, stop bits."""
    bits = 1 + 8 + (0 if parity == "N" else 1) + stopbits
    return bits / baudrate


def spec_silence_s(baudrate: int, parity: str = "N", stopbits: int = 1) -> float:
    """t3.5 as the Modbus serial-line spec sets it (s): 3.5 chars, or 1.75 ms above 19200 bit/s."""
    if baudrate > 19200:
        return SPEC_T35_FIXED_S
    return 3.5 * char_time_s(baudrate, parity, stopbits)


@dataclass(frozen=True, slots=True)
class ReadPlan:
    """The one register read that fetches a cell's value (and its decimals when near enough).

    ``start``/``count``: registers read (0-based); ``value_offset``/``value_words``: where the
    value sits in the block (1 word int16, 2 words int32 high word first); ``decimals_offset``:
    where the decimals register sits in the block, or None when it is read apart (or fixed).
    """

    function_code: int
    start: int
    count: int
    value_offset: int
    value_words: int
    decimals_offset: int | None

    @property
    def reply_bytes(self) -> int:
        """Length of the normal reply ADU (bytes)."""
        return READ_REPLY_OVERHEAD_BYTES + 2 * self.count


def plan_read(register_map: ModbusRegisterMap, max_block: int = MAX_BLOCK_REGISTERS) -> ReadPlan:
    """Choose the block read for ``register_map``: value and decimals in one read when the block
    spans at most ``max_block`` registers (the decimals then always match the value they scale),
    else the value alone."""
    fc = 3 if register_map.register_kind == "holding" else 4
    words = 2 if register_map.value_type == "int32" else 1
    lo, hi = register_map.value_register, register_map.value_register + words - 1
    dec = register_map.decimals_register
    if dec is not None and max(hi, dec) - min(lo, dec) + 1 <= max_block:
        start = min(lo, dec)
        return ReadPlan(fc, start, max(hi, dec) - start + 1, lo - start, words, dec - start)
    return ReadPlan(fc, lo, words, 0, words, None)


def transaction_chars(plan: ReadPlan) -> float:
    """Characters on the wire per polled cell: request + reply + t3.5 silence after each."""
    return READ_REQUEST_BYTES + plan.reply_bytes + 2 * 3.5


def _framer() -> FramerRTU:
    return FramerRTU(DecodePDU(is_server=False))


def build_read_request(slave: int, plan: ReadPlan) -> bytes:
    """The RTU ADU asking ``slave`` for ``plan``'s block (pymodbus encodes it, CRC included)."""
    cls = ReadHoldingRegistersRequest if plan.function_code == 3 else ReadInputRegistersRequest
    return _framer().buildFrame(cls(address=plan.start, count=plan.count, dev_id=slave))


def build_write_request(slave: int, register: int, value: int) -> bytes:
    """The RTU ADU writing ``value`` (0..65535) to holding ``register`` of ``slave`` (code 6)."""
    pdu = WriteSingleRegisterRequest(address=register, registers=[value], dev_id=slave)
    return _framer().buildFrame(pdu)


@dataclass(frozen=True, slots=True)
class Scan:
    """Result of looking for one reply in received bytes.

    ``pdu``: the decoded reply (a pymodbus PDU, possibly an ``ExceptionResponse``) or None;
    ``start``/``end``: its slice of the buffer; ``need``: bytes to read next when no reply is
    complete yet; ``rejected``: complete candidates that failed the CRC or the content checks.
    """

    pdu: ModbusPDU | None
    start: int
    end: int
    need: int
    rejected: int


def scan_reply(
    buf: bytes, slave: int, function_code: int, reply_bytes: int, framer: FramerRTU | None = None
) -> Scan:
    """Find the reply of ``slave`` to a request with ``function_code`` in ``buf``.

    Pure: ``buf`` may hold noise before the reply, a partial reply, or a reply with a bad CRC.
    A candidate is any position holding ``slave`` followed by ``function_code`` (reply
    ``reply_bytes`` long) or ``function_code | 0x80`` (exception reply, 5 bytes); for register
    reads its byte-count byte must match too. pymodbus's RTU framer checks the CRC and its
    decoder builds the PDU; the first complete candidate that passes wins.
    """
    framer = framer or _framer()
    need = reply_bytes
    rejected = 0
    incomplete_seen = False
    n = len(buf)
    for i in range(n):
        if buf[i] != slave:
            continue
        if i + 1 < n and buf[i + 1] not in (function_code, function_code | 0x80):
            continue
        size = reply_bytes
        if i + 1 < n and buf[i + 1] == function_code | 0x80:
            size = EXCEPTION_REPLY_BYTES
        elif function_code in (3, 4) and i + 2 < n and buf[i + 2] != reply_bytes - 5:
            continue
        if n - i < size:
            if not incomplete_seen:
                need = size - (n - i)
                incomplete_seen = True
            continue
        frame = bytes(buf[i : i + size])
        if size == reply_bytes and buf[i + 1] in READ_REPLY_CLASS and (size - 5) % 2 == 0:
            pdu = decode_read_reply(frame, slave)
        else:
            pdu = _decode_exact(framer, frame, slave)
        if pdu is None:
            rejected += 1
            continue
        return Scan(pdu, i, i + size, 0, rejected)
    return Scan(None, 0, 0, max(1, need), rejected)


def _decode_exact(framer: FramerRTU, frame: bytes, slave: int) -> ModbusPDU | None:
    """Decode one complete ADU with pymodbus; None on bad CRC, other device or undecodable PDU."""
    used, dev_id, _tid, pdu_bytes = framer.decode(frame)
    if not used or not pdu_bytes or dev_id != slave:
        return None
    pdu = framer.decoder.decode(pdu_bytes)
    if pdu is not None:
        pdu.dev_id = dev_id
    return pdu


def registers_to_int(registers: Sequence[int], value_type: str) -> int:
    """Signed integer from 1 (int16) or 2 (int32, high word first) registers: the words as one
    big-endian two's-complement number (what pymodbus's ``convert_from_registers`` gives with
    ``word_order="big"``; tests/sensors/test_modbus_read_reply.py compares them)."""
    bits = _BITS[value_type]
    if len(registers) != bits // 16:
        raise ValueError(f"{value_type} needs {bits // 16} registers, got {len(registers)}")
    value = 0
    for word in registers:
        value = (value << 16) | (int(word) & 0xFFFF)
    return value - (1 << bits) if value >> (bits - 1) else value


def decode_reading(raw: int, decimals: int, register_map: ModbusRegisterMap) -> LoadCellReading:
    """Reading for integer ``raw`` with ``decimals`` decimal places in ``register_map.unit``.

    value = raw / 10**decimals; a raw value at the limit of its type is the transmitter
    saturating: it is flagged overload with ``reading_N`` = ±inf.
    """
    unit = register_map.unit
    value = raw / 10**decimals
    lo, hi = _INT_LIMITS[register_map.value_type]
    if raw in (lo, hi):
        return LoadCellReading(value, unit, math.copysign(math.inf, raw), overload=True)
    return LoadCellReading(value, unit, to_newtons(value, unit))


class ModbusLoadCellBus:
    """Load-cell transmitters on one Modbus RTU bus, polled one request at a time.

    ``port``: an open pyserial port (its read timeout is set to :data:`READ_POLL_S`; the bus
    closes it in :meth:`close`). ``slaves``: slave address (1..247) of cell 0, 1, ...
    ``response_timeout_s``: wait for a reply (s). ``inter_frame_s``: bus silence before each
    request (s), default the spec's t3.5 for the port's baud rate. ``port_name`` names the port
    in errors (default ``port.port``).
    """

    def __init__(
        self,
        port: serial.SerialBase,
        slaves: Sequence[int],
        register_map: ModbusRegisterMap,
        *,
        response_timeout_s: float = RESPONSE_TIMEOUT_S,
        inter_frame_s: float | None = None,
        port_name: str | None = None,
    ) -> None:
        if not slaves:
            raise ValueError("a Modbus load-cell bus needs at least one slave address")
        if len(set(slaves)) != len(slaves) or not all(1 <= s <= 247 for s in slaves):
            raise ValueError(f"slave addresses must be unique and in 1..247, got {list(slaves)}")
        self.port = port
        self.port_name = port_name or str(getattr(port, "port", None) or port)
        self.slaves = tuple(int(s) for s in slaves)
        self.register_map = register_map
        self.plan = plan_read(register_map)
        self.response_timeout_s = float(response_timeout_s)
        baud = int(getattr(port, "baudrate", 115200))
        parity = str(getattr(port, "parity", "N"))
        stopbits = int(getattr(port, "stopbits", 1))
        self.inter_frame_s = (
            spec_silence_s(baud, parity, stopbits) if inter_frame_s is None else inter_frame_s
        )
        self.stats = LinkStats()
        self.traffic = TrafficLog()
        self.last_problem: list[str] = ["" for _ in self.slaves]
        self._framer = _framer()
        self._requests = [build_read_request(s, self.plan) for s in self.slaves]
        self._decimals: list[int | None] = [None for _ in self.slaves]
        self._quiet_since = 0.0
        self._next = 0
        try:
            port.timeout = min(READ_POLL_S, self.response_timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SensorError(self.port_name, f"cannot configure port: {exc}") from exc

    @property
    def n_cells(self) -> int:
        return len(self.slaves)

    def address(self, index: int) -> int:
        """Slave address of cell ``index``."""
        return self.slaves[index]

    def poll(self) -> list[tuple[int, LoadCellReading]]:
        """Poll the next cell in turn: ``[(index, reading)]``, or ``[]`` when its reply was bad.

        Raises :class:`SensorError` when the port fails (disconnect).
        """
        index = self._next
        self._next = (index + 1) % len(self.slaves)
        reading = self.read(index)
        return [] if reading is None else [(index, reading)]

    def read(self, index: int) -> LoadCellReading | None:
        """Poll cell ``index`` once: its reading, or None when the reply was missing or bad.

        Raises :class:`SensorError` when the port fails (disconnect).
        """
        slave = self.slaves[index]
        plan = self.plan
        known = self._decimals[index]
        off = plan.decimals_offset
        if off is None and known is None:
            known = self._read_decimals(index)
            if known is None:
                return None
        pdu = self._transact(index, self._requests[index], plan.function_code, plan.reply_bytes)
        if pdu is None:
            return None
        regs = list(pdu.registers)
        if len(regs) != plan.count:
            return self._reject(index, f"slave {slave}: {len(regs)} registers, asked {plan.count}")
        decimals = regs[off] if off is not None else known if known is not None else -1
        if not 0 <= decimals <= MAX_DECIMALS:
            return self._reject(index, f"slave {slave}: decimals register says {decimals}")
        words = regs[plan.value_offset : plan.value_offset + plan.value_words]
        raw = registers_to_int(words, self.register_map.value_type)
        self.stats.frames_ok += 1
        return decode_reading(raw, decimals, self.register_map)

    def tare(self, index: int) -> None:
        """Tell cell ``index``'s transmitter to tare (write ``tare_value`` to ``tare_register``).

        Raises :class:`SensorError` when the map has no tare register or the write is not
        acknowledged with its exact echo.
        """
        slave = self.slaves[index]
        reg, value = self.register_map.tare_register, self.register_map.tare_value
        if reg is None:
            raise SensorError(self.port_name, f"slave {slave}: register map has no tare_register")
        pdu = self._transact(index, build_write_request(slave, reg, value), 6, WRITE_SINGLE_BYTES)
        if pdu is not None and (pdu.address != reg or list(pdu.registers) != [value]):
            self._reject(index, f"slave {slave}: echo {pdu.address}={list(pdu.registers)}")
            pdu = None
        if pdu is None:
            why = self.last_problem[index]
            raise SensorError(self.port_name, f"slave {slave}: tare not acknowledged: {why}")
        self.stats.frames_ok += 1

    def close(self) -> None:
        """Close the port (idempotent)."""
        with contextlib.suppress(serial.SerialException, OSError):
            self.port.close()

    # -- one transaction ----------------------------------------------------------------

    def _read_decimals(self, index: int) -> int | None:
        reg = self.register_map.decimals_register
        if reg is None:
            self._decimals[index] = self.register_map.decimals
            return self.register_map.decimals
        plan = ReadPlan(self.plan.function_code, reg, 1, 0, 1, 0)
        pdu = self._transact(
            index,
            build_read_request(self.slaves[index], plan),
            plan.function_code,
            plan.reply_bytes,
        )
        if pdu is None:
            return None
        decimals = int(pdu.registers[0]) if len(pdu.registers) == 1 else -1
        if not 0 <= decimals <= MAX_DECIMALS:
            return self._reject(
                index, f"slave {self.slaves[index]}: decimals register says {decimals}"
            )
        self._decimals[index] = decimals
        return decimals

    def _reject(self, index: int, why: str) -> None:
        self.stats.bad_frames += 1
        self.last_problem[index] = why
        return None

    def _transact(
        self, index: int, request: bytes, function_code: int, reply_bytes: int
    ) -> ModbusPDU | None:
        """Send ``request`` and return the matching reply PDU, or None (counted) when none came."""
        slave = self.slaves[index]
        port = self.port
        self._discard_input()
        wait = self._quiet_since + self.inter_frame_s - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        try:  # (self._io written out: this runs for every poll)
            port.write(request)
        except _PORT_ERRORS as exc:
            raise self._failed("write", exc) from exc
        self.traffic.add("tx", request)
        deadline = time.monotonic() + self.response_timeout_s
        buf = bytearray()
        pdu: ModbusPDU | None = None
        start, need = 0, max(1, reply_bytes)  # what scan_reply says of no bytes
        while pdu is None and time.monotonic() < deadline:
            try:
                chunk = port.read(need)
            except _PORT_ERRORS as exc:
                raise self._failed("read", exc) from exc
            if chunk:
                buf += chunk
                pdu = exact_read_reply(buf, slave, function_code, reply_bytes)
                if pdu is None:
                    scan = scan_reply(buf, slave, function_code, reply_bytes, self._framer)
                    pdu, start, need = scan.pdu, scan.start, scan.need
        self._quiet_since = time.monotonic()
        if buf:
            self.traffic.add("rx", bytes(buf))
        if pdu is None:
            if not buf:
                self.stats.timeouts += 1
                self.last_problem[index] = f"slave {slave}: no reply in {self.response_timeout_s} s"
            else:
                self.stats.bad_frames += 1
                self.stats.discarded_bytes += len(buf)
                self.last_problem[index] = f"slave {slave}: no valid reply in {bytes(buf).hex(' ')}"
            return None
        self.stats.discarded_bytes += start
        if isinstance(pdu, ExceptionResponse):
            code = pdu.exception_code
            self.stats.exceptions += 1
            self.last_problem[index] = (
                f"slave {slave}: exception {code} ({EXCEPTION_TEXT.get(code, 'unknown')})"
            )
            return None
        return pdu

    def _discard_input(self) -> None:
        """Drop whatever arrived since the last reply (late replies, noise), counting it."""
        try:
            waiting = self.port.in_waiting
        except _PORT_ERRORS as exc:
            raise self._failed("check", exc) from exc
        if waiting:
            junk = self._io("read", self.port.read, waiting)
            self.stats.discarded_bytes += len(junk)
            self.traffic.add("rx", junk)

    def _io(self, doing: str, call: Callable[..., R], *args: object) -> R:
        try:
            return call(*args)
        except _PORT_ERRORS as exc:
            raise self._failed(doing, exc) from exc

    def _failed(self, doing: str, exc: BaseException) -> SensorError:
        """The error of a port that failed during ``doing``, with the last frames."""
        return SensorError(
            self.port_name,
            f"serial port failed during {doing} (disconnected?): {exc}\n"
            f"last frames:\n{self.traffic.dump()}",
        )
