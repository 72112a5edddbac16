"""Rows handed to the shared ring between the loop's cycles (issue #23, the log stage's mean).

The process writer's ring store (:meth:`~cdcr_ctl.runlog.writer.process.ProcessRunLogWriter`'s
store: one packed store of the row's head, one memoryview copy of its numbers, the head counter)
costs 0.75 us a row with warm caches, but 4.0-4.9 us in the 1 kHz loop's log stage, where the loop
comes back from its sleep with cold caches: measured with the log stage split by
``time.perf_counter`` marks in the loop (``git show 4f9c215:benchmarks/bench_runlog_split.py``;
README, "Run logs"). The same store into one slot that never leaves the cache cost the same (3.8-3.9
us), so the cost is the interpreter's cold path, not the ring's memory; with the writer process
stopped (SIGSTOP) or the CAN traffic log off the stage was no faster. The old thread writer's
``deque.append`` costs 0.7-0.8 us there: that difference was the log stage's regression.

So in real time the loop's ``write`` only appends the row to a deque (as the thread writer
did), and :class:`RowHandoff`'s thread stores the rows into the ring while the loop is between
cycles (``quiet``, the loop's :class:`~cdcr_ctl.control.timing.BetweenCycles`, as the CAN
traffic log's writer does), every :data:`FEED_PERIOD_S`. It runs at the loop thread's
scheduling policy and priority (taken from the loop thread when it hands over its first row):
a thread holding the interpreter lock and preempted by ordinary work would make a real-time
loop wait for the lock.

A loop that is never between cycles (late cycle after late cycle on an overloaded machine)
would keep the rows in the deque: past ``backlog_rows`` queued rows the thread stores them
whatever ``quiet`` says (as the traffic log does past its backlog), so they neither wait for a
quiet moment without bound nor fill the ring unseen.

Crash safety: rows in the deque are lost if the loop's process is killed (SIGKILL): normally at
most :data:`FEED_PERIOD_S` plus a cycle of rows (~11 ms at 1 kHz), and never more than
``backlog_rows`` (the writer sets it to half ``fsync_every_s`` of rows), inside the issue's rule
of no more than ``fsync_every_s`` (0.5 s by default) of samples missing. Rows in the ring survive as
before (the writer process drains them). A loop on simulated time (``on_full="wait"``) and a
writer given no ``quiet`` store on the caller's thread, as before.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

log = logging.getLogger("cdcr_ctl.runlog.writer")

#: How often the handoff thread moves the rows handed over into the ring (s). Rows wait that long
#: in the loop's process (lost on a SIGKILL of it), and the writer process drains the ring every
#: ``drain_interval_s`` (50 ms) anyway.
FEED_PERIOD_S = 0.01
#: While ``quiet`` says no (the loop is in a cycle), look again this often (s).
QUIET_POLL_S = 0.0002


class RowHandoff:
    """Rows from the loop thread (:meth:`put`: a ``deque.append``) into the ring by ``store(row)``
    (False: the row was refused and is not counted as stored) on a thread of its own, while
    ``quiet()`` holds (or more than ``backlog_rows`` wait), then calls ``tick()`` (the writer's
    check of its process's failure flag, off the loop's path). :meth:`finish` stores what is
    queued, then calls ``then()`` once (the close request) and ends the thread."""

    def __init__(
        self,
        store: Callable[[Any], bool],
        quiet: Callable[[], bool],
        tick: Callable[[], None] | None = None,
        backlog_rows: int = 250,
        name: str = "run-log-handoff",
    ) -> None:
        self._store = store
        self._backlog = max(1, int(backlog_rows))
        self._quiet = quiet
        self._tick = tick
        self._queue: deque[Any] = deque()
        #: The loop's ``write`` calls this (bound once: a plain ``deque.append``).
        self.put = self._queue.append
        self._wake = threading.Event()
        self._then: Callable[[], None] | None = None
        self._finishing = False
        self._called = False
        #: The scheduling (policy, parameters) of the thread that hands rows over (set by
        #: :meth:`adopt`), which this thread takes before it stores any row.
        self._source: tuple[int, Any] | None = None
        self._adopted = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def adopt(self) -> None:
        """(The loop thread, once: two system calls.) The handoff thread takes the calling
        thread's scheduling policy and priority."""
        with contextlib.suppress(OSError, AttributeError):
            self._source = (os.sched_getscheduler(0), os.sched_getparam(0))

    def queued(self) -> int:
        """Rows handed over and not yet stored."""
        return len(self._queue)

    def finish(self, then: Callable[[], None]) -> None:
        """Store what is queued, then call ``then()`` (from the handoff thread) and end; if that
        thread has ended already, call ``then()`` here."""
        self._then = then
        self._finishing = True
        self._wake.set()
        if not self._thread.is_alive() and not self._called:
            self._called = True
            then()

    def join(self, timeout_s: float | None = None) -> None:
        self._thread.join(timeout_s)

    def _take_scheduling(self) -> None:
        """Run at the loop thread's policy and priority (Linux: ``sched_setscheduler(0)`` sets
        the calling thread's). Without the right to (not root, no CAP_SYS_NICE, no
        RLIMIT_RTPRIO), this thread stays as it is and says so once."""
        self._adopted = True
        if self._source is None:
            return
        policy, param = self._source
        try:
            if (policy, param.sched_priority) != (os.sched_getscheduler(0), 0):
                os.sched_setscheduler(0, policy, param)
        except OSError as exc:
            log.warning(
                "run-log handoff thread keeps its scheduling (cannot take the loop's: %s)", exc
            )

    def _run(self) -> None:
        try:
            while not (self._finishing and not self._queue):
                self._wake.wait(FEED_PERIOD_S)
                if not self._adopted and self._source is not None:
                    self._take_scheduling()
                self._feed()
                if self._tick is not None:
                    try:
                        self._tick()
                    except Exception:
                        log.exception("run-log handoff: the writer's check failed")
        finally:
            then = self._then
            if then is not None and not self._called:
                self._called = True
                with contextlib.suppress(Exception):
                    then()

    def _feed(self) -> None:
        """Store every queued row, one at a time while ``quiet()`` holds or the backlog is
        reached."""
        q, quiet, store, backlog = self._queue, self._quiet, self._store, self._backlog
        while q:
            if len(q) < backlog and not quiet():
                time.sleep(QUIET_POLL_S)
                continue
            try:
                store(q.popleft())
            except Exception:  # the store counts what it refuses; never let the thread die
                log.exception("run-log handoff: a row could not be stored")
