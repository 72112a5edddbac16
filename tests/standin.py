"""Stand-in hardware beside the product under test: the simulated rig's processes at SCHED_FIFO.

The simulator stands in for drives and sensors that have processors of their own. On a machine
others load, a simulator at SCHED_OTHER (even at nice -5) is starved with everything else: beside
``stress-ng --cpu 2`` its drives missed their 100 ms heartbeats and the daemon under test rightly
tripped ("heartbeat lost") before the test's subject happened. So the system tests and the
documentation's command runner run every thread of the simulator, and of every process it
started (its physics worker), at SCHED_FIFO :data:`STANDIN_PRIORITY`: above a daemon at the
tests' real-time priority, so the daemon under test never holds the stand-in hardware up. The
daemon itself runs at whatever its rig config asks for.

Needs root or CAP_SYS_NICE; where not permitted the simulator stays as it is.
"""

from __future__ import annotations

import contextlib
import os

#: SCHED_FIFO priority of the daemon in the tests whose claim needs it real-time
#: (``control.realtime_priority``, as a lab PC's unit runs it).
RT_PRIORITY = 50
#: How much higher the simulated rig's threads run than such a daemon (a SCHED_FIFO task is not
#: time-sliced against another of its priority).
SIM_ABOVE = 10
#: SCHED_FIFO priority of the stand-in hardware.
STANDIN_PRIORITY = RT_PRIORITY + SIM_ABOVE


def standin_realtime(pid: int, priority: int = STANDIN_PRIORITY) -> list[int]:
    """Every thread of process ``pid`` and of its descendants at SCHED_FIFO ``priority`` (as
    ``chrt -a -f -p`` on each; threads they start later inherit it). Returns the threads set
    (none where not permitted)."""
    done: list[int] = []
    for p in with_descendants(pid):
        for task in tasks(p):
            with contextlib.suppress(PermissionError, ProcessLookupError):
                os.sched_setscheduler(task, os.SCHED_FIFO, os.sched_param(min(99, priority)))
                done.append(task)
    return done


def tasks(pid: int) -> list[int]:
    """The threads of process ``pid`` (none once it is gone)."""
    try:
        return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return []


def with_descendants(pid: int) -> list[int]:
    """``pid`` and every process it started, and theirs (the simulator's physics worker: a
    process of its own, which a ``chrt -a`` of the simulator alone leaves at SCHED_OTHER, where
    a loaded machine starved it and with it the stand-in drives and sensors)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        for task in tasks(p):
            with contextlib.suppress(OSError), open(f"/proc/{p}/task/{task}/children") as f:
                todo.extend(int(c) for c in f.read().split())
    return out


__all__ = ["RT_PRIORITY", "SIM_ABOVE", "STANDIN_PRIORITY", "standin_realtime", "with_descendants"]
