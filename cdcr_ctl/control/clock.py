"""The loop's clock: what ``ControlLoop`` asks of time, so the same loop runs on the wall clock on
the rig and on simulated time in the lock-step simulator (:mod:`cdcr_ctl.sim.lockstep`).

A clock has a fixed period (s) and hands out cycle deadlines: :meth:`LoopClock.wait` returns when
the next cycle is due, with ``(deadline, lateness_s)`` on the clock's own time base;
:meth:`LoopClock.done` marks the end of a cycle's work; :meth:`LoopClock.now` reads the clock
(s). The wall clock is :class:`~cdcr_ctl.control.timing.Ticker` (``time.monotonic``, sleep then
spin to each absolute deadline), the default of every loop.
"""

from __future__ import annotations

from typing import Protocol

from cdcr_ctl.control.timing import LatenessStats, Ticker


class LoopClock(Protocol):
    """Cycle deadlines at ``period_s`` (s) and the statistics of how late each cycle started."""

    period_s: float
    stats: LatenessStats

    def now(self) -> float:
        """The clock's present time (s)."""

    def wait(self) -> tuple[float, float]:
        """Block until the next cycle is due; ``(deadline s, lateness s)``."""

    def done(self) -> None:
        """End of one cycle's work."""

    def reset_stats(self) -> LatenessStats:
        """Start the statistics afresh; returns the old ones."""


def wall_clock(period_s: float) -> LoopClock:
    """The default: absolute deadlines on ``time.monotonic`` (:class:`Ticker`)."""
    return Ticker(period_s)


__all__ = ["LoopClock", "wall_clock"]
