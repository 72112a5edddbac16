"""Simulated ASCII load-cell transmitter: ``ST,GS,+  4.876kg`` lines streamed on a pty.

With ``emulate_baud`` it sends no faster than its lines take on the wire.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from cdcr_ctl.sensors.loadcell import from_newtons
from cdcr_ctl.sensors.loadcell_ascii import format_line
from cdcr_ctl.sim.loadcells.feed import CAPACITY_N, OVERLOAD_FRACTION, SensorNoise, Tensions
from cdcr_ctl.sim.loadcells.pty import PtySim


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
