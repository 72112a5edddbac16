"""The CAN traffic log written off the send and receive paths (issue #21).

Formatting a frame for a python-can writer (ASC text, the run's MCAP channel) costs tens of
microseconds of interpreter time; at 1 kHz the group sends and receives about seven frames a
cycle, and it did that on the control loop's thread (sent frames) and the bus listener's
(received frames), under one lock the two shared. Measured with the run log on at 1 kHz
(README, "The control plane cannot stall the loop"): the traffic log made the loop's long
cycles 5-8x as many. Here the hot paths only append the frame to a queue (``deque.append``:
atomic, no lock); a thread of its own writes the queue to the listener every
:data:`DRAIN_PERIOD_S`, in arrival order.

That thread still takes the interpreter lock for its formatting, and every time the loop lets
the lock go inside its cycle (each frame written to the adapter) it waited to get it back (a
second pass of issue #21 measured the traffic log's thread at 5% of a core and the loop's long
cycles 15 -> 40 per 8 s with it on). Given ``quiet`` (a predicate, the control loop's "between
my cycles"), the thread writes only while it holds, a frame at a time, and otherwise waits
:data:`QUIET_POLL_S`; past :data:`BACKLOG_FRAMES` queued frames it writes regardless, so the log
never falls behind without bound.

A ``tap`` (the run log's ``/can`` channel: a ring into the run-log writer process) gets the
frames a batch at a time (issue #23): while quiet holds the thread takes up to
:data:`TAP_BATCH_FRAMES` queued frames, hands them to the tap in one call (its
``on_messages(frames)`` if it has one: one lock and one store for the batch, instead of a call
per frame) and then writes them to ``listener`` one at a time, as before.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable

import can

log = logging.getLogger("cdcr_ctl.drives.group")

#: How often the writer thread drains the queue (s): the traffic log lags the bus by at most
#: this (plus one drain's work).
DRAIN_PERIOD_S = 0.02
#: While ``quiet`` says no, look again this often (s): a fraction of a 1 kHz loop's period.
QUIET_POLL_S = 0.0002
#: Queued frames past which the writer ignores ``quiet`` (about 0.6 s of a 1 kHz group's traffic).
BACKLOG_FRAMES = 4096
#: Frames handed to the tap in one call (8 ms of a 1 kHz group's traffic; ~40 us of work).
TAP_BATCH_FRAMES = 64


class DeferredTrafficLog(can.Listener):
    """``on_message_received`` queues; a thread hands the frames to ``listener`` (and to
    ``tap``, a batch at a time) in order.

    A write error (``OSError``/``ValueError``: disk full, file gone) stops the log and is passed
    to ``on_failure(text)``; it never reaches the sender. :meth:`stop` writes what is queued,
    then stops the listener and the tap. ``quiet``: when the thread may take the interpreter
    lock (see the module docstring); None: whenever it has frames. The tap may be ahead of the
    listener by up to a batch (a listener's write error stops both there).
    """

    def __init__(
        self,
        listener: can.Listener,
        on_failure: Callable[[str], None],
        quiet: Callable[[], bool] | None = None,
        tap: can.Listener | None = None,
    ) -> None:
        self.listener = listener
        self.tap = tap
        self._on_failure = on_failure
        self._quiet = quiet
        self._queue: deque[can.Message] = deque()
        #: Frames taken from the queue and handed to the tap, not yet to the listener.
        self._pending: deque[can.Message] = deque()
        self._write_lock = threading.Lock()
        self._stopped = threading.Event()
        self._failed = False
        self._thread = threading.Thread(target=self._run, name="can-traffic-log", daemon=True)
        self._thread.start()

    @property
    def failed(self) -> bool:
        """Whether a write failed (the log stopped)."""
        return self._failed

    def on_message_received(self, msg: can.Message) -> None:
        if not self._failed:
            self._queue.append(msg)

    def _run(self) -> None:
        while not self._stopped.wait(DRAIN_PERIOD_S):
            self.drain(self._quiet)

    def drain(self, quiet: Callable[[], bool] | None = None) -> None:
        """Write every queued frame (the writer thread; :meth:`stop`), while ``quiet()`` holds
        or more than :data:`BACKLOG_FRAMES` wait; the thread returns early once stopped
        (:meth:`stop` writes the rest)."""
        with self._write_lock:
            q = self._queue
            pending = q if self.tap is None else self._pending
            try:
                while (q or pending) and not self._failed:
                    backlog = len(q) + len(pending) if pending is not q else len(q)
                    if quiet is not None and backlog < BACKLOG_FRAMES and not quiet():
                        if self._stopped.is_set():
                            return
                        time.sleep(QUIET_POLL_S)
                        continue
                    if not pending:
                        self._to_tap(q, pending)
                    self.listener.on_message_received(pending.popleft())
            except (OSError, ValueError) as exc:
                self._failed = True
                q.clear()
                self._pending.clear()
                for listener in (self.listener, self.tap):
                    if listener is not None:
                        with contextlib.suppress(Exception):
                            listener.stop()
                log.error("CAN traffic log stopped: %s", exc)
                self._on_failure(f"CAN traffic log: {exc}")

    def _to_tap(self, q: deque[can.Message], pending: deque[can.Message]) -> None:
        """Up to :data:`TAP_BATCH_FRAMES` queued frames to the tap in one call, and on to
        ``pending`` for the listener."""
        batch = [q.popleft() for _ in range(min(len(q), TAP_BATCH_FRAMES))]
        pending.extend(batch)
        many = getattr(self.tap, "on_messages", None)
        if many is not None:
            many(batch)
        else:
            for msg in batch:
                self.tap.on_message_received(msg)

    def stop(self) -> None:
        self._stopped.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(5.0)
        self.drain()
        if not self._failed:
            try:
                self.listener.stop()
            finally:
                if self.tap is not None:
                    self.tap.stop()


__all__ = [
    "BACKLOG_FRAMES",
    "DRAIN_PERIOD_S",
    "QUIET_POLL_S",
    "TAP_BATCH_FRAMES",
    "DeferredTrafficLog",
]
