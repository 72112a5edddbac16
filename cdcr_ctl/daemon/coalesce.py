"""Requests that share one round trip: the front process's ``status`` coalescing
(:mod:`cdcr_ctl.daemon.front`): however many clients ask at once, at most one round trip to the
rig process is in flight, and every answer was fetched after its caller asked."""

from __future__ import annotations

import threading
from typing import Any


class _Batch:
    """One status round trip shared by the requests that joined it."""

    __slots__ = ("done", "error", "value")

    def __init__(self) -> None:
        self.done = threading.Event()
        self.value: Any = None
        self.error: BaseException | None = None

    def result(self) -> Any:
        self.done.wait()
        if self.error is not None:
            raise self.error
        return self.value


class Coalescer:
    """At most one ``fetch()`` in flight; callers that arrive while one runs share the next one,
    which starts when it ends (so every answer was fetched after its caller asked)."""

    def __init__(self, fetch: Any) -> None:
        self._fetch = fetch
        self._lock = threading.Lock()
        self._running: _Batch | None = None
        self._next: _Batch | None = None
        #: Round trips made, and calls (a flood of calls costs few round trips).
        self.fetches = 0
        self.calls = 0
        #: Callers inside :meth:`get` now.
        self.waiting = 0

    def get(self) -> Any:
        with self._lock:
            self.calls += 1
            self.waiting += 1
        try:
            return self._get()
        finally:
            with self._lock:
                self.waiting -= 1

    def _get(self) -> Any:
        prev: _Batch | None = None
        with self._lock:
            if self._next is not None:
                return_batch = self._next
                lead = False
            elif self._running is None:
                return_batch = self._running = _Batch()
                lead = True
            else:
                prev = self._running
                return_batch = self._next = _Batch()
                lead = True
        batch = return_batch
        if not lead:
            return batch.result()
        if prev is not None:
            prev.done.wait()
            with self._lock:
                self._running, self._next = batch, None
        try:
            self.fetches += 1
            batch.value = self._fetch()
        except BaseException as exc:
            batch.error = exc
        finally:
            with self._lock:
                if self._running is batch:
                    self._running = None
            batch.done.set()
        return batch.result()


__all__ = ["Coalescer"]
