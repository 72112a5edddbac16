"""The run-log writer in a process of its own: the loop's process only copies numbers.

:class:`ProcessRunLogWriter` has the interface of
:class:`~cdcr_ctl.runlog.writer.thread.RunLogWriter`. Its :meth:`~ProcessRunLogWriter.write`
stores the row's numbers into a slot of a shared-memory ring (:mod:`cdcr_ctl.runlog.writer.ring`)
and returns; a writer process (:mod:`cdcr_ctl.runlog.writer.child`; SCHED_BATCH, or SCHED_FIFO 1
under a real-time loop: ``spawn.hand_over``) drains the ring into an ordinary ``RunLogWriter``
(CSV and MCAP encoding, fsyncs, ``run.yaml``) under its own interpreter lock. A write error there
is published in the shared header; :attr:`failure` reads it (one int64 load when there is none).

- The ring is sized by time (``logging.ring_s`` of rows at the loop's rate, see
  :class:`~cdcr_ctl.runlog.writer.factory.RunLogFactory`). When it is full, ``on_full`` decides:
  ``trip`` (real time, the default) refuses the row (``write`` returns False, counted as dropped)
  and sets :attr:`~ProcessRunLogWriter.overflow`, on which the loop trips ``log_overflow``
  (quick stop; the rows in the ring are still written and the run closed, its reason naming the
  overflow); ``wait`` (a loop on simulated time, lock-step) blocks ``write`` until the writer
  process has made room, so no row is lost whatever the load and the files are the same on
  every run; its writer drains it only once half full or at the close (``spawn.defer_fill``).
- The writer process exiting without closing the run (a crash) is also a failure. If the loop's
  process dies (SIGKILL), the writer process sees its parent change, drains the ring and closes
  the run with outcome ``aborted`` (``run.mcap`` ends with its summary and footer).
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import pickle
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.columns import TEXT_COLUMNS
from cdcr_ctl.runlog.writer.files import LogStats, RunMetadata, WriterBase, utc_now_iso
from cdcr_ctl.runlog.writer.handoff import RowHandoff
from cdcr_ctl.runlog.writer.ring import (
    CLOSE,
    DONE,
    FAILED,
    ROW_DROPPED,
    ROW_HEAD,
    ROW_TAIL,
    ROW_WAITS,
    W_HIGH,
    W_START,
    RingLayout,
    SharedRing,
    writer_counts,
)
from cdcr_ctl.runlog.writer.slots import SlotFiller
from cdcr_ctl.runlog.writer.spawn import (
    RingCanTap,
    defer_fill,
    hand_over,
    start_writer_process,
    wait_exit,
)
from cdcr_ctl.runlog.writer.thread import (
    CLOSE_TIMEOUT_S,
    DEFAULT_QUEUE_ROWS,
    DRAIN_INTERVAL_S,
    RunLogWriter,
    check_settings,
)

log = logging.getLogger("cdcr_ctl.runlog.writer")

#: CAN frames the ring holds: 5 s at 10 000 frames/s (a 1 kHz loop with 3 drives sends and
#: receives about 8 a cycle).
DEFAULT_CAN_FRAMES = 50_000
#: Rows between two checks that the writer process still runs (a ``waitpid`` each).
ALIVE_EVERY_ROWS = 256
#: What a full ring does to a row (see :meth:`ProcessRunLogWriter._room`): ``trip`` refuses it
#: and records :attr:`~ProcessRunLogWriter.overflow` (real time: the loop must never wait), or
#: ``wait`` blocks the loop until the writer process has made room (simulated time: no row
#: lost, the same files whatever the load).
ON_FULL = ("trip", "wait")
#: Poll period of a loop waiting for room (s); polls between two checks the writer still runs.
WAIT_POLL_S = 0.001
WAIT_ALIVE_EVERY = 100

#: Writers whose process has not been waited for (held until then; see :func:`_close_open`).
_OPEN: set[ProcessRunLogWriter] = set()


@atexit.register
def _close_open() -> None:
    """An interpreter exit closes any run log left open (outcome ``aborted``)."""
    for writer in list(_OPEN):
        writer.close("process exit with the log still open", outcome="aborted")


class ProcessRunLogWriter(WriterBase):
    """Writes one run directory through a writer process; a context manager, or call
    :meth:`close`. Arguments as :class:`~cdcr_ctl.runlog.writer.thread.RunLogWriter`
    (``second_sink`` must pickle). ``process``: a spare from :func:`start_writer_process`
    (started ahead; the factory keeps one ready), else one is started here. ``run_dir`` must be
    empty or not exist. The constructor makes the run's first files (config copies, ``run.yaml``,
    ``samples.csv``'s header); raises :class:`RigError` naming the path if they cannot be made,
    the directory is not empty, or the writer process cannot start. It does not wait for the
    writer process (an error there is a :attr:`failure`, which trips the loop). ``quiet`` (the
    loop's "between my cycles", with ``on_full="trip"``): rows go through a
    :class:`~cdcr_ctl.runlog.writer.handoff.RowHandoff`, ``write`` only queues them."""

    def __init__(
        self,
        run_dir: str | Path,
        columns: Sequence[str],
        metadata: RunMetadata,
        *,
        config_text: str | None = None,
        config_source: str = "",
        extra_files: Mapping[str, str] | None = None,
        fsync_every_s: float = 0.5,
        max_queued_rows: int = DEFAULT_QUEUE_ROWS,
        on_failure: Callable[[str], None] | None = None,
        drain_interval_s: float = DRAIN_INTERVAL_S,
        second_sink: Any = None,
        can_frames: int = DEFAULT_CAN_FRAMES,
        process: subprocess.Popen | None = None,
        on_full: str = "trip",
        quiet: Callable[[], bool] | None = None,
    ) -> None:
        cols = check_settings(columns, fsync_every_s, max_queued_rows, drain_interval_s, on_full)
        self.on_full = on_full
        self._overflow: str | None = None
        self.run_dir = Path(run_dir)
        self.columns = cols
        self.metadata = metadata
        self.samples_path = self.run_dir / "samples.csv"
        self.fsync_every_s = float(fsync_every_s)
        self.max_queued_rows = int(max_queued_rows)
        self._on_failure = on_failure
        self._tail = 0
        #: ``write`` takes its fast path while its head is below this: the writer process's
        #: tail (as last read) + the ring's size; -1 once closing or failed.
        self._limit = 0
        self._warned = False
        self._dropped = 0
        self._head = 0
        #: Rows stored into the ring (the ring's head) and rows handed over that the handoff
        #: thread could not store (counted dropped).
        self._fed = 0
        self._skipped = 0
        self._handoff: RowHandoff | None = None
        self._closing = False
        self._failure: str | None = None
        self._notified = False
        self._exit_checked = False
        #: Called once when the log is asked to close, or None (spawn.defer_fill's spare).
        self.on_close: Callable[[], None] | None = None

        num_cols = [c for c in self.columns if c not in TEXT_COLUMNS]
        layout = RingLayout(len(num_cols), self.max_queued_rows, can_frames)
        try:
            self._ring = SharedRing.create(layout)
        except OSError as exc:
            raise RigError(f"{self.run_dir}: cannot make the run log's ring: {exc}") from exc
        self._cap = layout.rows
        self._hq = self._ring.hq
        self._fill = SlotFiller(self._ring, self.columns, self.samples_path).fill
        spec = {
            "run_dir": str(self.run_dir),
            "columns": self.columns,
            "metadata": metadata,
            "config_text": config_text,
            "config_source": config_source,
            "extra_files": dict(extra_files or {}),
            "fsync_every_s": self.fsync_every_s,
            "drain_interval_s": float(drain_interval_s),
            "defer_fill": defer_fill(on_full),
            "second_sink": second_sink,
            "layout": layout,
            "fd": self._ring.fd,
            "parent_pid": os.getpid(),
            "files_made": True,
        }
        try:
            blob = pickle.dumps(spec)
        except Exception as exc:
            self._ring.close()
            raise RigError(f"{self.run_dir}: the run log's settings do not pickle: {exc}") from exc
        try:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            if any(self.run_dir.iterdir()):
                raise RigError(f"{self.run_dir}: run directory is not empty")
            # The run's first files here, as the thread writer makes them (a few ms): the run
            # directory is whole from the run's start (readers, a SIGKILL before the writer
            # process is going), whatever CPU the writer process gets on a loaded machine.
            RunLogWriter.make_start_files(
                self.run_dir,
                self.columns,
                metadata,
                config_text=config_text,
                config_source=config_source,
                extra_files=extra_files,
                fsync_every_s=self.fsync_every_s,
            )
        except OSError as exc:
            self._ring.close()
            raise RigError(f"{self.run_dir}: cannot start the run log: {exc}") from exc
        except RigError:
            self._ring.close()
            raise
        # Never wait here for the writer process to take the run over: it runs off real time
        # (SCHED_BATCH), so on a loaded machine its start (run.mcap, the first drain) can take
        # a second or more, even from a spare with its imports done; a run's start (the
        # command thread, a joystick already streaming) must not wait for that. Rows wait in
        # the ring; an error there is published as the log's failure and trips the loop (as a
        # write error does). The files the daemon makes itself were made above and raise here.
        self._proc = self._start(blob, process)
        self.can_tap = RingCanTap(self._ring) if second_sink is not None else None
        if quiet is not None and on_full != "wait":
            # At most half fsync_every_s of rows wait in this process (lost on its SIGKILL).
            rate = metadata.rate_hz or 1000.0
            backlog = min(self._cap // 2, int(0.5 * self.fsync_every_s * rate))
            self._handoff = RowHandoff(self._store_handed, quiet, self._poll_failure, backlog)
            self._put = self._handoff.put
        _OPEN.add(self)

    def _start(self, blob: bytes, proc: subprocess.Popen | None) -> subprocess.Popen:
        """Hand the settings to ``proc`` (a spare from :func:`start_writer_process`, started
        ahead) or to a writer process started now."""
        try:
            if proc is None or proc.poll() is not None:
                proc = start_writer_process(self._ring.fd, self.on_full)
                blob = pickle.dumps({**pickle.loads(blob), "fd_inherited": True})
        except OSError as exc:
            self._ring.close()
            raise RigError(f"{self.run_dir}: cannot start the run-log writer: {exc}") from exc
        try:
            # The pipe stays open: the close request writes a byte to it to wake the writer
            # process at once (:meth:`_request_close`).
            self.writer_policy = hand_over(proc, blob, self.on_full)
        except OSError as exc:
            proc.kill()
            proc.wait()
            self._ring.close()
            raise RigError(f"{self.run_dir}: cannot start the run-log writer: {exc}") from exc
        return proc

    # ------------------------------------------------------------------ real-time side
    def write(self, row: Any) -> bool:
        """Copy one row's numbers into the ring; never raises, never blocks unless
        ``on_full="wait"`` and the ring is full (see :meth:`_room`). False: dropped.

        ``row``: a mapping column -> value, a sequence in column order, or an object with
        ``row_parts()`` -> (names of the values, float64 values, ``t_s``, ``cycle``,
        lateness (s), ``event``) such as the loop's ``CycleRow`` (the names tuple is the
        same object from row to row; its column positions are looked up once; ``t_s`` and the
        lateness go unrounded, the writer process rounds them). Such a row costs one packed
        store of its head and one memoryview copy of its array (no numpy call, no rounding,
        no allocation here); numbers go as
        float64 (``cycle`` comes back as an integer), None and NaN
        as empty; the ``event`` column as text (cut at the ring's
        :data:`~cdcr_ctl.runlog.writer.ring.EVENT_BYTES`). Call from one thread. With a
        handoff (``quiet``), the row is queued (its numbers must not change afterwards: the
        loop's ``CycleRow`` keeps a fresh array) and stored between the loop's cycles.
        """
        head = self._head
        if head >= self._limit and not self._make_room(head):
            return False
        if self._handoff is not None:
            if not head:  # the first row: the handoff thread takes this thread's scheduling
                self._handoff.adopt()
            self._put(row)
            self._head = head + 1
            return True
        if not self._store(row, head):
            return False
        self._head = head + 1  # rows taken so far (the ``queued`` count)
        return True

    def _store_handed(self, row: Any) -> bool:
        """The handoff thread: store a row handed over into the ring's next slot."""
        if self._ring is None:
            self._skipped += 1
            return False
        if self._store(row, self._fed):
            self._fed += 1
            return True
        self._skipped += 1
        return False

    def _store(self, row: Any, head: int) -> bool:
        """Store ``row`` into slot ``head`` and publish ``head + 1``; False (dropped, counted)
        if it cannot be taken."""
        ring = self._ring
        try:
            self._fill(row, head % self._cap)
        except Exception as exc:  # a row this writer cannot take: dropped, said once
            if not self._warned:
                self._warned = True
                log.warning("%s: a row could not be logged: %s", self.samples_path, exc)
            self._dropped += 1
            ring.hq[ROW_DROPPED] = self._dropped
            return False
        head += 1
        ring.hq[ROW_HEAD] = head
        if not head % ALIVE_EVERY_ROWS:
            self._check_alive()
        return True

    def _make_room(self, head: int) -> bool:
        """``write``'s slow path: False (the row dropped and counted) if the log is closing or
        failed, or the ring is full at ``head`` and :meth:`_room` finds no room."""
        ring = self._ring
        if ring is None or self._closing or self._failure is not None:
            self._limit = -1
            self._dropped += 1
            return False
        self._tail = ring.hq[ROW_TAIL]
        if head - self._skipped - self._tail >= self._cap and not self._room(head):
            self._dropped += 1
            ring.hq[ROW_DROPPED] = self._dropped
            return False
        self._limit = self._tail + self._cap + self._skipped
        return True

    def _room(self, head: int) -> bool:
        """The ring is full at ``head``. ``on_full="wait"`` (the loop on simulated time): wait
        until the writer process has taken rows (True), or until it failed or ended (False).
        ``on_full="trip"`` (real time): never wait; record :attr:`overflow` (False)."""
        if self.on_full != "wait":
            return self._trip_full("ring", self._cap, "writer process")
        ring = self._ring
        ring.hq[ROW_WAITS] += 1
        waited = 0
        while head - self._tail >= self._cap:
            if self.failure is not None:
                return False
            waited += 1
            if waited % WAIT_ALIVE_EVERY == 0:
                self._check_alive()
                if self._exit_checked:
                    return False
            time.sleep(WAIT_POLL_S)
            self._tail = ring.hq[ROW_TAIL]
        return True

    @property
    def high_water(self) -> int:
        """Most rows the ring held at one of the writer process's drains after its first
        (rows; the steady state)."""
        h = self._ring.hdr if self._ring is not None else self._final
        return int(h[W_HIGH])

    @property
    def start_backlog(self) -> int:
        """Rows the ring held at the writer process's first drain (its start: interpreter,
        imports unless it was a spare, the run's files)."""
        h = self._ring.hdr if self._ring is not None else self._final
        return int(h[W_START])

    @property
    def waits(self) -> int:
        """Rows the loop waited for room for (``on_full="wait"``)."""
        h = self._ring.hdr if self._ring is not None else self._final
        return int(h[ROW_WAITS])

    def _check_alive(self) -> None:
        if self._exit_checked or self._proc.poll() is None:
            return
        self._exit_checked = True
        if not self._ring.hdr[DONE] and self._failure is None:
            self._failure = (
                f"{self.samples_path}: the run-log writer process ended "
                f"(exit status {self._proc.returncode}) before the run was closed"
            )
            log.error("run log stopped: %s", self._failure)
            self._notify()

    def _notify(self) -> None:
        self._limit = -1  # failed: every later row takes the slow path and is refused
        if self._notified or self._on_failure is None:
            return
        self._notified = True
        try:
            self._on_failure(self._failure)
        except Exception:
            log.exception("run log on_failure callback raised")

    @property
    def failure(self) -> str | None:
        """Text of the write error that stopped this log (file and cause), or None. With a
        handoff its thread looks at the writer process's flag (:meth:`_poll_failure`, every
        feed); else this does (one int64 load on the loop's path)."""
        if self._failure is None and self._handoff is None and self._hq[FAILED]:
            self._poll_failure()
        return self._failure

    def _poll_failure(self) -> None:
        """Take the writer process's published failure, if any."""
        if self._failure is None and self._hq[FAILED]:
            text = self._ring.failure() if self._ring is not None else None
            if text is not None:
                self._failure = text
                self._notify()

    @property
    def error(self) -> BaseException | None:
        """The writer process's error as an OSError-like text holder (the exception itself
        stays in that process)."""
        return None if self.failure is None else OSError(self.failure)

    @property
    def closed(self) -> bool:
        """True once the writer process has finished (everything written, run.yaml updated)."""
        return self._proc.poll() is not None

    @property
    def stats(self) -> LogStats:
        h = self._ring.hdr if self._ring is not None else self._final
        written, dropped, lost, fsyncs, nbytes = writer_counts(h)
        return LogStats(
            self._head,
            written,
            self._dropped + dropped,
            lost + max(0, self._head - self._skipped - int(h[ROW_TAIL])) * self.closed,
            fsyncs,
            nbytes,
        )

    def close(self, reason: str, outcome: str | None = None, wait: bool = True) -> None:
        """End the run log: the writer process drains the ring, fsyncs and records
        ``outcome``/``reason`` in run.yaml. ``wait=False`` returns at once (use that from the
        loop); :meth:`wait_closed` waits. A second call changes nothing. Never raises."""
        if not self._closing:
            self._closing = True
            self._limit = -1
            if self.can_tap is not None:
                self.can_tap.detach()
            end = (str(reason), outcome or "closed", utc_now_iso())
            if self._handoff is not None:  # the rows handed over first, then the request
                self._handoff.finish(lambda: self._request_close(*end))
            else:
                self._request_close(*end)
            if self.on_close is not None:
                with contextlib.suppress(Exception):  # close never raises (then: no spare)
                    self.on_close()
                self.on_close = None
        if wait:
            self.wait_closed(CLOSE_TIMEOUT_S)

    def _request_close(self, reason: str, outcome: str, end_utc: str) -> None:
        """The close request into the ring, then a byte on the writer process's stdin, which
        wakes it now (:class:`~cdcr_ctl.runlog.writer.child.Wake`), not at its next drain."""
        ring = self._ring
        if ring is not None:
            ring.request_close(reason, outcome, end_utc)
        self._end_stdin(b"\x01")

    def _end_stdin(self, data: bytes = b"") -> None:
        """Write ``data`` to the writer process's stdin and close it (once; never raises)."""
        stdin = self._proc.stdin
        with contextlib.suppress(OSError, ValueError):  # the process gone, or closed already
            if stdin is not None and not stdin.closed:
                stdin.write(data)
                stdin.close()  # flushes first, closes even when that fails

    def wait_closed(self, timeout_s: float | None = None) -> bool:
        """Wait until the writer process has finished after :meth:`close`; False on timeout.
        Returns as the process ends (:func:`~cdcr_ctl.runlog.writer.spawn.wait_exit`)."""
        if not wait_exit(self._proc, timeout_s):
            return False
        self._release()
        return True

    def _release(self) -> None:
        ring = self._ring
        if ring is None:
            return
        self._check_alive_final()
        self._end_stdin()
        self._final = [int(v) for v in ring.hdr]
        self._limit = -1
        self._ring = None
        _OPEN.discard(self)
        ring.close()

    def _check_alive_final(self) -> None:
        if self._ring.hdr[CLOSE] and not self._ring.hdr[DONE] and self._failure is None:
            self._failure = (
                f"{self.samples_path}: the run-log writer process ended "
                f"(exit status {self._proc.returncode}) before it closed the run"
            )
            log.error("run log: %s", self._failure)
            self._limit = -1
        self._poll_failure()  # picks up a failure the writer published last


# A closed writer answers ``failure`` without its ring.
ProcessRunLogWriter._final = [0] * 64  # type: ignore[attr-defined]
