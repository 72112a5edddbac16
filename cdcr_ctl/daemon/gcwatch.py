"""How long the garbage collector's passes take in the rig process (issue #21).

A collection runs in whichever thread allocates when a generation's threshold is crossed, and it
holds the interpreter lock for its whole pass: the loop waits for it even when another thread
(a command thread unpickling a trajectory, the CAN traffic log's writer) triggered it. The rig
process installs one :class:`GcWatch` (``gc.callbacks``) and reports its counts in ``status``
(``rig_gc``): per generation the passes, their total and longest duration (ms), and how many took
longer than one loop period.
"""

from __future__ import annotations

import gc
import os
import threading
import time
from typing import Any

_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 0.01


class GcWatch:
    """Times every collection pass of this process (``gc.callbacks``); :meth:`summary` for
    ``status``. ``period_s``: the loop's period, for the count of passes longer than it."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.count = [0, 0, 0]
        self.total_s = [0.0, 0.0, 0.0]
        self.max_s = [0.0, 0.0, 0.0]
        self.over_period = [0, 0, 0]
        self._t0 = 0.0

    def install(self) -> GcWatch:
        gc.callbacks.append(self._callback)
        return self

    def remove(self) -> None:
        if self._callback in gc.callbacks:
            gc.callbacks.remove(self._callback)

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
            return
        dt = time.perf_counter() - self._t0
        g = min(max(int(info.get("generation", 0)), 0), 2)
        self.count[g] += 1
        self.total_s[g] += dt
        self.max_s[g] = max(self.max_s[g], dt)
        if dt > self.period_s:
            self.over_period[g] += 1

    def summary(self) -> dict[str, Any]:
        """Per generation: ``passes``, ``total_ms``, ``max_ms``, ``over_period``; and whether
        automatic collection is on (``enabled``) with its thresholds."""
        return {
            "enabled": gc.isenabled(),
            "thresholds": list(gc.get_threshold()),
            **{
                f"gen{g}": {
                    "passes": self.count[g],
                    "total_ms": round(self.total_s[g] * 1e3, 3),
                    "max_ms": round(self.max_s[g] * 1e3, 3),
                    "over_period": self.over_period[g],
                }
                for g in range(3)
            },
        }


def thread_cpu_s() -> dict[str, float]:
    """CPU time (user + system, s) of each Python thread of this process, by thread name, from
    ``/proc/self/task/<tid>/stat`` (Linux; empty elsewhere): which thread competes with the
    loop for the interpreter lock. Threads without a Python name (a C library's) are left out."""
    out: dict[str, float] = {}
    for th in threading.enumerate():
        tid = th.native_id
        if tid is None:
            continue
        try:
            with open(f"/proc/self/task/{tid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except OSError:
            continue
        # Fields after the name: state is [0], utime [11], stime [12] (proc(5), 14 and 15).
        out[th.name] = round((int(fields[11]) + int(fields[12])) * _TICK_S, 2)
    return out


__all__ = ["GcWatch", "thread_cpu_s"]
