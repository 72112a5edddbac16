"""A sensor reader that runs its ``poll()`` back to back in a daemon thread.

Each reader (tracker, attitude sensor, joystick) implements :meth:`PollingReader.poll`: one unit of
I/O with a bounded wait that publishes what it decoded, and raises
:class:`~cdcr_ctl.errors.SensorError` when the transport fails. The thread stops on that error and
keeps it in :attr:`PollingReader.failure`; the control loop never calls ``poll`` itself, it reads
the published values (``latest()``) and checks ``failure``.
"""

from __future__ import annotations

import logging
import threading
from typing import Self

from cdcr_ctl.errors import SensorError

log = logging.getLogger(__name__)

#: Longest wait for a reader thread to finish its current poll and stop (s).
JOIN_TIMEOUT_S = 2.0


class PollingReader:
    """Base class: ``start()`` runs ``poll()`` in a daemon thread until ``stop()`` or a failure.

    Subclasses set ``port_name`` (named in every error), implement :meth:`poll` (bounded wait,
    typically <= 50 ms, so ``stop()`` is prompt) and :meth:`_close_transport`.
    """

    port_name: str = "?"

    def __init__(self) -> None:
        self._stop_event = threading.Event()
        self._thread: threading.Thread | None = None
        #: Why the reader stopped (transport failed, reader crashed); None while healthy.
        self.failure: SensorError | None = None

    # -- to implement -----------------------------------------------------------------------

    def poll(self) -> None:
        """One unit of I/O (bounded wait); publish what arrived. Raise SensorError on failure."""
        raise NotImplementedError

    def _close_transport(self) -> None:
        """Close the socket / port / device (idempotent, must not raise)."""

    def _on_failure(self, exc: SensorError) -> None:
        """Called in the thread when it stops on ``exc`` (e.g. flag values stale)."""

    # -- life cycle -------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """True while the reader thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> Self:
        """Start the reader thread (idempotent); returns self."""
        if self._thread is None:
            self._stop_event.clear()
            self._thread = threading.Thread(target=self._run, name=self.port_name, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread after its current poll; the transport stays open."""
        self._stop_event.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(JOIN_TIMEOUT_S)
            if thread.is_alive():
                log.warning("%s: thread did not stop in %s s", self.port_name, JOIN_TIMEOUT_S)

    def close(self) -> None:
        """Stop the thread and close the transport (idempotent)."""
        self.stop()
        self._close_transport()

    def raise_if_failed(self) -> None:
        """Raise :attr:`failure` if the reader has one."""
        if self.failure is not None:
            raise self.failure

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run(self) -> None:
        try:
            while not self._stop_event.is_set():
                self.poll()
        except SensorError as exc:
            if not self._stop_event.is_set():
                self._fail(exc)
        except Exception as exc:  # a bug must not die silently in a daemon thread
            if not self._stop_event.is_set():
                err = SensorError(self.port_name, f"reader crashed: {exc!r}")
                err.__cause__ = exc
                log.exception("%s: reader crashed", self.port_name)
                self._fail(err)

    def _fail(self, exc: SensorError) -> None:
        self.failure = exc
        log.error("%s", exc)
        self._on_failure(exc)
