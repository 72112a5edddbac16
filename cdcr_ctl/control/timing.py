"""Fixed-rate scheduling on absolute monotonic deadlines, with lateness statistics.

The loop wakes at ``t0 + n * period`` (never ``now + period``, which drifts). Lateness is how far
after its deadline a cycle started; a cycle whose work ends after the next deadline is an overrun.
After an overrun the schedule skips the missed deadlines instead of bursting to catch up, and
counts them.
"""

from __future__ import annotations

import bisect
import contextlib
import ctypes
import ctypes.util
import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)

#: Histogram bin edges for lateness (us): fine near zero, coarse in the tail.
LATENESS_EDGES_US = np.array(
    [0, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10_000, 100_000, np.inf], dtype=float
)
_EDGES = LATENESS_EDGES_US.tolist()  # the same edges for bisect on the loop's path

#: Sleep this much less than needed and spin the rest (s): a SCHED_OTHER thread's sleep overshoots
#: by its 50 us timer slack plus scheduling delay (~50-150 us on a busy machine).
SPIN_MARGIN_S = 200e-6
#: The same for a SCHED_FIFO/SCHED_RR thread: no timer slack, it preempts everything else.
SPIN_MARGIN_RT_S = 50e-6


def realtime_thread() -> bool:
    """Whether the calling thread runs under a real-time policy (SCHED_FIFO or SCHED_RR)."""
    try:
        return os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR)
    except (AttributeError, OSError):
        return False


def percentiles(values: np.ndarray, qs: tuple[float, ...]) -> list[float]:
    """``numpy.percentile(values, qs)`` (its default, linear interpolation between the two
    nearest ranks) by one ``numpy.partition``, which releases the interpreter lock while it
    works; ``numpy.percentile`` spends part of its time in Python-level steps holding the lock
    (issue #21: ``status`` computed it on 65536 samples from a command thread of the rig process
    while the loop waited). ``values`` 1-D, non-empty, no NaN."""
    n = len(values)
    pos = [q / 100.0 * (n - 1) for q in qs]
    ranks = sorted({min(int(p) + k, n - 1) for p in pos for k in (0, 1)})
    part = np.partition(values, ranks)
    out = []
    for p in pos:
        lo = int(p)
        hi = min(lo + 1, n - 1)
        a, b = float(part[lo]), float(part[hi])
        out.append(a + (b - a) * (p - lo))
    return out


@dataclass
class LatenessStats:
    """Streaming lateness statistics: histogram plus a bounded reservoir for percentiles."""

    histogram: np.ndarray = field(default_factory=lambda: np.zeros(len(LATENESS_EDGES_US) - 1, int))
    cycles: int = 0
    overruns: int = 0
    skipped: int = 0
    max_us: float = 0.0
    _recent: np.ndarray = field(default_factory=lambda: np.zeros(65536))
    _n_recent: int = 0

    def add(self, lateness_s: float) -> None:
        us = lateness_s * 1e6
        self.cycles += 1
        self.max_us = max(self.max_us, us)
        i = bisect.bisect_right(_EDGES, us) - 1  # as np.searchsorted(side="right"), 20x faster
        self.histogram[min(max(i, 0), len(self.histogram) - 1)] += 1
        self._recent[self._n_recent % len(self._recent)] = us
        self._n_recent += 1

    def percentiles_us(self, qs: tuple[float, ...] = (50, 99, 99.9)) -> dict[str, float]:
        n = min(self._n_recent, len(self._recent))
        if n == 0:
            return {f"p{q:g}": float("nan") for q in qs}
        return {f"p{q:g}": v for q, v in zip(qs, percentiles(self._recent[:n], qs), strict=True)}

    def summary(self) -> dict[str, object]:
        edges = LATENESS_EDGES_US
        hist = {
            f"{edges[i]:g}-{edges[i + 1]:g}us": int(c) for i, c in enumerate(self.histogram) if c
        }
        return {
            "cycles": self.cycles,
            "overruns": self.overruns,
            "skipped_deadlines": self.skipped,
            "lateness_max_us": round(self.max_us, 1),
            **{f"lateness_{k}_us": round(v, 1) for k, v in self.percentiles_us().items()},
            "lateness_histogram": hist,
        }


class Ticker:
    """Yields cycle deadlines at ``period_s`` on ``time.monotonic``.

    ``wait()`` sleeps until the next deadline (sleep, then a short spin for precision) and returns
    ``(deadline, lateness_s)``; ``done()`` marks the end of the cycle's work for overrun counting.
    """

    def __init__(self, period_s: float, spin: bool = True, spin_margin_s: float | None = None):
        if period_s <= 0:
            raise ValueError("period_s must be positive")
        self.period_s = period_s
        self.spin = spin
        #: Sleep until this long before the deadline, then spin (s); by default chosen for the
        #: scheduling policy of the thread that creates the ticker.
        self.spin_margin_s = (
            spin_margin_s
            if spin_margin_s is not None
            else (SPIN_MARGIN_RT_S if realtime_thread() else SPIN_MARGIN_S)
        )
        self.stats = LatenessStats()
        self._t0 = time.monotonic()
        self._n = 0

    @property
    def next_deadline(self) -> float:
        return self._t0 + self._n * self.period_s

    def now(self) -> float:
        """The clock's time (s, ``time.monotonic``)."""
        return time.monotonic()

    def wait(self) -> tuple[float, float]:
        deadline = self.next_deadline
        while True:
            now = time.monotonic()
            remaining = deadline - now
            if remaining <= 0:
                break
            margin = self.spin_margin_s if self.spin else 0.0
            if remaining > margin:
                time.sleep(remaining - margin)
                if not self.spin:
                    now = time.monotonic()
                    break
        now = time.monotonic()
        lateness = max(now - deadline, 0.0)
        self.stats.add(lateness)
        return deadline, lateness

    def reset_stats(self) -> LatenessStats:
        """Start the statistics afresh (e.g. after start-up); returns the old ones."""
        old, self.stats = self.stats, LatenessStats()
        return old

    def done(self) -> None:
        """End of one cycle's work: schedule the next deadline, skipping any already missed."""
        self._n += 1
        now = time.monotonic()
        if now > self.next_deadline:
            self.stats.overruns += 1
            missed = int((now - self.next_deadline) // self.period_s)
            if missed > 0:
                self.stats.skipped += missed
                self._n += missed


#: :class:`BetweenCycles` ends this long before the loop's sleep ends (s): room for another
#: thread's unit of work (one CAN frame formatted for the traffic log, 30-60 us measured on this
#: machine, README) to finish before the loop wants the interpreter lock back.
QUIET_GUARD_S = 150e-6
#: A loop that has not ended a cycle for this long (s) is not running: between cycles.
QUIET_STALE_S = 0.1


class BetweenCycles:
    """Whether the control loop is between its cycles (issue #21): after a cycle's work ended
    and until :data:`QUIET_GUARD_S` before the loop's next wake-up (the deadline less the
    ticker's spin margin), on ``time.monotonic``. A thread of the loop's process whose work can
    wait (the CAN traffic log's writer) calls it to take the interpreter lock only then. True
    before the loop's first cycle, after its last, and when it ended no cycle for
    :data:`QUIET_STALE_S`."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._until = -math.inf
        self._clock = clock

    def mark(self, next_deadline_s: float, spin_margin_s: float) -> None:
        """(The loop thread, after a cycle's work.) Quiet until its next wake-up less the guard."""
        self._until = next_deadline_s - spin_margin_s - QUIET_GUARD_S

    def clear(self) -> None:
        """(The loop thread, when it stops.) Quiet from now on."""
        self._until = -math.inf

    def __call__(self) -> bool:
        until = self._until
        now = self._clock()
        return now < until or now > until + QUIET_STALE_S


def timer_floor(
    period_s: float,
    until: Callable[[], bool],
    max_cycles: int,
    deadlines_out: np.ndarray | None = None,
) -> np.ndarray:
    """The machine's floor (issue #21): a bare loop on a :class:`Ticker` of ``period_s`` (the
    control loop's clock, sleep and spin method) doing no work, until ``until()`` is true or
    ``max_cycles`` ran. Returns each cycle's lateness (s) counted as the control loop's rows
    count it: from its deadline, plus one period per deadline skipped before it. Run it in a
    process of its own (scheduled as the daemon is) while the loop runs: whatever lateness it
    shows, the machine (its load, its timer, the scheduler) causes, not the control plane.
    ``deadlines_out`` (optional, at least ``max_cycles`` long): each cycle's deadline
    (``time.monotonic``, s) is stored there, to line the floor's late cycles up with the loop's."""
    ticker = Ticker(period_s)
    out = np.empty(max_cycles)
    skipped_before = 0
    n = 0
    while n < max_cycles and not until():
        deadline, lateness = ticker.wait()
        out[n] = lateness + skipped_before * period_s
        if deadlines_out is not None:
            deadlines_out[n] = deadline
        n += 1
        skipped = ticker.stats.skipped
        ticker.done()
        skipped_before = ticker.stats.skipped - skipped
    return out[:n]


def raise_loop_priority() -> str | None:
    """(In the loop thread.) Under SCHED_FIFO/SCHED_RR, one priority step above the process's
    other threads (which inherited :func:`try_realtime`'s): a socket or sensor thread of the
    same policy then never keeps the loop's core from it. Returns a log line, None under
    SCHED_OTHER (nothing to raise)."""
    if not realtime_thread():
        return None
    try:
        policy = os.sched_getscheduler(0)
        prio = min(os.sched_getparam(0).sched_priority + 1, os.sched_get_priority_max(policy))
        os.sched_setscheduler(0, policy, os.sched_param(prio))
    except OSError as exc:
        return f"loop thread priority not raised ({exc.strerror})"
    return f"loop thread at real-time priority {prio}"


def try_realtime(priority: int, lock_memory: bool) -> list[str]:
    """Ask for SCHED_FIFO at ``priority`` and mlockall; return log lines saying what was granted."""
    notes = []
    if priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            notes.append(f"SCHED_FIFO priority {priority}")
        except (PermissionError, OSError) as exc:
            notes.append(
                f"SCHED_FIFO {priority} not permitted ({exc.strerror}); running SCHED_OTHER"
            )
    if lock_memory:
        libc_name = ctypes.util.find_library("c")
        ok = False
        if libc_name:
            with contextlib.suppress(OSError, AttributeError):
                libc = ctypes.CDLL(libc_name, use_errno=True)
                MCL_CURRENT, MCL_FUTURE = 1, 2
                ok = libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0
        notes.append("mlockall done" if ok else "mlockall not permitted; memory may page")
    for line in notes:
        log.info("realtime: %s", line)
    return notes
