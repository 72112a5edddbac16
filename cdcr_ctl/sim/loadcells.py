"""Simulated load-cell transmitters on a pseudo-terminal: a Modbus RTU slave bus or an ASCII stream.

A callable returns the truth tensions (N) per cell; :class:`SensorNoise` adds Gaussian noise, a
linear drift and random dropouts (no reply / a missing line). Fault hooks let tests and the
simulated rig break the link on purpose: :meth:`PtySim.drop_next`, :meth:`PtySim.corrupt_next`
(bad CRC / unparsable line), :meth:`PtySim.inject_garbage`, :meth:`PtySim.split_next` (a frame
written in two pieces), :meth:`PtySim.garble_for` (nothing valid for a while),
:meth:`PtySim.disconnect` (the pty is closed, as if unplugged) / :meth:`PtySim.reconnect`, and
:meth:`TensionFeed.spike` (``sim.feed.spike``: a snagged cable reads high).

Timing: a pty moves bytes instantly and ignores the baud rate. With ``emulate_baud`` the Modbus
slave answers when a real bus would have delivered its last reply byte (request + t3.5 + reply
characters after the request arrived, plus ``turnaround_s``) and the ASCII streamer sends no
faster than its lines take on the wire. The slave's end-of-request silence is ``silence_s``
(default the spec's t3.5: 3.5 characters, fixed 1.75 ms above 19200 bit/s).

Runs in a thread (``with ModbusLoadCellSim(...) as sim: sim.path``) or as its own process::

    python -m cdcr_ctl.sim.loadcells --slaves 1 2 3 --tension-N 5 --link /tmp/cdcr-sim/loadcells
    python -m cdcr_ctl.sim.loadcells --rig config/qi2023-sim.yaml --tension-N 4 5 6

which prints the pty path on its first line of output and serves until SIGINT/SIGTERM.
Framing, CRC and PDUs are pymodbus's; production code never imports this module.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import fcntl
import math
import os
import select
import signal
import sys
import threading
import time
import tty
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersResponse,
    ReadInputRegistersResponse,
    WriteMultipleRegistersResponse,
    WriteSingleRegisterResponse,
)

from cdcr_ctl.config.loadcells import LoadCellsConfig, ModbusRegisterMap
from cdcr_ctl.sensors.loadcell import G_M_PER_S2, from_newtons
from cdcr_ctl.sensors.loadcell_ascii import format_line
from cdcr_ctl.sensors.loadcell_modbus import char_time_s, spec_silence_s

#: Rated capacity of a JLBS-MD-10kg cell (N).
CAPACITY_N = 10.0 * G_M_PER_S2

#: The transmitter reports overload above this fraction of capacity.
OVERLOAD_FRACTION = 1.1

#: Bytes arriving after this much silence start a new request; the old partial one is dropped (s).
#: (RTU's t3.5 rule, made loose because a pty and a loaded machine add their own gaps.)
FRAME_GAP_S = 0.02

#: How long the serving thread blocks in one read before checking for stop (s).
POLL_S = 0.02

#: Line noise sent before every frame while :meth:`PtySim.garble_for` is in force.
GARBLE_NOISE = b"\x00\xff\x55\xaa#?\r"

#: Registers past the highest one the map uses that still read as 0 (beyond: illegal address).
SPARE_REGISTERS = 16

Tensions = Callable[[], Sequence[float]]


@dataclass(frozen=True)
class SensorNoise:
    """What separates the transmitter's reading from the truth.

    ``noise_N``: standard deviation of white Gaussian noise (N); ``drift_N_per_s``: linear drift
    (N/s) of every cell, or one rate per cell; ``dropout``: probability that a reply (Modbus) or
    line (ASCII) is missing; ``seed``: of the random generator.
    """

    noise_N: float = 0.0
    drift_N_per_s: float | Sequence[float] = 0.0
    dropout: float = 0.0
    seed: int = 1


@dataclass
class SimStats:
    """What the simulator did: requests understood, replies/lines sent, faults applied."""

    requests: int = 0
    bad_requests: int = 0
    replies: int = 0
    dropped: int = 0
    corrupted: int = 0
    overflow_bytes: int = 0


class TensionFeed:
    """Measured tension (N) of each cell: truth + drift * t + noise, or None on a dropout."""

    def __init__(
        self, tensions: Tensions, n_cells: int, noise: SensorNoise, clock: Callable[[], float]
    ) -> None:
        self.tensions = tensions
        self.n_cells = n_cells
        self.noise = noise
        self.clock = clock
        self.t0_s = clock()
        self.rng = np.random.default_rng(noise.seed)
        drift = noise.drift_N_per_s
        self.drift_N_per_s = (
            [float(drift)] * n_cells
            if isinstance(drift, int | float)
            else [float(d) for d in drift]
        )
        if len(self.drift_N_per_s) != n_cells:
            raise ValueError(f"{len(self.drift_N_per_s)} drift rates for {n_cells} cells")
        #: Per cell: (extra tension N, until clock s) of an injected spike (a snagged cable).
        self._spikes: dict[int, tuple[float, float]] = {}

    def spike(self, index: int, add_N: float, duration_s: float) -> None:
        """Fault hook: cell ``index`` reads ``add_N`` (N) more than the truth for
        ``duration_s`` (s), as when its cable snags on a guide."""
        if not 0 <= index < self.n_cells:
            raise IndexError(f"no load cell {index} (have {self.n_cells})")
        self._spikes[index] = (float(add_N), self.clock() + float(duration_s))

    def measure(self, index: int) -> float | None:
        """Tension (N) cell ``index`` reports now, or None when this reading drops out."""
        if self.noise.dropout and self.rng.random() < self.noise.dropout:
            return None
        truth = list(self.tensions())
        if len(truth) != self.n_cells:
            raise ValueError(f"tension callback gave {len(truth)} values for {self.n_cells} cells")
        now = self.clock()
        value = float(truth[index]) + self.drift_N_per_s[index] * (now - self.t0_s)
        spike = self._spikes.get(index)
        if spike is not None and now < spike[1]:
            value += spike[0]
        if self.noise.noise_N:
            value += float(self.rng.normal(0.0, self.noise.noise_N))
        return value


class PtyEndpoint:
    """The device end of a pseudo-terminal: the simulator uses the master; clients open ``path``.

    The slave end is held open too (raw mode), so the master never sees a hang-up while no
    client is connected. ``link``: a symlink made to ``path`` (parents created), removed on close.
    Writes never block: bytes that do not fit (nobody reading) are dropped and counted.
    """

    def __init__(self, link: str | Path | None = None) -> None:
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd)
        flags = fcntl.fcntl(self.master_fd, fcntl.F_GETFL)
        fcntl.fcntl(self.master_fd, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self.path = os.ttyname(self.slave_fd)
        self.link = Path(link) if link is not None else None
        self.overflow_bytes = 0
        self._lock = threading.Lock()
        self.closed = False
        if self.link is not None:
            self.link.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self.path)
            tmp.replace(self.link)

    def write(self, data: bytes) -> None:
        """Send ``data`` to the client; what the pty buffer cannot take is dropped and counted."""
        with self._lock:
            if self.closed:
                return
            view = memoryview(data)
            while view:
                try:
                    n = os.write(self.master_fd, view)
                except BlockingIOError:
                    self.overflow_bytes += len(view)
                    return
                except OSError as exc:
                    if exc.errno == errno.EIO:  # no client and no keep-alive: nowhere to go
                        self.overflow_bytes += len(view)
                        return
                    raise
                view = view[n:]

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """Bytes the client sent (at most ``max_bytes``), waiting ``timeout_s`` (s); b'' if none."""
        if self.closed:
            return b""
        try:
            ready, _, _ = select.select([self.master_fd], [], [], timeout_s)
            if not ready:
                return b""
            return os.read(self.master_fd, max_bytes)
        except (BlockingIOError, InterruptedError):
            return b""
        except (OSError, ValueError):
            if self.closed:
                return b""
            raise

    def close(self) -> None:
        """Hang up: close both pty ends (the client's next read or write fails) and remove the
        symlink (idempotent).

        The master's descriptor number is not freed here but pointed at /dev/null (``dup2``
        closes the pty atomically), so a thread still blocked on it can never read a file
        opened later under the same number; :meth:`release` frees it.
        """
        with self._lock:
            if self.closed:
                return
            self.closed = True
            devnull = os.open(os.devnull, os.O_RDWR)
            try:
                os.dup2(devnull, self.master_fd)
            finally:
                os.close(devnull)
            with contextlib.suppress(OSError):
                os.close(self.slave_fd)
        if self.link is not None:
            with contextlib.suppress(OSError):
                if self.link.is_symlink() and os.readlink(self.link) == self.path:
                    self.link.unlink()

    def release(self) -> None:
        """Close the pty (if still open) and free the master's descriptor (idempotent).

        Call only when no thread uses this endpoint any more.
        """
        self.close()
        with self._lock:
            if self.master_fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(self.master_fd)
                self.master_fd = -1


@dataclass
class _Faults:
    drop: int = 0
    corrupt: int = 0
    split: int = 0
    split_gap_s: float = 0.005
    garbage: bytearray = field(default_factory=bytearray)
    garble_until_s: float = -math.inf


class PtySim:
    """Base of the simulated transmitters: pty, tension feed, fault hooks, serving thread."""

    def __init__(
        self,
        tensions: Tensions,
        n_cells: int,
        *,
        baudrate: int,
        emulate_baud: bool,
        noise: SensorNoise,
        link: str | Path | None,
        clock: Callable[[], float],
    ) -> None:
        self.baudrate = int(baudrate)
        self.char_s = char_time_s(self.baudrate)
        self.emulate_baud = emulate_baud
        self.clock = clock
        self.feed = TensionFeed(tensions, n_cells, noise, clock)
        self.stats = SimStats()
        self._faults = _Faults()
        self._faults_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.pty = PtyEndpoint(link)

    @property
    def path(self) -> str:
        """The pty the client opens (``/dev/pts/N``)."""
        return self.pty.path

    # -- fault hooks ----------------------------------------------------------------------

    def drop_next(self, n: int = 1) -> None:
        """Do not send the next ``n`` replies / lines."""
        with self._faults_lock:
            self._faults.drop += n

    def corrupt_next(self, n: int = 1) -> None:
        """Corrupt the next ``n`` replies (CRC) / lines (unit replaced by ``?``)."""
        with self._faults_lock:
            self._faults.corrupt += n

    def split_next(self, n: int = 1, gap_s: float = 0.005) -> None:
        """Write the next ``n`` frames in two pieces, ``gap_s`` (s) apart."""
        with self._faults_lock:
            self._faults.split += n
            self._faults.split_gap_s = gap_s

    def inject_garbage(self, data: bytes) -> None:
        """Send ``data`` just before the next frame (line noise, a stray device)."""
        with self._faults_lock:
            self._faults.garbage += data

    def garble_for(self, duration_s: float) -> None:
        """Fault hook: for ``duration_s`` (s) every reply / line is corrupted and preceded by
        line noise (a broken shield, a transmitter gone mad): no valid reading gets through."""
        with self._faults_lock:
            self._faults.garble_until_s = time.monotonic() + float(duration_s)

    def disconnect(self) -> None:
        """Close the pty: the client's next read or write fails, as if the cable were pulled."""
        self.pty.close()

    def reconnect(self) -> None:
        """Plug back in after :meth:`disconnect`: a new pty at the same link, served anew.
        (The client must open the port again.)"""
        if not self.pty.closed:
            return
        old = self.pty
        if self._thread is not None:
            self._thread.join(2.0)
        old.release()
        self.pty = PtyEndpoint(old.link)
        self._thread = None
        if not self._stop.is_set():
            self.start()

    # -- life cycle -----------------------------------------------------------------------

    def start(self) -> PtySim:
        """Serve in a daemon thread (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(
                target=self.serve, name=f"{type(self).__name__} {self.path}", daemon=True
            )
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pty."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
            if self._thread.is_alive():
                self.pty.close()  # hang up; the descriptor stays reserved for the thread
                return
        self.pty.release()

    def __enter__(self) -> PtySim:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def serve(self) -> None:
        """Serve until :meth:`stop` or :meth:`disconnect` (blocking)."""
        raise NotImplementedError

    # -- sending a frame through the fault hooks --------------------------------------------

    def _send(self, frame: bytes, corrupt: Callable[[bytes], bytes]) -> None:
        with self._faults_lock:
            f = self._faults
            if f.drop:
                f.drop -= 1
                self.stats.dropped += 1
                return
            garbling = time.monotonic() < f.garble_until_s
            if f.corrupt or garbling:
                if not garbling:
                    f.corrupt -= 1
                else:
                    f.garbage += GARBLE_NOISE
                frame = corrupt(frame)
                self.stats.corrupted += 1
            garbage, f.garbage = bytes(f.garbage), bytearray()
            split = f.split > 0
            if split:
                f.split -= 1
            gap_s = f.split_gap_s
        data = garbage + frame
        if split:
            cut = len(garbage) + max(1, len(frame) // 2)
            self.pty.write(data[:cut])
            time.sleep(gap_s)
            self.pty.write(data[cut:])
        else:
            self.pty.write(data)
        self.stats.replies += 1
        self.stats.overflow_bytes = self.pty.overflow_bytes


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
        self.registers = {s: [0] * self.n_registers for s in self.slaves}
        for s in self.slaves:
            if rm.decimals_register is not None:
                self.registers[s][rm.decimals_register] = rm.decimals
        self.tare_counts = dict.fromkeys(self.slaves, 0)
        self._framer = FramerRTU(DecodePDU(is_server=True))
        self._buf = bytearray()
        self._last_rx_s = -math.inf
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
        rm = self.register_map
        bits = 32 if rm.value_type == "int32" else 16
        lo, hi = -(2 ** (bits - 1)), 2 ** (bits - 1) - 1
        if abs(force_N) > OVERLOAD_FRACTION * self.capacity_N:
            return hi if force_N > 0 else lo
        raw = round(from_newtons(force_N, rm.unit) * 10 ** self.decimals(slave))
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
        rm = self.register_map
        if fc in (3, 4):
            if request.address + request.count > self.n_registers:
                return ExceptionResponse(fc, 2, device_id=slave)
            regs = list(self.registers[slave][request.address : request.address + request.count])
            span = range(request.address, request.address + request.count)
            vwords = 2 if rm.value_type == "int32" else 1
            vregs = range(rm.value_register, rm.value_register + vwords)
            if any(r in span for r in vregs):
                force = self.feed.measure(self.slaves.index(slave))
                if force is None:
                    return None
                words = self._value_words(self.counts(slave, force))
                for r, w in zip(vregs, words, strict=True):
                    if r in span:
                        regs[r - request.address] = w
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
        self._buf += data
        out: list[tuple[bytes, int]] = []
        while self._buf:
            try:
                used, dev_id, _tid, pdu_bytes = self._framer.decode(bytes(self._buf))
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
            self.stats.requests += 1
            reply = self.respond(request)
            if reply is None:
                self.stats.dropped += 1
                continue
            reply.dev_id = dev_id
            out.append((self._framer.buildFrame(reply), request_len))
        return out

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


def _garble_line(line: bytes) -> bytes:
    body = line.rstrip(b"\r\n")
    return body[:-2] + b"??" + line[len(body) :]


class AsciiLoadCellSim(PtySim):
    """One transmitter streaming ``ST,GS,+  4.876kg`` lines on a pty.

    ``tensions()[0]`` is the truth tension (N). ``rate_hz``: lines per second, default as fast
    as the baud rate carries them. A line is ``US`` (unstable) when the value moved more than
    ``unstable_N`` (N) since the last line, ``OL`` above :data:`OVERLOAD_FRACTION` of
    ``capacity_N``.
    """

    def __init__(
        self,
        tensions: Tensions,
        *,
        unit: str = "kg",
        decimals: int = 3,
        rate_hz: float | None = None,
        baudrate: int = 115200,
        emulate_baud: bool = True,
        unstable_N: float = 0.05,
        noise: SensorNoise | None = None,
        capacity_N: float = CAPACITY_N,
        link: str | Path | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.unit = unit
        self.decimals = decimals
        self.rate_hz = rate_hz
        self.unstable_N = unstable_N
        self.capacity_N = capacity_N
        self._previous_N: float | None = None
        super().__init__(
            tensions,
            1,
            baudrate=baudrate,
            emulate_baud=emulate_baud,
            noise=noise or SensorNoise(),
            link=link,
            clock=clock,
        )

    def line(self, force_N: float) -> bytes:
        """The line sent for a measured ``force_N`` (N)."""
        stable = self._previous_N is None or abs(force_N - self._previous_N) <= self.unstable_N
        self._previous_N = force_N
        overload = abs(force_N) > OVERLOAD_FRACTION * self.capacity_N
        return format_line(
            from_newtons(force_N, self.unit),
            self.unit,
            decimals=self.decimals,
            stable=stable,
            overload=overload,
        )

    def next_line(self) -> bytes | None:
        """The next line to send, or None when this reading drops out."""
        force = self.feed.measure(0)
        return None if force is None else self.line(force)

    def serve(self) -> None:
        due = time.monotonic()
        while not self._stop.is_set() and not self.pty.closed:
            line = self.next_line()
            period = 1.0 / self.rate_hz if self.rate_hz else 0.0
            if self.emulate_baud:
                period = max(period, len(line or b"ST,GS,+  0.000kg\r\n") * self.char_s)
            if line is None:
                with self._faults_lock:
                    self.stats.dropped += 1
            else:
                self._send(line, _garble_line)
            due += period if period > 0 else 0.001
            wait = due - time.monotonic()
            if wait > 0:
                self._stop.wait(wait)
            elif wait < -0.1:
                due = time.monotonic()  # fell far behind (machine busy): do not burst


def sim_for_config(
    lc: LoadCellsConfig,
    tensions: Tensions,
    *,
    noise: SensorNoise | None = None,
    link: str | Path | None = None,
    emulate_baud: bool = True,
    clock: Callable[[], float] = time.monotonic,
) -> PtySim:
    """The simulated transmitter(s) a rig config's ``sensors.load_cells`` section talks to (not
    started): its protocol, slave addresses (in ``cells`` order: ``tensions()[i]`` is
    ``cells[i]``), register map and baud rate. ``link`` defaults to nothing; pass
    ``lc.serial.port`` to put the pty where the controller's config looks for it."""
    if lc.protocol == "modbus_rtu":
        return ModbusLoadCellSim(
            tensions,
            [c.slave for c in lc.cells],
            lc.register_map,
            baudrate=lc.serial.baudrate,
            emulate_baud=emulate_baud,
            noise=noise,
            link=link,
            clock=clock,
        )
    return AsciiLoadCellSim(
        tensions,
        unit=lc.register_map.unit,
        decimals=lc.register_map.decimals,
        baudrate=lc.serial.baudrate,
        emulate_baud=emulate_baud,
        noise=noise,
        link=link,
        clock=clock,
    )


# -- standalone process ----------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m cdcr_ctl.sim.loadcells",
        description="Simulated load-cell transmitters on a pty; prints the pty path first.",
    )
    p.add_argument(
        "--rig",
        help="rig YAML: protocol, slaves, register map, baud and port "
        "(as --link) from its sensors.load_cells",
    )
    p.add_argument("--protocol", choices=["modbus_rtu", "ascii"], default=None)
    p.add_argument("--slaves", type=int, nargs="+", default=None, help="Modbus slave addresses")
    p.add_argument(
        "--tension-N",
        type=float,
        nargs="+",
        default=[5.0],
        help="truth tension per cell (N); one value is used for every cell",
    )
    p.add_argument("--amplitude-N", type=float, default=0.0, help="sine added to the truth (N)")
    p.add_argument("--period-s", type=float, default=2.0, help="period of that sine (s)")
    p.add_argument("--noise-N", type=float, default=0.0)
    p.add_argument("--drift-N-per-s", type=float, default=0.0)
    p.add_argument("--dropout", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--baudrate", type=int, default=None)
    p.add_argument(
        "--no-baud-emulation",
        action="store_true",
        help="answer at once instead of at the pace of the baud rate",
    )
    p.add_argument("--turnaround-s", type=float, default=0.0, help="slave think time (s)")
    p.add_argument(
        "--silence-s",
        type=float,
        default=None,
        help="end-of-request silence (s); default t3.5 of the Modbus spec",
    )
    p.add_argument("--rate-hz", type=float, default=None, help="ASCII lines per second")
    p.add_argument("--link", help="make this symlink to the pty")
    p.add_argument("--duration-s", type=float, default=None, help="exit after this long")
    return p


def build_sim(args: argparse.Namespace, clock: Callable[[], float] = time.monotonic) -> PtySim:
    """The simulator the command line asks for (not started)."""
    protocol, slaves, register_map = "modbus_rtu", [1, 2, 3], ModbusRegisterMap()
    baudrate, link = 115200, args.link
    if args.rig:
        from cdcr_ctl.config.loader import load_rig_config

        lc = load_rig_config(args.rig).sensors.load_cells
        if lc is None:
            raise SystemExit(f"{args.rig}: no sensors.load_cells section")
        protocol, register_map = lc.protocol, lc.register_map
        slaves, baudrate = [c.slave for c in lc.cells], lc.serial.baudrate
        link = link or lc.serial.port
    protocol = args.protocol or protocol
    slaves = args.slaves or slaves
    baudrate = args.baudrate or baudrate
    n = len(slaves) if protocol == "modbus_rtu" else 1
    base = list(args.tension_N) * n if len(args.tension_N) == 1 else list(args.tension_N)
    if len(base) != n:
        raise SystemExit(f"--tension-N needs 1 or {n} values, got {len(base)}")
    t0 = clock()
    amp, period = args.amplitude_N, args.period_s

    def tensions() -> list[float]:
        wave = amp * math.sin(2 * math.pi * (clock() - t0) / period) if amp else 0.0
        return [b + wave for b in base]

    noise = SensorNoise(args.noise_N, args.drift_N_per_s, args.dropout, args.seed)
    emulate = not args.no_baud_emulation
    if protocol == "modbus_rtu":
        return ModbusLoadCellSim(
            tensions,
            slaves,
            register_map,
            baudrate=baudrate,
            emulate_baud=emulate,
            silence_s=args.silence_s,
            turnaround_s=args.turnaround_s,
            noise=noise,
            link=link,
            clock=clock,
        )
    return AsciiLoadCellSim(
        tensions,
        unit=register_map.unit,
        decimals=register_map.decimals,
        rate_hz=args.rate_hz,
        baudrate=baudrate,
        emulate_baud=emulate,
        noise=noise,
        link=link,
        clock=clock,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Run the simulator until SIGINT/SIGTERM (or ``--duration-s``); print the pty path first."""
    args = _parser().parse_args(argv)
    sim = build_sim(args)
    stop = threading.Event()

    def on_signal(_sig: int, _frame: object) -> None:
        stop.set()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
    print(sim.path, flush=True)
    if sim.pty.link is not None:
        print(f"linked {sim.pty.link} -> {sim.path}", file=sys.stderr, flush=True)
    with sim:
        stop.wait(args.duration_s)
    print(f"stats {sim.stats}", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
