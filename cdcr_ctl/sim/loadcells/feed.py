"""The world feed of the simulated load cells: truth tensions (N) + drift + noise + dropouts.

A callable returns the truth tensions (N) per cell; :class:`SensorNoise` adds Gaussian noise, a
linear drift and random dropouts (no reply / a missing line); :meth:`TensionFeed.spike`
(``sim.feed.spike``: a snagged cable reads high).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.sensors.loadcell import G_M_PER_S2

#: Rated capacity of a JLBS-MD-10kg cell (N).
CAPACITY_N = 10.0 * G_M_PER_S2

#: The transmitter reports overload above this fraction of capacity.
OVERLOAD_FRACTION = 1.1

#: Gaussian draws taken from the generator at once when nothing else draws from it.
NOISE_BLOCK = 256


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
        #: Noise drawn ahead, in blocks (only without dropouts: then the generator draws nothing
        #: else, and ``rng.normal(0, s, n)`` gives the n numbers n calls ``rng.normal(0, s)``
        #: give, in the same order: numpy's ``random_normal`` per element either way).
        self._ahead: list[float] = []
        self._batched = not noise.dropout

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
            value += self._draw()
        return value

    def _draw(self) -> float:
        """The next ``rng.normal(0.0, noise_N)`` (N)."""
        if not self._batched:
            return float(self.rng.normal(0.0, self.noise.noise_N))
        if not self._ahead:
            block = self.rng.normal(0.0, self.noise.noise_N, NOISE_BLOCK).tolist()
            block.reverse()
            self._ahead = block
        return self._ahead.pop()
