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


class DeferredTrafficLog(can.Listener):
    """``on_message_received`` queues; a thread hands the frames to ``listener`` in order.

    A write error (``OSError``/``ValueError``: disk full, file gone) stops the log and is passed
    to ``on_failure(text)``; it never reaches the sender. :meth:`stop` writes what is queued,
    then stops the listener. ``quiet``: when the thread may take the interpreter lock (see the
    module docstring); None: whenever it has frames.
    """

    def __init__(
        self,
        listener: can.Listener,
        on_failure: Callable[[str], None],
        quiet: Callable[[], bool] | None = None,
    ) -> None:
        self.listener = listener
        self._on_failure = on_failure
        self._quiet = quiet
        self._queue: deque[can.Message] = deque()
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
            try:
                while q and not self._failed:
                    if quiet is not None and len(q) < BACKLOG_FRAMES and not quiet():
                        if self._stopped.is_set():
                            return
                        time.sleep(QUIET_POLL_S)
                        continue
                    self.listener.on_message_received(q.popleft())
            except (OSError, ValueError) as exc:
                self._failed = True
                q.clear()
                with contextlib.suppress(Exception):
                    self.listener.stop()
                log.error("CAN traffic log stopped: %s", exc)
                self._on_failure(f"CAN traffic log: {exc}")

    def stop(self) -> None:
        self._stopped.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(5.0)
        self.drain()
        if not self._failed:
            self.listener.stop()


__all__ = ["BACKLOG_FRAMES", "DRAIN_PERIOD_S", "QUIET_POLL_S", "DeferredTrafficLog"]
