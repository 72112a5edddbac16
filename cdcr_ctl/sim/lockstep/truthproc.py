"""The lock-step world's truth solved in a process of its own, one cycle behind the drives.

The truth's statics solve is the largest single cost of a simulated cycle. Here a worker process
(``multiprocessing``, spawn) holds its own copy of the truth and solves each period's drive
positions while the loop process computes the next cycle; the result is picked up at the start of
the next period. So the world shown to the sensors lags the drives by one SYNC period plus up to
one physics period, as in real time, where the physics thread solves at its own rate and
publishes when done (a few ms behind the drives). Determinism holds: the same positions go to
the worker in the same order, and each result is taken at a fixed cycle.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.simconfig import load_sim_config


def _worker(sim_path: str, conn: Any) -> None:
    """Solve each counts list received; answer ``(state, failures, cpu_s)``; stop on None."""
    truth = make_truth(load_sim_config(sim_path))
    while True:
        counts = conn.recv()
        if counts is None:
            return
        c0 = time.thread_time()
        state = truth.step(counts)
        conn.send((to_wire(state), truth.failures, time.thread_time() - c0))


def _float_arrays(state: Any) -> bool:
    """Whether ``state`` is a dataclass of float64 arrays that nested lists give back exactly."""
    if not dataclasses.is_dataclass(state):
        return False
    for f in dataclasses.fields(state):
        a = getattr(state, f.name)
        if not isinstance(a, np.ndarray) or a.dtype != np.float64 or (a.size == 0 and a.ndim != 1):
            return False
    return True


def to_wire(state: Any) -> Any:
    """A solved state for the pipe: a dataclass of float arrays as a tuple of nested float lists
    (pickled in a fraction of the time its arrays take; floats round-trip exactly), anything
    else as it is."""
    if _float_arrays(state):
        return tuple(getattr(state, f.name).tolist() for f in dataclasses.fields(state))
    return state


def from_wire(wire: Any, like: Any) -> Any:
    """The state :func:`to_wire` sent, rebuilt as the class of ``like`` (the local truth's
    state: the same class, made by the same truth)."""
    if isinstance(wire, tuple) and _float_arrays(like):
        return type(like)(*[np.array(v, dtype=np.float64) for v in wire])
    return wire


class TruthProcess:
    """Solves the truth of ``sim_path`` in a worker; the results go into ``local`` (a truth of
    the same world in this process, whose ``cell_tensions``/``tip_pose`` the sensors read)."""

    def __init__(self, sim_path: str, local: Any) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_worker, args=(sim_path, child), name="lockstep-truth", daemon=True
        )
        self._proc.start()
        child.close()
        self.local = local
        self.pending = False
        self.cpu_s = 0.0

    def submit(self, counts: Sequence[int]) -> None:
        """Start solving for ``counts`` (a result must not be pending)."""
        self._conn.send(list(counts))
        self.pending = True

    def collect(self) -> None:
        """Wait for the pending result and make it the world's state."""
        wire, failures, cpu_s = self._conn.recv()
        self.pending = False
        state = from_wire(wire, self.local._state)
        with self.local._lock:
            self.local._state = state
            self.local.steps += 1
        self.local.failures = failures
        self.cpu_s += cpu_s

    def close(self) -> None:
        try:
            if self.pending:
                self.collect()
            self._conn.send(None)
        except (OSError, EOFError):
            pass
        self._proc.join(2.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(1.0)
        self._conn.close()


__all__ = ["TruthProcess"]
