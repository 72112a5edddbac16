"""Load cells: units, calibration, and the data types every load-cell protocol produces.

A load cell here is a number of newtons and nothing else: cells are identified by their index on
the bus and (Modbus) their slave address; which cable a cell measures is the control loop's
business. The protocol readers (:mod:`.loadcell_modbus`, :mod:`.loadcell_ascii`) turn bytes into
:class:`LoadCellReading` in newtons; :class:`Calibration` turns a reading into a force;
:mod:`.loadcell_sampler` runs a reader in its own thread and publishes the latest samples.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Literal

#: Standard acceleration of gravity (m/s^2), CGPM 1901 / ISO 80000-3: 1 kgf = 9.80665 N.
G_M_PER_S2 = 9.80665

#: One avoirdupois pound (kg), international yard and pound agreement 1959.
LB_KG = 0.45359237

Unit = Literal["kg", "g", "N", "lb"]

#: Newtons per unit of reading: a transmitter calibrated in kg reports kilogram-force.
NEWTONS_PER_UNIT: dict[str, float] = {
    "kg": G_M_PER_S2,
    "g": G_M_PER_S2 / 1000.0,
    "N": 1.0,
    "lb": LB_KG * G_M_PER_S2,
}


def to_newtons(value: float, unit: str) -> float:
    """Convert a reading in ``unit`` (kg, g, N, lb: mass units mean kilogram-force etc.) to N.

    ``F_N = value * g`` for kg with g = 9.80665 m/s^2; raises ``ValueError`` for other units.
    """
    try:
        return value * NEWTONS_PER_UNIT[unit]
    except KeyError:
        raise ValueError(
            f"unknown load-cell unit {unit!r} (know {sorted(NEWTONS_PER_UNIT)})"
        ) from None


def from_newtons(force_N: float, unit: str) -> float:
    """Inverse of :func:`to_newtons`: express ``force_N`` (N) in ``unit``."""
    return force_N / NEWTONS_PER_UNIT[unit]


@dataclass(frozen=True, slots=True)
class Calibration:
    """Linear calibration of one cell: ``force_N = span * (reading_N - zero_N)``.

    ``zero_N`` (N) is the reading with no load; ``span`` (dimensionless) corrects the gain.
    Overload readings (±inf) stay ±inf, so a limit check still trips on them.
    """

    zero_N: float = 0.0
    span: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.zero_N) and math.isfinite(self.span) and self.span > 0):
            raise ValueError(f"calibration needs finite zero_N and span > 0, got {self}")

    def apply(self, reading_N: float) -> float:
        """Force (N) for a transmitter reading (N)."""
        return self.span * (reading_N - self.zero_N)

    def with_zero(self, reading_N: float) -> Calibration:
        """The same span, zeroed so that ``reading_N`` (N, the unloaded reading) gives 0 N."""
        return Calibration(zero_N=float(reading_N), span=self.span)

    @classmethod
    def from_two_points(
        cls, reading_a_N: float, known_a_N: float, reading_b_N: float, known_b_N: float
    ) -> Calibration:
        """Zero and span from two known loads: ``known = span * (reading - zero)`` at both.

        span = (known_b - known_a) / (reading_b - reading_a); zero = reading_a - known_a / span.
        Typical use: a = no load (known 0 N), b = a reference mass m (known m * g).
        """
        d_reading = reading_b_N - reading_a_N
        if d_reading == 0:
            raise ValueError("two-point calibration needs two different readings")
        span = (known_b_N - known_a_N) / d_reading
        return cls(zero_N=reading_a_N - known_a_N / span, span=span)


@dataclass(frozen=True, slots=True)
class LoadCellReading:
    """One reading as the transmitter reported it, converted to newtons (before calibration).

    ``value``/``unit``: the number and unit on the wire; ``reading_N``: that in N (±inf on
    overload); ``stable``: the transmitter's motion flag (ASCII ST/US; None when the protocol has
    none); ``net``: True for a net (tared) value, False for gross, None when unknown.
    """

    value: float
    unit: str
    reading_N: float
    stable: bool | None = None
    net: bool | None = None
    overload: bool = False


@dataclass
class LinkStats:
    """Counters of one serial link, for logs and tests. All counts since the reader was made.

    ``frames_ok``: frames returned as readings; ``bad_frames``: frames or responses seen and
    rejected (bad CRC, wrong length, unparsable line, nonsense decimals); ``timeouts``: requests
    with no reply at all; ``exceptions``: Modbus exception responses; ``discarded_bytes``: bytes
    thrown away around frames (line noise, stale replies, local echo).
    """

    frames_ok: int = 0
    bad_frames: int = 0
    timeouts: int = 0
    exceptions: int = 0
    discarded_bytes: int = 0


@dataclass
class TrafficLog:
    """The last ``size`` frames on a link as (t_s, direction, bytes); dumped with any fault."""

    size: int = 16
    frames: deque[tuple[float, str, bytes]] = field(default_factory=deque)

    def add(self, direction: str, data: bytes, t_s: float | None = None) -> None:
        """Record ``data`` sent (``"tx"``) or received (``"rx"``) at ``t_s`` (s, monotonic)."""
        self.frames.append((time.monotonic() if t_s is None else t_s, direction, bytes(data)))
        while len(self.frames) > self.size:
            self.frames.popleft()

    def dump(self, last: int = 6) -> str:
        """The last ``last`` frames as ``tx 01 03 ...`` lines (hex), oldest first."""
        rows = list(self.frames)[-last:]
        return "\n".join(f"  {d} {b.hex(' ') or '(nothing)'}" for _, d, b in rows)
