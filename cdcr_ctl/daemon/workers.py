"""What the daemon's worker processes (the front's intake, the rig process's planner) do first:
end themselves when the process that started them is gone.

A ``ProcessPoolExecutor`` worker waits for work on a pipe that its parent's pool keeps open; a
parent killed with SIGKILL (a test, the OOM killer, systemd after its stop timeout) cannot shut
the pool down, and the worker would live on as an orphan. A daemon thread of the worker looks at
its parent process every :data:`PARENT_CHECK_S` and ends the worker once it has changed.
"""

from __future__ import annotations

import multiprocessing
import os
import select
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

#: How often a worker checks that the process that started it still runs (s).
PARENT_CHECK_S = 1.0


def _exit_with_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(PARENT_CHECK_S)
    os._exit(0)


def watch_parent(parent_pid: int) -> None:
    """(in a worker) End this process once its parent (``parent_pid``, the pid of the process
    that made the pool) is gone."""
    threading.Thread(target=_exit_with_parent, args=(parent_pid,), daemon=True).start()


def watch_process(pid: int) -> threading.Event:
    """An event set once process ``pid`` (this process's parent) has ended. Waits on a pidfd
    (Linux 5.3+), which wakes as the process ends, whichever of its threads started this one;
    without pidfds, looks at the parent every :data:`PARENT_CHECK_S`."""
    gone = threading.Event()
    try:
        fd = os.pidfd_open(pid)
    except (AttributeError, OSError):
        fd = None
    if os.getppid() != pid:  # ended before the pidfd was opened (or ``pid`` is not the parent)
        gone.set()

    def wait() -> None:
        if fd is not None:
            select.select([fd], [], [])
            os.close(fd)
        else:
            while os.getppid() == pid:
                time.sleep(PARENT_CHECK_S)
        gone.set()

    if not gone.is_set():
        threading.Thread(target=wait, name="parent-watch", daemon=True).start()
    elif fd is not None:
        os.close(fd)
    return gone


def nice_and_watch_parent(increment: int, parent_pid: int) -> None:
    """(a pool initializer) ``os.nice(increment)``, then :func:`watch_parent`."""
    os.nice(increment)
    watch_parent(parent_pid)


def one_worker_pool(
    initializer: Callable[..., None], initargs: tuple[Any, ...]
) -> ProcessPoolExecutor:
    """A pool of one spawned worker (spawned: no copy of the caller's threads, locks or real-time
    policy), set up by ``initializer(*initargs)``, which should call :func:`watch_parent`."""
    return ProcessPoolExecutor(
        max_workers=1,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=initializer,
        initargs=initargs,
    )


__all__ = [
    "PARENT_CHECK_S",
    "nice_and_watch_parent",
    "one_worker_pool",
    "watch_parent",
    "watch_process",
]
