"""The lock-step world's truth solved in a process of its own, one cycle behind the drives.

The truth's statics solve is the largest single cost of a simulated cycle. Here a worker process
(``multiprocessing``, spawn) holds its own copy of the truth and solves each period's drive
positions while the loop process computes the next cycle; the result is picked up at the start of
the next period. So the world shown to the sensors lags the drives by one SYNC period plus up to
one physics period (4-9 ms on the Qi rig: 250 Hz loop, 200 Hz physics), as in real time, where
the physics thread solves at its own rate and publishes when done (a few ms behind the drives).
Determinism holds: the same positions go to the worker in the same order, and each result is
taken at a fixed cycle (the next period's start), never "whenever it is ready".

**The hand-off.** The drive counts go to the worker and the solved state comes back through
shared memory (:class:`_Shared`: int64 counts, float64 state; exact, nothing pickled), and each
side wakes the other with a semaphore (a futex): one wake-up of the worker per solve (measured:
992-1000 for the planar bend's 999 solves). Through the pipe used before, the loop's process
woke the worker 1617-1719 times for them and paid a pickle and an unpickle a solve; and a
pipe's write wakes its reader as a *synchronous* wake-up (the kernel's hint that the writer is
about to sleep), which makes the scheduler favour the writer's CPU for the reader even though
the loop thread goes on running.
Measured with ``perf sched record`` on the 2-core machine at load average 6-7 (README,
"Lock-step simulation"): the worker still ran on the loop thread's CPU after 90-100 % of its
wake-ups either way, because the other CPU was busy too (other jobs, and in a lock-step run
itself the run-log writer process and the next run's spare writer starting); the semaphore
takes away the hint, not the other CPU's load. A state that is not a dataclass of fixed-shape
float64 arrays (none of the designs' truths today) falls back to the pipe, pickled.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import signal
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from cdcr_ctl.errors import RigError
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.simconfig import load_sim_config

#: While waiting for the other side's semaphore, look this often (s, wall clock) whether the
#: other process is still alive (a dead worker or parent must not leave the other waiting for
#: ever). Not a pacing: a wake-up comes as soon as the semaphore is released.
ALIVE_CHECK_S = 1.0
#: The lock-step rig's ``spin_s`` (s, wall clock; :class:`TruthProcess`). Its loop collects
#: the solve it submitted one cycle before, and submits the next at once in four cycles of
#: five (physics at 200 Hz, loop at 250 Hz): a loop cycle is ~0.4-0.6 ms of wall, so 2 ms
#: covers the gaps of a run and lets both sides sleep when it ends or stalls (a worker
#: descheduled by a busy machine is not waited for on the CPU for longer). Measured on the
#: lock-step benchmark (docs/performance/figures.md): the loop thread's sleep over a
#: 3215-cycle bend 0.2-0.33 s -> 0.01 s, the worker's CPU per cycle ~290 -> ~215 us.
LOCKSTEP_SPIN_S = 0.002
#: Longest wall time one solve may take before the worker counts as stuck (s).
SOLVE_TIMEOUT_S = 60.0

# Slots of the int64 block: request number (-1: stop), answered request number, failures,
# then the K drive counts.
_REQ, _ANS, _FAIL, _COUNTS = 0, 1, 2, 3
# Slots of the float64 block: the solve's thread CPU (s), then the state's arrays, flattened.
_CPU, _STATE = 0, 1


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


def state_shapes(state: Any) -> tuple[tuple[int, ...], ...] | None:
    """The shapes of ``state``'s arrays when it is a dataclass of float64 arrays (it can cross
    in shared memory), else None."""
    if not _float_arrays(state):
        return None
    return tuple(getattr(state, f.name).shape for f in dataclasses.fields(state))


class _Shared:
    """The two shared blocks (int64 and float64) and numpy views of them. ``shapes``: the
    state's array shapes (None: the state goes through the pipe)."""

    def __init__(self, ints: Any, floats: Any, shapes: tuple[tuple[int, ...], ...] | None):
        self.ints = np.frombuffer(ints, dtype=np.int64)
        self.floats = np.frombuffer(floats, dtype=np.float64)
        self.shapes = shapes
        self.sizes = [int(np.prod(s, dtype=np.int64)) for s in shapes] if shapes else []
        self.n_state = sum(self.sizes)

    def put_state(self, state: Any) -> None:
        """(Worker.) Write ``state``'s arrays, flattened in field order; a state whose shapes
        differ from the layout is an error (the same truth makes the same shapes)."""
        fl, o = self.floats, _STATE
        fields = dataclasses.fields(state)
        for f, shape, n in zip(fields, self.shapes or (), self.sizes, strict=True):
            a = getattr(state, f.name)
            if a.shape != shape:
                raise RigError(
                    f"truth worker: state field {f.name} has shape {a.shape}, not {shape}"
                )
            fl[o : o + n] = a.ravel()
            o += n

    def get_state(self, like: Any) -> Any:
        """(Loop process.) The state written by :meth:`put_state`, as the class of ``like``:
        one private copy of the block, each array a view of it (the same bits)."""
        flat = self.floats[_STATE : _STATE + self.n_state].copy()
        arrays, o = [], 0
        for shape, n in zip(self.shapes or (), self.sizes, strict=True):
            arrays.append(flat[o : o + n].reshape(shape))
            o += n
        return type(like)(*arrays)


def _worker(
    sim_path: str,
    ints: Any,
    floats: Any,
    shapes: Any,
    req: Any,
    ans: Any,
    conn: Any,
    parent: int,
    spin_s: float,
) -> None:
    """Solve each request (drive counts in shared memory), answer through shared memory (or the
    pipe when ``shapes`` is None); stop on request number -1 or when the parent is gone. After
    an answer, look for the next request in shared memory for up to ``spin_s`` (s) before
    sleeping on the semaphore (see :class:`TruthProcess`)."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a forked worker has the parent's handlers
    truth = make_truth(load_sim_config(sim_path))
    sh = _Shared(ints, floats, shapes)
    iv, fv = sh.ints, sh.floats
    k = len(iv) - _COUNTS
    last = 0
    while True:
        if spin_s > 0:
            end = time.perf_counter() + spin_s
            while iv[_REQ] == last and time.perf_counter() < end:
                pass
        while not req.acquire(True, ALIVE_CHECK_S):
            if os.getppid() != parent:
                return
        n = last = int(iv[_REQ])
        if n < 0:
            return
        counts = [int(c) for c in iv[_COUNTS : _COUNTS + k]]
        c0 = time.thread_time()
        state = truth.step(counts)
        if shapes is not None:
            sh.put_state(state)
        else:
            conn.send(to_wire(state))
        fv[_CPU] = time.thread_time() - c0
        iv[_FAIL] = truth.failures
        iv[_ANS] = n
        ans.release()


class TruthProcess:
    """Solves the truth of ``sim_path`` in a worker; the results go into ``local`` (a truth of
    the same world in this process, whose ``cell_tensions``/``tip_pose`` the sensors read, and
    whose state gives the layout of the shared memory)."""

    def __init__(
        self, sim_path: str, local: Any, start_method: str = "spawn", spin_s: float = 0.0
    ) -> None:
        """``start_method``: ``spawn`` (a new interpreter, ~1.5 s of imports), or ``fork`` for a
        caller with no other thread yet (the worker then starts in milliseconds). ``spin_s``
        (s, wall clock): how long each side looks for the other's next word in shared memory
        before it sleeps on its semaphore (0: at once). The lock-step rig, whose loop hands
        off a solve almost every cycle, spins (:data:`LOCKSTEP_SPIN_S`): on this VM a wake-up
        of a sleeping CPU costs tens of microseconds and lets other processes in between, so
        each solve started cold; the real-time simulator, whose physics thread submits every
        5 ms, does not."""
        self.spin_s = float(spin_s)
        ctx = multiprocessing.get_context(start_method)
        self.local = local
        self.n_drives = len(local.counts_per_mm)
        shapes = state_shapes(local.state)
        n_state = sum(int(np.prod(s, dtype=np.int64)) for s in shapes) if shapes else 0
        ints = ctx.RawArray("q", _COUNTS + self.n_drives)
        floats = ctx.RawArray("d", _STATE + n_state)
        self._sh = _Shared(ints, floats, shapes)
        self._req, self._ans = ctx.Semaphore(0), ctx.Semaphore(0)
        self._conn, child = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(
            target=_worker,
            args=(
                sim_path,
                ints,
                floats,
                shapes,
                self._req,
                self._ans,
                child,
                os.getpid(),
                self.spin_s,
            ),
            name="lockstep-truth",
            daemon=True,
        )
        self._proc.start()
        child.close()
        self._seq = 0
        self.pending = False
        self.cpu_s = 0.0

    @property
    def pid(self) -> int:
        """The worker's process id."""
        return int(self._proc.pid or 0)

    def submit(self, counts: Sequence[int]) -> None:
        """Start solving for ``counts`` (a result must not be pending)."""
        iv = self._sh.ints
        iv[_COUNTS : _COUNTS + self.n_drives] = counts
        self._seq += 1
        iv[_REQ] = self._seq
        self._req.release()
        self.pending = True

    def collect(self) -> None:
        """Wait for the pending result and make it the world's state. The answer is looked for
        in shared memory for up to ``spin_s`` before the wait on the semaphore, which is then
        taken at once (and orders the state's reads after the worker's writes)."""
        iv, seq = self._sh.ints, self._seq
        if self.spin_s > 0 and iv[_ANS] != seq:
            end = time.perf_counter() + self.spin_s
            while iv[_ANS] != seq and time.perf_counter() < end:
                pass
        waited = 0.0
        while not self._ans.acquire(True, ALIVE_CHECK_S):
            waited += ALIVE_CHECK_S
            if not self._proc.is_alive() or waited >= SOLVE_TIMEOUT_S:
                self.pending = False
                raise RigError(
                    f"lock-step truth worker {'ended' if not self._proc.is_alive() else 'stuck'}"
                    f" (exit code {self._proc.exitcode}) with solve {self._seq} pending"
                )
        self.pending = False
        sh = self._sh
        if sh.shapes is not None:
            state = sh.get_state(self.local._state)
        else:
            state = from_wire(self._conn.recv(), self.local._state)
        with self.local._lock:
            self.local._state = state
            self.local.steps += 1
        self.local.failures = int(sh.ints[_FAIL])
        self.cpu_s += float(sh.floats[_CPU])

    def close(self) -> None:
        try:
            if self.pending:
                self.collect()
        except RigError:
            pass
        self._sh.ints[_REQ] = -1
        self._req.release()
        self._proc.join(2.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(1.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(1.0)
        self._conn.close()


__all__ = ["LOCKSTEP_SPIN_S", "TruthProcess", "from_wire", "state_shapes", "to_wire"]
