"""Timestamped samples shared by every sensor: a stamped value and a latest-value holder.

A sensor thread :meth:`LatestValue.publish`-es each new value with the monotonic time it was
acquired; the control loop calls :meth:`LatestValue.latest` and gets the value with its age and a
stale flag, without waiting on the sensor (the lock is held only to swap one reference).

Times are seconds on the ``time.monotonic()`` clock unless a test injects another clock.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")

Clock = Callable[[], float]


@dataclass(frozen=True, slots=True)
class Stamped(Generic[T]):
    """A value and when it was acquired.

    ``t_s``: acquisition time (s, monotonic clock); ``seq``: 1 for the first value a holder
    published, then counting up (tells a reader whether it has already seen this value).
    """

    value: T
    t_s: float
    seq: int = 0

    def age_s(self, now_s: float) -> float:
        """Seconds since acquisition at ``now_s`` (same clock as ``t_s``)."""
        return now_s - self.t_s


@dataclass(frozen=True, slots=True)
class Latest(Generic[T]):
    """What a reader sees: the newest value, its time and age, and whether it is stale.

    With no value yet: ``value`` None, ``t_s`` NaN, ``age_s`` inf, ``stale`` True, ``seq`` 0.
    ``stale`` is True when ``age_s > stale_after_s`` or the holder was invalidated (sensor lost)
    since the last publish.
    """

    value: T | None
    t_s: float
    age_s: float
    stale: bool
    seq: int


class LatestValue(Generic[T]):
    """Thread-safe holder of the newest :class:`Stamped` value of one sensor channel.

    One writer (the sensor's thread) and any number of readers. ``stale_after_s`` (s) is the age
    beyond which a value is flagged stale; ``clock`` returns seconds (default
    ``time.monotonic``) and is injectable for tests.
    """

    def __init__(self, stale_after_s: float, clock: Clock = time.monotonic) -> None:
        if not stale_after_s > 0:
            raise ValueError(f"stale_after_s must be > 0 s, got {stale_after_s!r}")
        self.stale_after_s = float(stale_after_s)
        self.clock = clock
        self._lock = threading.Lock()
        self._stamped: Stamped[T] | None = None
        self._valid = True

    def publish(self, value: T, t_s: float | None = None) -> Stamped[T]:
        """Store ``value`` acquired at ``t_s`` (s; default: now on the holder's clock)."""
        t = self.clock() if t_s is None else float(t_s)
        with self._lock:
            seq = 1 if self._stamped is None else self._stamped.seq + 1
            stamped = Stamped(value, t, seq)
            self._stamped = stamped
            self._valid = True
        return stamped

    def invalidate(self) -> None:
        """Flag the current value stale until the next :meth:`publish` (the sensor was lost)."""
        with self._lock:
            self._valid = False

    @property
    def stamped(self) -> Stamped[T] | None:
        """The newest stamped value, or None."""
        return self._stamped

    def latest(self, now_s: float | None = None) -> Latest[T]:
        """The newest value with its age at ``now_s`` (s; default: now). Never blocks on I/O."""
        with self._lock:
            stamped, valid = self._stamped, self._valid
        if stamped is None:
            return Latest(None, math.nan, math.inf, True, 0)
        now = self.clock() if now_s is None else float(now_s)
        age = stamped.age_s(now)
        return Latest(
            stamped.value, stamped.t_s, age, (not valid) or age > self.stale_after_s, stamped.seq
        )
