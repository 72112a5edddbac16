"""Read load cells in their own thread and publish the latest force of each cell with its age.

The sampler thread polls its link back to back (a Modbus bus cell after cell, as fast as the baud
rate and the bus silences allow; an ASCII stream as fast as it sends) and publishes every good
reading with the monotonic time it arrived. The control loop calls :meth:`LoadCellSampler.latest`
and never waits on the serial port. A sample older than ``stale_after_s`` is flagged stale; when
the port fails the sampler stops, keeps the :class:`~cdcr_ctl.errors.SensorError` in
:attr:`LoadCellSampler.failure` and flags every sample stale.

Usage::

    with open_load_cells(cfg.sensors.load_cells) as cells:
        cells.wait_for_samples(timeout_s=1.0)
        for s in cells.latest():
            print(s.index, s.address, s.force_N, s.age_s, s.stale)
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import serial

from cdcr_ctl import seriallink
from cdcr_ctl.config.loadcells import LoadCellsConfig
from cdcr_ctl.errors import RigTimeoutError, SensorError
from cdcr_ctl.sensors.loadcell import Calibration, LinkStats, LoadCellReading
from cdcr_ctl.sensors.loadcell_ascii import AsciiLoadCellStream
from cdcr_ctl.sensors.loadcell_modbus import ModbusLoadCellBus
from cdcr_ctl.sensors.sample import Clock, LatestValue

log = logging.getLogger(__name__)

#: Longest wait for the sampler thread to finish its current request and stop (s).
JOIN_TIMEOUT_S = 2.0

#: Longest wait for a tare command to be carried out by the sampler thread (s).
TARE_TIMEOUT_S = 1.0


class LoadCellLink(Protocol):
    """What the sampler needs from a protocol reader (Modbus bus or ASCII stream)."""

    port_name: str
    stats: LinkStats
    n_cells: int

    def address(self, index: int) -> int | None: ...

    def poll(self) -> list[tuple[int, LoadCellReading]]:
        """One unit of I/O; the readings it produced. Raises SensorError on port failure."""

    def tare(self, index: int) -> None: ...

    def close(self) -> None: ...


@dataclass(frozen=True, slots=True)
class LoadCellSample:
    """Latest force of one cell as the loop sees it.

    ``index``: position of the cell in the config's ``cells`` list; ``address``: its Modbus slave
    address (None on an ASCII stream). ``force_N``: calibrated force (N), NaN when no sample yet,
    ±inf on overload. ``t_s``: arrival time (s, monotonic clock); ``age_s``: its age now (s, inf
    when none); ``stale``: older than ``stale_after_s``, none yet, or the port has failed.
    ``reading_N``: the transmitter's reading before calibration (N). ``stable``/``net``: the
    transmitter's flags when its protocol has them (else None). ``seq``: samples so far.
    """

    index: int
    address: int | None
    force_N: float
    t_s: float
    age_s: float
    stale: bool
    reading_N: float
    stable: bool | None
    net: bool | None
    overload: bool
    seq: int


class LoadCellSampler:
    """Runs a :class:`LoadCellLink` in a daemon thread and keeps the latest sample per cell.

    ``calibrations``: one per cell (default: identity). ``stale_after_s`` (s). ``clock``: seconds,
    default ``time.monotonic`` (tests inject one). The sampler owns ``link``: :meth:`close` (and
    leaving the ``with`` block) stops the thread and closes the port.
    """

    def __init__(
        self,
        link: LoadCellLink,
        calibrations: Sequence[Calibration] | None = None,
        *,
        stale_after_s: float = 0.1,
        clock: Clock = time.monotonic,
    ) -> None:
        n = link.n_cells
        cals = list(calibrations) if calibrations is not None else [Calibration()] * n
        if len(cals) != n:
            raise ValueError(f"{len(cals)} calibrations for {n} cells")
        self.link = link
        self.port_name = link.port_name
        self._cals = cals
        self._holders: list[LatestValue[LoadCellReading]] = [
            LatestValue(stale_after_s, clock) for _ in range(n)
        ]
        self._clock = clock
        self._commands: queue.SimpleQueue[tuple[Callable[[], object], Future[object]]] = (
            queue.SimpleQueue()
        )
        self._stop = threading.Event()
        self._published = threading.Condition()
        #: Threads in :meth:`wait_for_samples` (counted under ``_published`` before their first
        #: look at the samples, so a publish that reads 0 here happened before that look).
        self._waiters = 0
        self._thread: threading.Thread | None = None
        self.failure: SensorError | None = None

    # -- life cycle ---------------------------------------------------------------------

    @property
    def n_cells(self) -> int:
        return len(self._holders)

    @property
    def stats(self) -> LinkStats:
        """The link's frame counters (good, bad, timeouts, exceptions, discarded bytes)."""
        return self.link.stats

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> LoadCellSampler:
        """Start the sampling thread (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._run, name=f"loadcells {self.port_name}", daemon=True
            )
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread after its current request; the port stays open."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(JOIN_TIMEOUT_S)
            if self._thread.is_alive():
                log.warning(
                    "%s: load-cell thread did not stop in %s s", self.port_name, JOIN_TIMEOUT_S
                )

    def close(self) -> None:
        """Stop the thread and close the port (idempotent)."""
        self.stop()
        self.link.close()

    def __enter__(self) -> LoadCellSampler:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what the loop calls ------------------------------------------------------------

    def latest(self, now_s: float | None = None) -> tuple[LoadCellSample, ...]:
        """Latest sample of every cell, in config order, aged at ``now_s`` (default now).

        Never blocks on the port.
        """
        now = self._clock() if now_s is None else now_s
        failed = self.failure is not None
        out = []
        for i, holder in enumerate(self._holders):
            got = holder.latest(now)
            r = got.value
            address = self.link.address(i)
            if r is None:
                out.append(
                    LoadCellSample(
                        i,
                        address,
                        math.nan,
                        got.t_s,
                        got.age_s,
                        True,
                        math.nan,
                        None,
                        None,
                        False,
                        0,
                    )
                )
                continue
            out.append(
                LoadCellSample(
                    i,
                    address,
                    self._cals[i].apply(r.reading_N),
                    got.t_s,
                    got.age_s,
                    got.stale or failed,
                    r.reading_N,
                    r.stable,
                    r.net,
                    r.overload,
                    got.seq,
                )
            )
        return tuple(out)

    def latest_forces(self, now_s: float | None = None) -> tuple[list[float], list[float]]:
        """Per cell in config order: its calibrated force (N; NaN before the first sample) and
        the age of that sample at ``now_s`` (s; inf before the first), the ``force_N`` and
        ``age_s`` :meth:`latest` gives, without the rest of the sample (the loop's one read
        each cycle). Never blocks on the port."""
        now = self._clock() if now_s is None else now_s
        forces: list[float] = []
        ages: list[float] = []
        for cal, holder in zip(self._cals, self._holders, strict=True):
            stamped = holder.stamped  # one reference read: the newest value and its time
            if stamped is None:
                forces.append(math.nan)
                ages.append(math.inf)
                continue
            r = stamped.value
            forces.append(math.nan if r is None else cal.apply(r.reading_N))
            ages.append(stamped.age_s(now))
        return forces, ages

    def raise_if_failed(self) -> None:
        """Raise the :class:`SensorError` that stopped the sampler, if any."""
        if self.failure is not None:
            raise self.failure

    # -- blocking helpers (start-up, commands; not for the loop's path) -----------------------

    def wait_for_samples(self, count: int = 1, timeout_s: float = 1.0) -> None:
        """Block until every cell has ``count`` samples; :class:`RigTimeoutError` after
        ``timeout_s`` (s), the sampler's :class:`SensorError` if it failed meanwhile."""
        deadline = time.monotonic() + timeout_s
        with self._published:
            self._waiters += 1
            try:
                self._wait_for(count, timeout_s, deadline)
            finally:
                self._waiters -= 1

    def _wait_for(self, count: int, timeout_s: float, deadline: float) -> None:
        """:meth:`wait_for_samples`' loop (``_published`` held)."""
        while True:
            self.raise_if_failed()
            seqs = [h.stamped.seq if h.stamped else 0 for h in self._holders]
            if min(seqs) >= count:
                return
            left = deadline - time.monotonic()
            if left <= 0:
                raise RigTimeoutError(
                    f"{self.port_name}: load cells have {seqs} samples after {timeout_s} s, "
                    f"wanted {count} each; link stats {self.stats}"
                )
            self._published.wait(min(left, 0.05))

    def calibration(self, index: int) -> Calibration:
        return self._cals[index]

    def set_calibration(self, index: int, calibration: Calibration) -> None:
        """Use ``calibration`` for cell ``index`` from now on (applies to the latest sample too)."""
        self._cals[index] = calibration

    def zero(self, index: int) -> Calibration:
        """Software zero: make the latest reading of cell ``index`` read 0 N; return the new
        calibration. Raises :class:`SensorError` when the cell has no fresh sample."""
        got = self._holders[index].latest()
        if got.value is None or got.stale or got.value.overload:
            raise SensorError(self.port_name, f"cell {index}: no fresh sample to zero on")
        cal = self._cals[index].with_zero(got.value.reading_N)
        self._cals[index] = cal
        return cal

    def tare(self, index: int, timeout_s: float = TARE_TIMEOUT_S) -> None:
        """Tare cell ``index``'s transmitter, between two polls of the sampler thread.

        Raises :class:`SensorError` (no tare register, no acknowledgement, port failed) or
        :class:`RigTimeoutError` when not done within ``timeout_s`` (s).
        """
        self.raise_if_failed()
        if not self.running:
            self.link.tare(index)
            return
        fut: Future[object] = Future()
        self._commands.put((lambda: self.link.tare(index), fut))
        try:
            fut.result(timeout=timeout_s)
        except TimeoutError as exc:
            raise RigTimeoutError(
                f"{self.port_name}: tare of cell {index} not done within {timeout_s} s"
            ) from exc

    def publish(self, readings: Sequence[tuple[int, LoadCellReading]], t_s: float) -> None:
        """Publish ``[(index, reading)]`` of one poll, acquired at ``t_s`` (s, the sampler's
        clock). The thread does this after each poll; a caller that polls the link itself on
        its own schedule (the lock-step simulator, without :meth:`start`) does it too."""
        for index, reading in readings:
            self._holders[index].publish(reading, t_s)
        if self._waiters:  # nobody waits: no one to wake (see ``_waiters``)
            with self._published:
                self._published.notify_all()

    # -- the thread ---------------------------------------------------------------------

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._run_commands()
                got = self.link.poll()
                if got:
                    self.publish(got, self._clock())
        except SensorError as exc:
            self._fail(exc)
        except Exception as exc:  # a bug must not leave the loop reading fresh-looking data
            err = SensorError(self.port_name, f"load-cell sampler crashed: {exc!r}")
            err.__cause__ = exc
            self._fail(err)

    def _run_commands(self) -> None:
        while True:
            try:
                call, fut = self._commands.get_nowait()
            except queue.Empty:
                return
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(call())
            except SensorError as exc:
                fut.set_exception(exc)

    def _fail(self, exc: SensorError) -> None:
        log.error("%s", exc)
        self.failure = exc
        for holder in self._holders:
            holder.invalidate()
        while True:  # nobody will run queued commands any more
            try:
                _call, fut = self._commands.get_nowait()
            except queue.Empty:
                break
            if fut.set_running_or_notify_cancel():
                fut.set_exception(exc)
        with self._published:
            self._published.notify_all()


def forces_and_ages(samples: Sequence[LoadCellSample]) -> tuple[np.ndarray, np.ndarray]:
    """``(force_N, age_s)`` arrays from :meth:`LoadCellSampler.latest` (NaN/inf where none)."""
    return (
        np.array([s.force_N for s in samples], dtype=float),
        np.array([s.age_s for s in samples], dtype=float),
    )


def open_serial(cfg: LoadCellsConfig) -> serial.SerialBase:
    """Open ``cfg.serial`` (device path or pyserial URL) exclusively; SensorError on failure."""
    s = cfg.serial
    seriallink.register()
    try:
        return serial.serial_for_url(
            s.port,
            baudrate=s.baudrate,
            parity=s.parity,
            stopbits=s.stopbits,
            timeout=s.timeout_s,
            exclusive=True,
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise SensorError(s.port, f"cannot open load-cell port: {exc}") from exc


def open_load_cells(
    cfg: LoadCellsConfig,
    *,
    port: serial.SerialBase | None = None,
    clock: Clock = time.monotonic,
) -> LoadCellSampler:
    """The sampler for a ``sensors.load_cells`` config section (not started: use ``with``).

    Opens ``cfg.serial`` unless an open ``port`` is given. Cell ``i`` of the sampler is
    ``cfg.cells[i]``: Modbus slave ``cells[i].slave``, calibration ``zero_N``/``span``.
    """
    opened = port is None
    port = open_serial(cfg) if port is None else port
    name = cfg.serial.port
    try:
        link: LoadCellLink
        if cfg.protocol == "modbus_rtu":
            link = ModbusLoadCellBus(
                port,
                [c.slave for c in cfg.cells],
                cfg.register_map,
                response_timeout_s=cfg.serial.timeout_s,
                inter_frame_s=cfg.inter_frame_s,
                port_name=name,
            )
        else:
            if len(cfg.cells) != 1:
                raise SensorError(
                    name, f"an ASCII stream carries one cell, config has {len(cfg.cells)}"
                )
            link = AsciiLoadCellStream(port, port_name=name)
        cals = [Calibration(zero_N=c.zero_N, span=c.span) for c in cfg.cells]
        return LoadCellSampler(link, cals, stale_after_s=cfg.stale_after_s, clock=clock)
    except BaseException:
        if opened:
            port.close()
        raise
