"""Starting the run-log writer process, and the CAN listener feeding its ring.

:func:`start_writer_process` starts ``python -c _BOOT``: off real time (``WRITER_POLICY``) and at
``WRITER_NICE`` before its imports, then :func:`cdcr_ctl.runlog.writer.child.main`, which waits
for its settings on stdin (so the factory can keep a spare with its imports done).
:func:`wait_exit` waits for its end. :class:`RingCanTap` puts CAN frames into the ring's records
for ``run.mcap``'s ``/can``.
"""

from __future__ import annotations

import logging
import os
import pickle
import select
import struct
import subprocess
import sys
import threading
from collections.abc import Sequence

import can

from cdcr_ctl.runlog.writer.ring import CAN_DROPPED, SharedRing

log = logging.getLogger(__name__)

#: Nice increment of the writer process: 0, the daemon's own. Measured at 1 kHz with MCAP under
#: ``stress-ng --cpu 2`` on the 2-core machine (``benchmarks/bench_loop.py --runlog mcap
#: --seconds 15 --spare-s 3 --writer-nice N``, two runs each, docs/performance/figures.md): at
#: nice +10
#: the writer got about a tenth of a nice-0 task's share, less than its ~20-30 % of a core, and
#: fell 6 s behind (one run never drained before its close, another was not done 30 s after
#: it): a longer run would have overflowed any ring. At nice +5 it started 1.6-1.7 s behind; at
#: nice 0 0.6-0.9 s, then held at most 0.12-0.14 s of rows, and the loop's rate was no lower
#: (715-752 Hz against 394-708 at +10). The loop on the rig runs SCHED_FIFO, above any nice
#: level, so the writer's share is taken from other ordinary work, never from the loop.
WRITER_NICE = 0
#: Scheduling policy of the writer process (``os.SCHED_*`` name): SCHED_BATCH, so the writer
#: waking for its drain never preempts a running loop mid-cycle (a batch task waits for the
#: next scheduler tick); its CPU share is the same as at SCHED_OTHER.
WRITER_POLICY = "SCHED_BATCH"
#: SCHED_FIFO priority a writer process takes with its run when the process handing it the run
#: is real-time (a loop at ``control.realtime_priority``) and the ring trips when full: the
#: lowest real-time priority, so every task of a real-time loop (its loop, CAN and stop threads,
#: the stop line) preempts it and it never preempts them, while no ordinary task (another
#: job's CPU-bound work, hundreds of status clients) can starve it. Off real time (SCHED_BATCH
#: at ``WRITER_NICE``) a writer beside a SCHED_FIFO loop at 1 kHz with ``stress-ng --cpu 8``
#: on the 2-core machine did not drain once in a 5 s run (``benchmarks/bench_loop.py
#: --rt-priority 60 --runlog mcap --seconds 5 --spare-s 3``: ring high-water 4262 rows, all of
#: them at its first drain); a longer run overflows the ring and trips ``log_overflow``. 0: never.
WRITER_RT_PRIORITY = 1
#: Nice increment of a writer whose loop waits for it when its ring is full (``on_full="wait"``:
#: a loop on simulated time, the lock-step rig), kept once it has its run. There is no real-time
#: loop to protect there, but the lock-step truth worker is on the critical path: at nice 0 the
#: writer's drains held the worker's CPU for whole time slices and the loop waited for the
#: truth. Lower, the woken worker preempts it. SCHED_IDLE did that best on an idle machine (the
#: lock-step benchmark, four alternating pairs over the bend's cycles: 6.4-7.9x at nice 0,
#: 8.2-10.9x at SCHED_IDLE), but beside a CPU-bound neighbour (``stress-ng --cpu 2``) an idle
#: task gets almost nothing and lock-step runs crawled (three tests timed out); at nice 10 it
#: keeps a tenth of a nice-0 task's share. docs/performance/figures.md.
WAITING_WRITER_NICE = 10
#: Nice increment of a writer process while it starts (its interpreter and imports, ~0.3 s of
#: CPU idle, more under load) and waits as a spare: the factory starts the next run's spare as
#: a run starts, and at nice 0 that burst competed with the simulator and the loop at the
#: moment a run begins (tests/system/test_daemon_stops.py tripped on a drive heartbeat lost
#: within 0.7 s of the run's start, 3 of 11 runs on the loaded machine, 0 of 4 on main). Once
#: it has a run it goes to WRITER_NICE, which needs the right to raise a priority (root,
#: CAP_SYS_NICE, or RLIMIT_NICE, systemd ``LimitNICE=``); without it it stays here and says so.
SPARE_NICE = 10
#: The writer process's first statements: off real time and at SPARE_NICE before its imports,
#: then :func:`cdcr_ctl.runlog.writer.child.main` (which sets ``run_nice`` once it has a run).
#: Once ``main`` returns, the run's files are closed and fsynced and the ring says so: the
#: process ends at once (``os._exit``), without the interpreter's teardown, which would only
#: delay the loop's process waiting for its end (``wait_closed``).
_BOOT = (
    "import os, signal, sys\n"
    "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
    "try:\n    os.sched_setscheduler(0, os.{policy}, os.sched_param(0))\n"
    "except (OSError, AttributeError):\n    pass\n"
    "base = os.getpriority(os.PRIO_PROCESS, 0)\n"
    "try:\n    os.nice({spare_nice})\n"
    "except OSError:\n    pass\n"
    "from cdcr_ctl.runlog.writer.child import main\n"
    "code = main(run_nice=base + {nice})\n"
    "sys.stderr.flush()\n"
    "os._exit(code)\n"
)


#: A ring that waits (``on_full="wait"``: a loop on simulated time) is drained only once it is
#: this full (rows or CAN frames, a fraction of its size), or when the run closes or the loop's
#: process is gone; a ring that trips is drained every drain interval. Lock-step runs as fast
#: as the two cores allow, and a writer draining meanwhile takes its CPU from the loop thread or
#: the truth worker: on the planar bend (``benchmarks/bench_lockstep.py``, docs/performance/
#: figures.md) the cycles took 566-684 us each with the writer draining beside them
#: at nice 10, 462-536 us deferred. Deferred, the writer does the same work after the run's last
#: cycle, on CPUs the run no longer needs (the whole run is no faster: a serial tail). Rows
#: wait in shared memory, which the writer process holds too: a loop process killed meanwhile
#: loses none of them (the writer drains when it sees its parent gone). Real time keeps its
#: drain interval: there the log is on disk within ``fsync_every_s``.
WAIT_DEFER_FILL = 0.5


def defer_fill(on_full: str) -> float | None:
    """How full a ring whose ``on_full`` this is must be before its writer drains it, before
    the run closes (:data:`WAIT_DEFER_FILL`); None: every drain interval."""
    return WAIT_DEFER_FILL if on_full == "wait" else None


def writer_nice(on_full: str) -> int:
    """The writer process's nice increment (once it has its run) for a ring whose ``on_full``
    is this."""
    return WAITING_WRITER_NICE if on_full == "wait" else WRITER_NICE


def take_realtime(proc: subprocess.Popen, on_full: str) -> str | None:
    """Before handing ``proc`` (a writer process) its run: SCHED_FIFO at
    :data:`WRITER_RT_PRIORITY` when the calling thread is real-time (SCHED_FIFO/RR) and the ring
    trips when full (a loop on the wall clock). Set on the process's main thread before it reads
    its settings, so the threads it starts for the run inherit it. Returns the policy it runs
    at, or None when it stays off real time (not asked, or not permitted: logged)."""
    if not WRITER_RT_PRIORITY or on_full == "wait":
        return None
    if os.sched_getscheduler(0) not in (os.SCHED_FIFO, os.SCHED_RR):
        return None
    try:
        os.sched_setscheduler(proc.pid, os.SCHED_FIFO, os.sched_param(WRITER_RT_PRIORITY))
    except OSError as exc:  # no CAP_SYS_NICE / RLIMIT_RTPRIO for it: it stays SCHED_BATCH
        log.warning("run-log writer stays off real time (%s)", exc.strerror or exc)
        return None
    return f"SCHED_FIFO {WRITER_RT_PRIORITY}"


def hand_over(proc: subprocess.Popen, blob: bytes, on_full: str) -> str | None:
    """Give ``proc`` (from :func:`start_writer_process`) its run: the settings ``blob`` (a
    pickled dict) on its stdin, after :func:`take_realtime`. A real-time writer is also told
    to take the policy itself once it reads them, before it starts the run's threads: a process
    just started may run its boot line (SCHED_BATCH) after this call. Returns
    :func:`take_realtime`'s answer; raises OSError when ``proc``'s stdin is closed."""
    policy = take_realtime(proc, on_full)
    if policy is not None:
        blob = pickle.dumps({**pickle.loads(blob), "rt_priority": WRITER_RT_PRIORITY})
    proc.stdin.write(struct.pack("<Q", len(blob)) + blob)
    proc.stdin.flush()
    return policy


def start_writer_process(ring_fd: int | None = None, on_full: str = "trip") -> subprocess.Popen:
    """A writer process that imports what it needs and then waits for its settings on stdin.
    Given ``ring_fd``, the ring's descriptor is inherited; a spare started before its ring
    exists maps it through ``/proc/<parent>/fd/<fd>`` instead (so a spare needs its parent alive
    until it has its settings). One that never gets settings exits when its stdin closes.
    ``on_full``: what its ring does when full, which sets its nice level once it has its run
    (:func:`writer_nice`)."""
    boot = _BOOT.format(nice=writer_nice(on_full), spare_nice=SPARE_NICE, policy=WRITER_POLICY)
    cmd = [sys.executable, "-c", boot]
    fds = () if ring_fd is None else (ring_fd,)
    return subprocess.Popen(
        cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, pass_fds=fds, close_fds=True
    )


def wait_exit(proc: subprocess.Popen, timeout_s: float | None) -> bool:
    """Wait until ``proc`` has ended (and reap it); False after ``timeout_s``. Waits on a pidfd
    (Linux 5.3+), which wakes as the process ends: ``Popen.wait`` with a timeout polls, up to
    50 ms apart."""
    if proc.poll() is not None:
        return True
    try:
        fd = os.pidfd_open(proc.pid)
    except (AttributeError, OSError):  # no pidfd, or reaped meanwhile: Popen's own wait
        fd = None
    if fd is not None:
        try:
            ready, _, _ = select.select([fd], [], [], timeout_s)
        finally:
            os.close(fd)
        if not ready:
            return False
    try:
        proc.wait(None if fd is not None else timeout_s)
    except subprocess.TimeoutExpired:
        return False
    return True


class RingCanTap(can.Listener):
    """A python-can listener putting frames into the ring's CAN records for ``/can``. Any thread
    may call it (a lock orders the producers); a full ring counts the frame as dropped.

    :meth:`on_messages` takes a batch (the CAN traffic log's writer thread hands over what it
    drained, :class:`~cdcr_ctl.drives.group.traffic.DeferredTrafficLog`): one lock, one numpy
    store of the batch's records, instead of a call, a lock and a ``struct`` store per frame."""

    def __init__(self, ring: SharedRing) -> None:
        self._ring = ring
        self._lock = threading.Lock()
        self.dropped = 0

    def on_message_received(self, msg: can.Message) -> None:
        self.on_messages((msg,))

    def on_messages(self, msgs: Sequence[can.Message]) -> None:
        """A batch of frames, in order (timestamp, id, flags, dlc, data; data cut at 64 bytes)."""
        records = [
            (m.timestamp, m.arbitration_id,
             m.is_extended_id | m.is_rx << 1 | m.is_error_frame << 2 | m.is_remote_frame << 3,
             m.dlc, min(len(m.data), 64), bytes(m.data[:64]))
            for m in msgs
        ]  # fmt: skip
        with self._lock:
            ring = self._ring
            stored = ring.put_frames(records) if ring is not None else 0
            if stored < len(records):
                self.dropped += len(records) - stored
                if ring is not None:
                    ring.hq[CAN_DROPPED] = self.dropped

    def detach(self) -> None:
        with self._lock:
            self._ring = None

    def stop(self) -> None:  # python-can API; nothing to release
        pass
