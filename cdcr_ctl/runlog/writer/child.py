"""The run-log writer process: :func:`main`.

Started by :class:`~cdcr_ctl.runlog.writer.process.ProcessRunLogWriter`, which first moves it
from any real-time scheduling it inherited to SCHED_BATCH (a batch task never preempts a running
one when it wakes, so the loop is not cut mid-cycle by the writer's drains), sets its nice level
(``WRITER_NICE``) and has it ignore SIGINT and SIGTERM (a Ctrl-C or a service manager's SIGTERM
to the whole group goes to the daemon, which closes the run: this process follows the close
request, or the daemon's death). Reads its settings (a length-prefixed pickle) from stdin,
maps the shared ring from the inherited descriptor, makes an ordinary
:class:`~cdcr_ctl.runlog.writer.thread.RunLogWriter` in the run directory and sets ``READY``
(or publishes the error as the log's failure). Then, every drain interval: moves the ring's rows
and CAN frames to that writer, publishes its counters and any write error in the shared header,
and ends when

- the loop's process asks it to close: drains the ring, closes the run with the given outcome.
  The request also wakes it (:class:`Wake`: a byte on its stdin, which it waits on between
  drains), so a run's close does not wait for the drain period;
- the loop's process is gone (its parent changed: SIGKILL, a crash): drains what the ring holds
  and closes the run with outcome ``aborted``, so the files end whole.
"""

from __future__ import annotations

import logging
import math
import os
import pickle
import select
import struct
import sys
from typing import Any

from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.columns import TEXT_COLUMNS, lateness_cell_us, t_cell
from cdcr_ctl.runlog.writer.ringmap import (
    DONE,
    FAILED,
    ORDER_NAMES,
    READY,
    ROW_DROPPED,
    ROW_HEAD,
    ROW_TAIL,
    SLOT_HEAD,
    W_HIGH,
    W_START,
    RingMap,
    publish_writer_counts,
)
from cdcr_ctl.runlog.writer.thread import RunLogWriter

log = logging.getLogger("cdcr_ctl.runlog.writer")

#: Columns written back as integers (when the number is whole).
INT_COLUMNS = frozenset({"cycle"})
#: Reason recorded when the loop's process died with the run open.
PARENT_GONE = "the daemon process ended with the run open (the writer process drained the ring)"


class RingDrain:
    """Moves rows from the ring to ``writer`` in column order (numbers back to Python values)."""

    def __init__(self, ring: RingMap, writer: RunLogWriter, columns: list[str]) -> None:
        self.ring, self.writer = ring, writer
        num_cols = [c for c in columns if c not in TEXT_COLUMNS]
        text = [c for c in columns if c in TEXT_COLUMNS]
        self.text_pos = columns.index(text[0]) if text else -1
        self.int_pos = [j for j, c in enumerate(num_cols) if c in INT_COLUMNS]
        self.cap = ring.layout.rows
        self.row_floats = ring.layout.row_floats
        self.n = len(num_cols)
        self.num_cols = num_cols
        self._by_names: list[int] | None = None
        self.drained = False

    def _names_index(self) -> list[int]:
        """Column position (among the numeric columns) of each value of an ORDER_NAMES slot."""
        if self._by_names is None:
            pos = {c: j for j, c in enumerate(self.num_cols)}
            self._by_names = [pos[name] for name in self.ring.names()]
        return self._by_names

    def rows(self) -> int:
        """Hand every published row to the writer; the number moved."""
        hdr = self.ring.hq
        tail, head = hdr[ROW_TAIL], hdr[ROW_HEAD]
        if not self.drained:
            self.drained = True
            hdr[W_START] = head - tail  # the start's backlog, apart from the steady state
        elif head - tail > hdr[W_HIGH]:
            hdr[W_HIGH] = head - tail
        f64, rf, write, n = self.ring.f64, self.row_floats, self.writer.write, self.n
        for seq in range(tail, head):
            slot = seq % self.cap
            raw: list[Any] = f64[slot * rf : (slot + 1) * rf].tolist()
            order, n_text = raw[0], int(raw[1])
            if order == ORDER_NAMES:
                # The loop's time and lateness come unrounded (s): rounded here, by the rule
                # of the loop's own row mapping.
                raw[SLOT_HEAD] = t_cell(raw[SLOT_HEAD])
                raw[SLOT_HEAD + 2] = lateness_cell_us(raw[SLOT_HEAD + 2])
                values: list[Any] = [math.nan] * n
                for j, v in zip(self._names_index(), raw[SLOT_HEAD:], strict=False):
                    values[j] = v
            else:
                values = raw[SLOT_HEAD:]
            for j in self.int_pos:
                v = values[j]
                if v == v and not math.isinf(v) and v == int(v):
                    values[j] = int(v)
            values = [None if v != v else v for v in values]
            if self.text_pos >= 0:
                values.insert(self.text_pos, self.ring.get_event(slot, n_text) if n_text else "")
            write(values)
        hdr[ROW_TAIL] = head
        return head - tail

    def frames(self) -> None:
        tap = self.writer.can_tap
        frames = self.ring.take_frames()
        if tap is not None:
            tap.queue.extend(frames)

    def publish(self) -> None:
        s, hdr = self.writer.stats, self.ring.hq
        publish_writer_counts(hdr, s, s.dropped - self.upstream)
        if self.writer.failure is not None and not hdr[FAILED]:
            self.ring.set_failure(self.writer.failure)

    upstream = 0

    def all(self) -> int:
        """Drain rows and frames until the ring is empty; the rows moved."""
        self.frames()
        moved = 0
        while n := self.rows():
            moved += n
        self.frames()
        return moved


class Wake:
    """Waits between drains on the stdin pipe from the loop's process (after the settings, it
    writes one byte there with its close request, see
    :meth:`~cdcr_ctl.runlog.writer.process.ProcessRunLogWriter.close`); its end (the loop's
    process gone) wakes too. Once at its end, a plain sleep."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.open = True

    def wait(self, timeout_s: float) -> None:
        """Return after ``timeout_s`` or at once when woken."""
        if not self.open:
            select.select([], [], [], timeout_s)
            return
        ready, _, _ = select.select([self.fd], [], [], timeout_s)
        if ready:
            try:
                self.open = bool(os.read(self.fd, 64))
            except OSError:
                self.open = False


def _read_exact(fd: int, n: int) -> bytes:
    """``n`` bytes from ``fd`` (fewer at its end), unbuffered: nothing after them is read
    ahead (the wake byte that may follow is :class:`Wake`'s)."""
    out = b""
    while len(out) < n:
        chunk = os.read(fd, n - len(out))
        if not chunk:
            break
        out += chunk
    return out


def main(run_nice: int | None = None) -> int:
    """The writer process: wait for the settings, then write the run at ``run_nice`` (the
    spare waited at a lower priority, see :data:`~cdcr_ctl.runlog.writer.spawn.SPARE_NICE`)."""
    stdin = sys.stdin.fileno()
    head = _read_exact(stdin, 8)
    if len(head) < 8:
        return 0  # a spare whose factory went away: nothing to write
    (n,) = struct.unpack("<Q", head)
    spec = pickle.loads(_read_exact(stdin, n))
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    if spec.get("rt_priority"):  # beside a real-time loop (spawn.hand_over), for every thread
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(spec["rt_priority"]))
        except OSError as exc:
            log.warning("run-log writer stays off real time (%s)", exc.strerror or exc)
    if run_nice is not None:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, run_nice)
        except OSError as exc:  # no right to raise a priority: write at the spare's
            log.warning(
                "run-log writer stays at nice %d (cannot set %d: %s; allow it with systemd "
                "LimitNICE= or CAP_SYS_NICE)",
                os.getpriority(os.PRIO_PROCESS, 0),
                run_nice,
                exc.strerror or exc,
            )
    if spec.get("fd_inherited"):
        fd = spec["fd"]
    else:  # a spare, started before the ring existed
        fd = os.open(f"/proc/{spec['parent_pid']}/fd/{spec['fd']}", os.O_RDWR)
    ring = RingMap(spec["layout"], fd)
    parent = spec["parent_pid"]  # not getppid() now: the parent may already be gone
    failures: list[str] = []
    try:
        writer = RunLogWriter(
            spec["run_dir"],
            spec["columns"],
            spec["metadata"],
            config_text=spec["config_text"],
            config_source=spec["config_source"],
            extra_files=spec["extra_files"],
            fsync_every_s=spec["fsync_every_s"],
            max_queued_rows=2 * spec["layout"].rows,
            # Back-pressure from the thread to the ring: the drain waits for the thread rather
            # than drop a row the loop's side counted as logged; the ring then fills, and the
            # loop's side applies its own rule (trip in real time, wait in lock-step).
            on_full="wait",
            drain_interval_s=spec["drain_interval_s"],
            second_sink=spec["second_sink"],
            on_failure=failures.append,
            require_empty=False,
            files_made=bool(spec.get("files_made")),
            yield_gil=False,  # no real-time thread in this process to give the GIL to
        )
    except (RigError, OSError, ValueError) as exc:
        text = str(exc)
        if str(spec["run_dir"]) not in text:
            text = f"{spec['run_dir']}: cannot start the run log: {text}"
        ring.set_failure(text)
        log.error("run log not started: %s", text)
        return 1
    ring.hq[READY] = 1
    drain = RingDrain(ring, writer, list(spec["columns"]))
    period = spec["drain_interval_s"]
    # A ring that waits (lock-step) is drained only once this full, or at the close or the
    # parent's end (spawn.WAIT_DEFER_FILL); None: every drain interval.
    defer = spec.get("defer_fill")
    wake = Wake(stdin)
    reason, outcome = PARENT_GONE, "aborted"
    while True:
        request = ring.close_request()
        gone = os.getppid() != parent
        if defer is None or request is not None or gone or ring.backlog() >= defer:
            moved = drain.all()
            drain.publish()
        else:
            moved = 0
        if request is not None or gone:
            if request is not None:
                reason, outcome = request["reason"], request["outcome"]
            break
        # A drain that found the ring a quarter full or more: the loop is outpacing the drain
        # period (a loop on simulated time waiting for room, or one catching up), so drain
        # again at once rather than let the ring fill while this process sleeps.
        if moved < max(1, drain.cap // 4):
            wake.wait(period)
    drain.upstream = ring.hq[ROW_DROPPED]
    writer._dropped += drain.upstream  # rows the loop's side refused count in run.yaml too
    writer.close(reason, outcome=outcome)
    drain.publish()
    ring.hq[DONE] = 1
    return 0 if writer.failure is None else 2
