"""The simulated load cells and tracker on the lock-step clock, through the real protocol code.

Load cells: the controller's :class:`~cdcr_ctl.sensors.loadcell_modbus.ModbusLoadCellBus` polls
the simulated transmitters (:class:`~cdcr_ctl.sim.loadcells.ModbusLoadCellSim`) over
:class:`SerialLoopback`, a port object whose far end answers each request frame at once; the
Modbus RTU bytes are built and parsed by the production code on both sides. Time on the wire is
kept in simulated time: each transaction takes its request and reply characters at the
configured baud rate plus the bus silence (t3.5 or ``inter_frame_s``), and its reading is
published when the reply's last byte arrives (:class:`LoadCellSchedule`).

Tracker: frames of :class:`~cdcr_ctl.sim.tracker.SimNatNetServer` are made every ``1/rate_hz`` s
of simulated time from the truth, packed as NAT_FRAMEOFDATA datagrams and handed to the
controller's :class:`~cdcr_ctl.sensors.tracker.NatNetTracker` parser ``latency_s`` later
(:class:`TrackerSchedule`); the reader's clock is the simulated one, so ages and staleness are in
simulated time.
"""

from __future__ import annotations

import collections
from collections.abc import Callable

from cdcr_ctl.sensors.loadcell_modbus import READ_REQUEST_BYTES, ModbusLoadCellBus, char_time_s
from cdcr_ctl.sensors.loadcell_sampler import LoadCellSampler
from cdcr_ctl.sensors.tracker import NatNetTracker
from cdcr_ctl.sim.loadcells import ModbusLoadCellSim
from cdcr_ctl.sim.lockstep.canlink import no_cpu_clock
from cdcr_ctl.sim.tracker import SimNatNetServer


class SerialLoopback:
    """A pyserial-like port (``write``, ``read``, ``in_waiting``, ``timeout``) whose peer is a
    simulated Modbus transmitter: each request written is answered at once, at the simulated
    time ``clock()``. No pty, no thread."""

    def __init__(
        self,
        device: ModbusLoadCellSim,
        clock: Callable[[], float],
        *,
        port: str,
        baudrate: int,
        parity: str = "N",
        stopbits: int = 1,
    ) -> None:
        self.device = device
        self.clock = clock
        self.port = port
        self.baudrate = baudrate
        self.parity = parity
        self.stopbits = stopbits
        self.timeout: float | None = None
        self._rx = bytearray()
        self.is_open = True

    def write(self, data: bytes) -> int:
        for frame, _request_len in self.device.handle_bytes(bytes(data), self.clock()):
            self._rx += frame
        return len(data)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def close(self) -> None:
        self.is_open = False


class LoadCellSchedule:
    """Polls the load-cell bus back to back in simulated time, one transaction after another,
    each taking its wire time; publishes each reading when its reply has arrived."""

    def __init__(self, sampler: LoadCellSampler, link: ModbusLoadCellBus, silence_s: float):
        self.sampler = sampler
        self.link = link
        port = link.port
        char_s = char_time_s(port.baudrate, port.parity, port.stopbits)
        #: One poll: request and reply characters on the wire, and the bus silence the master
        #: keeps before each request (s).
        wire_chars = READ_REQUEST_BYTES + link.plan.reply_bytes
        self.transaction_s = wire_chars * char_s + silence_s
        self.next_s = self.transaction_s  # the first reply arrives one transaction after t = 0
        self.cpu_s = 0.0
        self.cpu_clock: Callable[[], float] = no_cpu_clock  # time.thread_time to measure
        self.polls = 0

    def advance(self, t0: float, t1: float) -> None:
        """Every transaction whose reply arrives in (t0, t1]."""
        c0 = self.cpu_clock()
        while self.next_s <= t1:
            got = self.link.poll()
            if got:
                self.sampler.publish(got, self.next_s)
            self.polls += 1
            self.next_s += self.transaction_s
        self.cpu_s += self.cpu_clock() - c0


class TrackerSchedule:
    """NatNet frames every ``1/rate_hz`` s of simulated time, delivered ``latency_s`` later."""

    def __init__(self, server: SimNatNetServer, reader: NatNetTracker) -> None:
        self.server = server
        self.reader = reader
        self.next_s = 0.0
        #: (receipt time s, datagram) of the frames made and not yet delivered.
        self._queue: collections.deque[tuple[float, bytes]] = collections.deque()
        self._source = server.data_address
        self.cpu_s = 0.0
        self.cpu_clock: Callable[[], float] = no_cpu_clock  # time.thread_time to measure
        self.frames = 0

    def advance(self, t0: float, t1: float) -> None:
        """Frames exposed in (t0, t1] are made now (from the truth as stepped for this period);
        frames due by t1 are packed and parsed."""
        c0 = self.cpu_clock()
        server = self.server
        while self.next_s <= t1:
            t_rx = self.next_s + server.latency_s
            self._queue.append((t_rx, server.make_datagram(self.next_s, transmit_s=t_rx)))
            self.next_s += server.period_s
        while self._queue and self._queue[0][0] <= t1:
            t_rx, data = self._queue.popleft()
            self.reader.handle_datagram(data, self._source, t_rx)
            self.frames += 1
        self.cpu_s += self.cpu_clock() - c0


__all__ = ["LoadCellSchedule", "SerialLoopback", "TrackerSchedule"]
