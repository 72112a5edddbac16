"""Simulated Modbus RTU load-cell transmitters: the slave's protocol state machine on a pty.

Framing, CRC and PDUs are pymodbus's. With ``emulate_baud`` the slave answers when a real bus
would have delivered its last reply byte (request + t3.5 + reply characters after the request
arrived, plus ``turnaround_s``). The slave's end-of-request silence is ``silence_s`` (default the
spec's t3.5: 3.5 characters, fixed 1.75 ms above 19200 bit/s).
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersResponse,
    ReadInputRegistersResponse,
    WriteMultipleRegistersResponse,
    WriteSingleRegisterResponse,
)

from cdcr_ctl.config.loadcells import ModbusRegisterMap
from cdcr_ctl.sensors.loadcell import from_newtons
from cdcr_ctl.sensors.loadcell_modbus import spec_silence_s
from cdcr_ctl.sensors.loadcell_reply import crc16
from cdcr_ctl.sim.loadcells.feed import CAPACITY_N, OVERLOAD_FRACTION, SensorNoise, Tensions
from cdcr_ctl.sim.loadcells.pty import PtySim

#: Bytes arriving after this much silence start a new request; the old partial one is dropped (s).
#: (RTU's t3.5 rule, made loose because a pty and a loaded machine add their own gaps.)
FRAME_GAP_S = 0.02

#: How long the serving thread blocks in one read before checking for stop (s).
POLL_S = 0.02


#: Distinct read-request frames :class:`ModbusLoadCellSim` keeps decoded.
MAX_CACHED_READS = 64

#: Registers past the highest one the map uses that still read as 0 (beyond: illegal address).
SPARE_REGISTERS = 16


def _flip_crc(frame: bytes) -> bytes:
    return frame[:-1] + bytes([frame[-1] ^ 0x5A])


class ModbusLoadCellSim(PtySim):
    """Modbus RTU transmitters, one per slave address, answering on one pty.

    ``tensions()`` returns the truth tension (N) of each cell, in ``slaves`` order. Registers
    follow ``register_map``: the value (int16 or int32 high word first, in ``unit`` with
    ``decimals`` decimals; saturated at the type's limit beyond :data:`OVERLOAD_FRACTION` of
    ``capacity_N``), the decimals register, and the tare register (writing ``tare_value`` tares
    the cell). Any other register up to :data:`SPARE_REGISTERS` past the highest used reads 0 and
    is writable; beyond, or another function code, gets a Modbus exception. Function codes 3, 4
    (both read the same registers), 6 and 16; address 0 (broadcast) writes without replying.
    """

    def __init__(
        self,
        tensions: Tensions,
        slaves: Sequence[int] = (1, 2, 3),
        register_map: ModbusRegisterMap | None = None,
        *,
        baudrate: int = 115200,
        emulate_baud: bool = True,
        silence_s: float | None = None,
        turnaround_s: float = 0.0,
        noise: SensorNoise | None = None,
        capacity_N: float = CAPACITY_N,
        link: str | Path | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.slaves = tuple(int(s) for s in slaves)
        self.register_map = register_map or ModbusRegisterMap()
        self.turnaround_s = turnaround_s
        self.silence_s = spec_silence_s(baudrate) if silence_s is None else silence_s
        self.capacity_N = capacity_N
        rm = self.register_map
        used = [rm.value_register + (1 if rm.value_type == "int32" else 0)]
        used += [r for r in (rm.decimals_register, rm.tare_register) if r is not None]
        self.n_registers = max(used) + 1 + SPARE_REGISTERS
        bits = 32 if rm.value_type == "int32" else 16
        #: The value type's limits: a saturated reading shows one of them.
        self._limits = (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
        self.registers = {s: [0] * self.n_registers for s in self.slaves}
        for s in self.slaves:
            if rm.decimals_register is not None:
                self.registers[s][rm.decimals_register] = rm.decimals
        self.tare_counts = dict.fromkeys(self.slaves, 0)
        self._framer = FramerRTU(DecodePDU(is_server=True))
        self._buf = bytearray()
        self._last_rx_s = -math.inf
        #: Read requests (fc 3/4) decoded before, by their frame bytes (performance only: the
        #: master polls each cell with the same frame).
        self._reads: dict[bytes, tuple[int, ModbusPDU]] = {}
        #: Per read block (address, count): (value word, offset in the block) of the value's
        #: words inside it (looked up once per block shape; the same for every slave).
        self._value_slots: dict[tuple[int, int], list[tuple[int, int]]] = {}
        #: Cell index of each slave address (the first cell with it, as ``slaves.index``).
        self._cell_index: dict[int, int] = {}
        #: Reply head and registers by register count (device, function, byte count, words).
        self._reply_structs: dict[int, struct.Struct] = {}
        for i, s in enumerate(self.slaves):
            self._cell_index.setdefault(s, i)
        super().__init__(
            tensions,
            len(self.slaves),
            baudrate=baudrate,
            emulate_baud=emulate_baud,
            noise=noise or SensorNoise(),
            link=link,
            clock=clock,
        )

    # -- the transmitter's registers (pure apart from the tension feed) ----------------------

    def decimals(self, slave: int) -> int:
        rm = self.register_map
        if rm.decimals_register is None:
            return rm.decimals
        return self.registers[slave][rm.decimals_register]

    def counts(self, slave: int, force_N: float) -> int:
        """The integer the transmitter shows for ``force_N`` (N), tare applied, saturated."""
        lo, hi = self._limits
        if abs(force_N) > OVERLOAD_FRACTION * self.capacity_N:
            return hi if force_N > 0 else lo
        rm = self.register_map
        dec = (
            rm.decimals
            if rm.decimals_register is None
            else self.registers[slave][rm.decimals_register]
        )
        raw = round(from_newtons(force_N, rm.unit) * 10**dec)
        return min(max(raw - self.tare_counts[slave], lo + 1), hi - 1)

    def _value_words(self, raw: int) -> list[int]:
        if self.register_map.value_type == "int32":
            u = raw & 0xFFFFFFFF
            return [u >> 16, u & 0xFFFF]
        return [raw & 0xFFFF]

    def respond(self, request: ModbusPDU) -> ModbusPDU | None:
        """The reply PDU to a decoded request (None: stay silent, i.e. a dropout)."""
        slave = request.dev_id
        fc = request.function_code
        if fc in (3, 4):
            if request.address + request.count > self.n_registers:
                return ExceptionResponse(fc, 2, device_id=slave)
            regs = self._read_registers(slave, request.address, request.count)
            if regs is None:
                return None
            cls = ReadHoldingRegistersResponse if fc == 3 else ReadInputRegistersResponse
            return cls(registers=regs, dev_id=slave)
        if fc in (6, 16):
            start, values = request.address, list(request.registers)
            if start + len(values) > self.n_registers:
                return ExceptionResponse(fc, 2, device_id=slave)
            for k, v in enumerate(values):
                self._write_register(slave, start + k, v)
            if fc == 6:
                return WriteSingleRegisterResponse(address=start, registers=values, dev_id=slave)
            return WriteMultipleRegistersResponse(address=start, count=len(values), dev_id=slave)
        return ExceptionResponse(fc, 1, device_id=slave)

    def _read_registers(self, slave: int, address: int, count: int) -> list[int] | None:
        """Registers ``address`` .. ``address + count - 1`` of ``slave`` (in range), the value
        measured now; None when the reading drops out."""
        regs = self.registers[slave][address : address + count]  # a copy
        slots = self._value_slots.get((address, count))
        if slots is None:
            rm = self.register_map
            vwords = 2 if rm.value_type == "int32" else 1
            span = range(address, address + count)
            slots = [
                (k, r - address)
                for k, r in enumerate(range(rm.value_register, rm.value_register + vwords))
                if r in span
            ]
            self._value_slots[(address, count)] = slots
        if slots:
            force = self.feed.measure(self._cell_index[slave])
            if force is None:
                return None
            words = self._value_words(self.counts(slave, force))
            for k, offset in slots:
                regs[offset] = words[k]
        return regs

    def _read_reply(self, request: ModbusPDU, dev_id: int) -> bytes | None:
        """The reply frame to a register read (fc 3/4) within the registers, built with one
        ``struct`` and pymodbus's CRC (its value, two bytes a step: ``crc16``): the bytes pymodbus's
        ``buildFrame`` makes of the response PDU (device, function, byte count, registers
        big-endian, CRC), without the PDU object. None when the reading drops out."""
        regs = self._read_registers(dev_id, request.address, request.count)
        if regs is None:
            return None
        n = len(regs)
        st = self._reply_structs.get(n)
        if st is None:
            st = self._reply_structs[n] = struct.Struct(f">BBB{n}H")
        body = st.pack(dev_id, request.function_code, 2 * n, *regs)
        return body + crc16(body).to_bytes(2, "big")

    def _write_register(self, slave: int, register: int, value: int) -> None:
        rm = self.register_map
        if register == rm.tare_register and value == rm.tare_value:
            force = self.feed.measure(self.slaves.index(slave))
            if force is not None:
                self.tare_counts[slave] = 0
                self.tare_counts[slave] = self.counts(slave, force)
            return
        self.registers[slave][register] = value

    def handle_bytes(self, data: bytes, now_s: float) -> list[tuple[bytes, int]]:
        """Feed bytes the master sent at ``now_s`` (s); return ``(reply_frame, request_len)``
        for each request to answer. Pure apart from the register state and the tension feed."""
        if now_s - self._last_rx_s > FRAME_GAP_S and self._buf:
            self.stats.bad_requests += 1  # an unfinished request was followed by silence
            self._buf.clear()
        self._last_rx_s = now_s
        if not self._buf and type(data) is bytes:
            known = self._reads.get(data)
            if known is not None:  # what the loop below does with it, without the buffer
                out: list[tuple[bytes, int]] = []
                self._answer(known[1], known[0], len(data), out)
                return out
        self._buf += data
        out = []
        while self._buf:
            buf = bytes(self._buf)
            known = self._reads.get(buf)
            if known is not None:
                # a read request seen before, alone in the buffer: decoded the same way again
                # (pymodbus's framer and decoder are pure; a read request is not mutated below)
                dev_id, request = known
                del self._buf[:]
                self._answer(request, dev_id, len(buf), out)
                continue
            try:
                used, dev_id, _tid, pdu_bytes = self._framer.decode(buf)
            except Exception:  # pymodbus raises on some malformed headers: drop and resync
                used, dev_id, pdu_bytes = len(self._buf), 0, b""
            if not used:
                if len(self._buf) > FramerRTU.MAX_SIZE:
                    self.stats.bad_requests += 1
                    self._buf.clear()
                break
            request_len = len(self._buf)
            del self._buf[:used]
            if not pdu_bytes:
                self.stats.bad_requests += 1
                continue
            request = self._framer.decoder.decode(pdu_bytes)
            if request is None:
                self.stats.bad_requests += 1
                continue
            request.dev_id = dev_id
            if dev_id == 0:
                if request.function_code in (6, 16):
                    for s in self.slaves:
                        request.dev_id = s
                        self.respond(request)
                continue
            if dev_id not in self.registers:
                continue  # another device's request
            cacheable = used == request_len and request.function_code in (3, 4)
            if cacheable and len(self._reads) < MAX_CACHED_READS:
                self._reads[buf] = (dev_id, request)
            self._answer(request, dev_id, request_len, out)
        return out

    def _answer(
        self, request: ModbusPDU, dev_id: int, used: int, out: list[tuple[bytes, int]]
    ) -> None:
        """Answer one request of ``used`` bytes: its reply frame appended to ``out`` (none if
        :meth:`respond` drops it)."""
        self.stats.requests += 1
        fc = request.function_code
        if fc in (3, 4) and request.address + request.count <= self.n_registers:
            frame = self._read_reply(request, dev_id)
            if frame is None:
                self.stats.dropped += 1
                return
            out.append((frame, used))
            return
        reply = self.respond(request)
        if reply is None:
            self.stats.dropped += 1
            return
        reply.dev_id = dev_id
        out.append((self._framer.buildFrame(reply), used))

    def serve(self) -> None:
        while not self._stop.is_set() and not self.pty.closed:
            data = self.pty.read(256, POLL_S)
            if not data:
                continue
            t_rx = time.monotonic()
            for frame, request_len in self.handle_bytes(data, t_rx):
                due = t_rx + self.turnaround_s
                if self.emulate_baud:
                    due += (request_len + len(frame)) * self.char_s + self.silence_s
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                self._send(frame, _flip_crc)
