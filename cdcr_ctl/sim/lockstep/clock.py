"""Simulated time for the lock-step rig: one SYNC period per loop cycle, from the cycle count.

:class:`SimClock` is a :class:`~cdcr_ctl.control.clock.LoopClock`. Its time is ``n * period_s``
after ``n`` cycles, never the wall clock, so a run's timing is the same on an idle machine and
under ``stress-ng``. Before each cycle it advances the world by one period (``advance(t0, t1)``:
the truth, the sensors' schedules) and returns at once: nothing sleeps.

The clock moves only while the loop has work (``busy()``: a run, a posted command, an offset
ramping; :attr:`cdcr_ctl.control.loop.ControlLoop.busy`). An idle simulated rig stands still, so
how long a client takes between two requests changes nothing in the world or in the logs. While
idle the loop thread waits for the next command (it polls ``busy`` every
:data:`IDLE_POLL_S` of wall time or at once on :meth:`SimClock.wake`); that is waiting for work,
not pacing simulated time.

The drive layer's sequences (enable, fault reset, the settle on close) run off the loop thread
and clock their own SYNCs while the loop is idle, with the world standing still: how many such
SYNCs a sequence sends depends on how fast the host answers, so none of them may move the world.
Their timeouts are measured on this clock (the drive group's ``watch_clock``), which stands
still meanwhile: a starved host delays them but cannot make them expire, and a drive that never
answers ends on the group's wall-clock backstop.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from cdcr_ctl.control.timing import LatenessStats

#: While the loop is idle, look for new work this often (s, wall clock).
IDLE_POLL_S = 0.002

#: :meth:`SimClock.wait_settled` looks again at least this often (s, wall clock).
SETTLE_POLL_S = 0.01
#: Longest wall time a caller waits for the loop to settle between two commands (s).
SETTLE_TIMEOUT_S = 60.0

Advance = Callable[[float, float], None]


class SimClock:
    """Loop clock on simulated time (s), starting at ``t0_s``. ``advance(t0, t1)`` moves the
    world from ``t0`` to ``t1``; ``busy()`` says whether the loop has work (default: always)."""

    def __init__(
        self,
        period_s: float,
        advance: Advance | None = None,
        busy: Callable[[], bool] | None = None,
        t0_s: float = 0.0,
    ) -> None:
        if not period_s > 0:
            raise ValueError("period_s must be positive")
        self.period_s = float(period_s)
        self.advance = advance
        self.busy = busy
        self.stats = LatenessStats()
        self.cycles = 0
        self.t0_s = float(t0_s)
        self._t = self.t0_s
        self._wake = threading.Event()
        #: Set while the loop waits for work (it has ended its run, say), clear while it has
        #: some: a caller waiting for a run's end waits on this, not polling the loop.
        self.idle = threading.Event()
        self._closed = False
        #: Called once, on the loop thread, before its first cycle (the rig pins that thread
        #: to its CPU there: :mod:`.placement`), or None.
        self.thread_setup: Callable[[], None] | None = None

    def now(self) -> float:
        """Simulated time (s) of the present cycle: ``t0_s`` + cycles so far times the period."""
        return self._t

    def wait(self) -> tuple[float, float]:
        """Wait for work (never for time), advance the world one period; (deadline, 0). The
        first cycle is at ``t0_s`` and advances nothing."""
        if self.thread_setup is not None:
            setup, self.thread_setup = self.thread_setup, None
            setup()
        busy = self.busy
        if busy is not None and not busy():
            self.idle.set()
            while not busy() and not self._closed:
                self._wake.wait(IDLE_POLL_S)
                self._wake.clear()
            self.idle.clear()
        if self.cycles > 0:
            t0, t1 = self._t, self.t0_s + self.cycles * self.period_s
            if self.advance is not None:
                self.advance(t0, t1)
            self._t = t1
        self.cycles += 1
        self.stats.add(0.0)
        return self._t, 0.0

    def wait_settled(self, timeout_s: float) -> bool:
        """(Not on the loop thread.) Wait, on the wall clock, until the loop has taken up every
        posted command and has no work left (it waits for work: :attr:`idle` set and ``busy()``
        false); False after ``timeout_s`` (s) without that.

        Why: the loop takes up every command posted before a cycle in that cycle. Two commands
        posted one after the other (``home``, then a run) land in one cycle or in two,
        depending on when the loop thread got the CPU, and the run would start one period
        earlier or later in simulated time. Posting the next command only once the loop has
        settled makes the cycle each command lands in a function of the commands alone."""
        busy = self.busy
        end = time.monotonic() + timeout_s
        while not self._closed:
            if self.idle.is_set() and (busy is None or not busy()):
                return True
            left = end - time.monotonic()
            if left <= 0:
                return False
            self.idle.wait(min(left, SETTLE_POLL_S))
            if self.idle.is_set():
                time.sleep(SETTLE_POLL_S / 10)  # idle but busy: a command not yet taken up
        return False

    def done(self) -> None:
        """Nothing to schedule: the next cycle is due as soon as there is work."""

    def reset_stats(self) -> LatenessStats:
        old, self.stats = self.stats, LatenessStats()
        return old

    def wake(self) -> None:
        """Look for work now (a command was posted)."""
        self._wake.set()

    def close(self) -> None:
        """Stop waiting for work (the loop is stopping)."""
        self._closed = True
        self._wake.set()


__all__ = ["IDLE_POLL_S", "SETTLE_POLL_S", "SETTLE_TIMEOUT_S", "SimClock"]
