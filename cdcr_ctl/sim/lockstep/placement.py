"""Where a lock-step rig's two busy parts run: the loop thread on one CPU, the truth worker on
another.

A lock-step run keeps the loop thread busy all the time (the controller's cycle, the simulated
drives and sensors) and the truth worker most of the time (the statics solve of the period,
:mod:`.truthproc`), one period behind. Left to the scheduler on a 2-CPU machine, a semaphore
wake-up often puts the worker on the loop thread's own CPU (measured with ``perf sched``: 76-100 %
of its wake-ups, docs/performance/figures.md), so the two take turns instead of overlapping,
and each preemption costs the loop thread its caches. Pinned apart, they overlap.

:class:`Placement` names the two CPUs (or none). ``auto`` takes the first two CPUs this process
may run on (``os.sched_getaffinity``); with one CPU nothing is pinned. Sessions run side by side
(``cdcr-ctl experiments --jobs N``) get ``Placement.rotated(i)``: job ``i``'s loop on the
``i``-th allowed CPU and its worker on the next, so N loops spread over the CPUs instead of
sharing the first. Only the loop thread and the worker are pinned; the process's other threads
(listeners, watchdog) and the run-log writer processes it starts keep the whole set, so the
scheduler puts them where there is room.

Placement changes where the work runs, never what it computes: simulated time and the logs are
the same pinned or not (``tests/system/test_lockstep.py``).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

from cdcr_ctl.errors import ConfigError


def allowed_cpus() -> list[int]:
    """The CPUs this process may run on, ascending (Linux; elsewhere ``[]``)."""
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return []


@dataclass(frozen=True)
class Placement:
    """CPU of the loop thread and of the truth worker (None: not pinned)."""

    loop_cpu: int | None = None
    worker_cpu: int | None = None

    @classmethod
    def rotated(cls, index: int = 0) -> Placement:
        """Session ``index``'s pair among the allowed CPUs: loop on CPU ``index mod n``, worker
        on the next; nothing pinned when fewer than two CPUs are allowed."""
        cpus = allowed_cpus()
        if len(cpus) < 2:
            return cls()
        i = index % len(cpus)
        return cls(cpus[i], cpus[(i + 1) % len(cpus)])

    @classmethod
    def parse(cls, text: str, source: str = "--cpus") -> Placement:
        """``auto`` (:meth:`rotated` of run 0), ``none``, ``LOOP,WORKER`` (CPU numbers) or
        ``job:I`` (:meth:`rotated` of session I); a bad value raises :class:`ConfigError` naming
        ``source`` and the text."""
        t = text.strip().lower()
        if t == "auto":
            return cls.rotated(0)
        if t == "none":
            return cls()
        try:
            if t.startswith("job:"):
                return cls.rotated(int(t[4:]))
            loop, worker = (int(v) for v in t.split(","))
        except ValueError:
            raise ConfigError(
                source, "cpus", "expected auto, none, job:I or LOOP,WORKER", text
            ) from None
        cpus = allowed_cpus()
        for cpu in (loop, worker):
            if cpus and cpu not in cpus:
                raise ConfigError(source, "cpus", f"CPU {cpu} is not one of {cpus}", text)
        return cls(loop, worker)

    def pin_this_thread(self) -> None:
        """Pin the calling thread to :attr:`loop_cpu` (call it on the loop thread)."""
        if self.loop_cpu is not None:
            _pin(0, self.loop_cpu)

    def pin_worker(self, pid: int) -> None:
        """Pin process ``pid`` (the truth worker) to :attr:`worker_cpu`."""
        if self.worker_cpu is not None:
            _pin(pid, self.worker_cpu)

    def describe(self) -> str:
        if self.loop_cpu is None:
            return "not pinned"
        return f"loop thread on CPU {self.loop_cpu}, truth worker on CPU {self.worker_cpu}"


def _pin(tid: int, cpu: int) -> None:
    """Pin thread or process ``tid`` (0: the calling thread) to ``cpu``; a refusal (a container
    that forbids it, a CPU gone offline) leaves it where it is."""
    with contextlib.suppress(OSError):
        os.sched_setaffinity(tid, {cpu})


__all__ = ["Placement", "allowed_cpus"]
