"""The loop's records and constants: its config, a run as ``status`` shows it, the hold setpoint,
the posted-command form, the per-stage cycle counters (:data:`STAGES`) and the tip history the
tracker-divergence check compares against.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Cable offsets (jogs, re-enable slack, compensation switches) ramp out at this fraction of the
#: cable velocity limit.
OFFSET_RAMP_FRACTION = 0.5
#: An offset ramps only while the whole command step of the cycle stays within this fraction of
#: the cable velocity limit (the margin keeps the supervisor's check from firing on rounding).
COMMAND_STEP_FRACTION = 0.95
#: Python's GIL switch interval while the loop runs (s); see :meth:`ControlLoop.start`.
GIL_SWITCH_INTERVAL_S = 5e-5
#: Tracker-vs-model divergence: how much longer than the tracker sample's age the world may lag
#: the command (drive following delay, the tracker's own exposure-to-send latency), s.
DIVERGENCE_LAG_S = 0.05
#: Cause of a stop the operator (or the daemon's shutdown) asked for: the run ends "stopped".
OPERATOR_STOP = "operator_stop"
#: Trip cause when a run log's ring (or queue) is full in real time: the writer fell behind and
#: a row was refused (QUICK_STOP; the log keeps every row it took and names the cause).
LOG_OVERFLOW = "log_overflow"


class Hold:
    """A constant setpoint."""

    def __init__(self, psi: np.ndarray) -> None:
        self._psi = np.array(psi, dtype=float)

    @property
    def duration_s(self) -> float:
        return math.inf

    def sample(self, t_s: float) -> np.ndarray:
        return self._psi


@dataclass
class RunInfo:
    """One run (trajectory or jog) as shown in ``status``."""

    id: str
    name: str
    state: str  # running | completed | stopped | tripped
    duration_s: float
    compensation: str
    started_t_s: float
    elapsed_s: float = 0.0
    end_reason: str = ""
    log_dir: str = ""
    #: The loop's counters over this run's rows (issue #21: counters and rows agree): the
    #: ``cycle`` of its first and last logged row, rows its log took, and the deadlines missed
    #: and long cycles the loop's global counters added that these rows report (a row reports
    #: those since the previous cycle: ``late: N cycles missed``, ``long: previous cycle``).
    first_cycle: int = -1
    last_cycle: int = -1
    rows: int = 0
    missed_cycles: int = 0
    long_cycles: int = 0


@dataclass
class LoopConfig:
    """Loop parameters derived from the rig config (see :func:`cdcr_ctl.control.build`)."""

    period_s: float
    counts_per_mm: np.ndarray  # (K,)
    compensation: str = "model"
    cable_velocity_mm_s: float = 50.0


#: A command posted to the loop thread: (kind, payload). Kinds: ``follow`` (source, run, sink),
#: ``offset`` (cable offset target, mm), ``home`` (counts), ``sink``, ``mode``, ``stop``
#: (Reaction), ``reenabled``. Applied at the start of the next cycle in the order posted.
_Command = tuple[str, Any]


#: Stages of a cycle timed by :class:`LoopCounters` (``time.perf_counter`` marks): read inputs
#: and pending commands, sample the setpoint; inverse kinematics and compensation; limits and
#: faults; RPDOs + SYNC out; the log row.
STAGES = ("inputs", "model", "checks", "send", "log")


@dataclass
class LoopCounters:
    """Loop statistics (written by the loop thread only). ``stage_s``: wall time spent per
    stage (:data:`STAGES`) summed over all cycles; ``stage_max_us``: the longest of each;
    ``work_cpu_s``: the loop thread's CPU time in the cycles' work (``time.thread_time``);
    ``cpu_s``: the loop thread's CPU time when it stopped (waiting and spinning included)."""

    cycles: int = 0
    #: Cycles whose work ran past the period; deadlines missed because of them (no cycle ran).
    long_cycles: int = 0
    missed_cycles: int = 0
    #: Operator stops acted on from the stop flag (:class:`StopFlag`).
    flag_stops: int = 0
    rows_logged: int = 0
    rows_dropped: int = 0
    trips: int = 0
    last_cycle_us: float = 0.0
    max_cycle_us: float = 0.0
    cpu_s: float = 0.0
    work_cpu_s: float = 0.0
    stage_s: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    stage_max_us: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    #: Over the long cycles only (issue #21: where their time went): wall time per stage, and
    #: the loop thread's CPU time in them (the rest it waited: for the interpreter lock, a
    #: higher-priority thread, a page, a system call).
    long_stage_s: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    long_wall_s: float = 0.0
    long_cpu_s: float = 0.0
    _timed_from: int = 0
    _marks: Sequence[float] = ()

    def stage_mean_us(self) -> dict[str, float]:
        """Mean wall time per cycle of each stage (us) since the last :meth:`reset_timing`."""
        n = max(self.cycles - self._timed_from, 1)
        return {k: round(v / n * 1e6, 1) for k, v in self.stage_s.items()}

    def work_cpu_us(self) -> float:
        """Mean CPU time of a cycle's work (us) since the last :meth:`reset_timing`."""
        return self.work_cpu_s / max(self.cycles - self._timed_from, 1) * 1e6

    def reset_timing(self) -> None:
        """Start the stage times and the longest cycle afresh (e.g. after start-up)."""
        self._timed_from = self.cycles
        self.max_cycle_us = 0.0
        self.work_cpu_s = 0.0
        for k in STAGES:
            self.stage_s[k] = 0.0
            self.stage_max_us[k] = 0.0

    def _stages(self, marks: Sequence[float]) -> None:
        """Add one cycle's stage times from its ``len(STAGES) + 1`` perf_counter marks."""
        self._marks = marks
        total, worst = self.stage_s, self.stage_max_us
        t0 = marks[0]
        for name, t1 in zip(STAGES, marks[1:], strict=False):
            dt = t1 - t0
            t0 = t1
            total[name] += dt
            us = dt * 1e6
            if us > worst[name]:
                worst[name] = us

    def _long(self, wall_s: float, cpu_s: float) -> None:
        """Add one long cycle: its wall and CPU time, and its stages (its marks, as given to
        :meth:`_stages`)."""
        self.long_wall_s += wall_s
        self.long_cpu_s += cpu_s
        marks = self._marks
        for name, t0, t1 in zip(STAGES, marks, marks[1:], strict=False):
            self.long_stage_s[name] += t1 - t0


class TipHistory:
    """The model's tip over the last fraction of a second, to compare a tracker sample with the
    command of the time it shows (robot base frame, mm; loop clock, s).

    A tracker sample ``age`` s old shows the world as it was then, and the world lags the command
    by the drives' following delay: comparing it with the current command's tip would count the
    distance the tip travelled meanwhile as divergence (at 100 mm/s and 50 ms, 5 mm).
    :meth:`distance` is the smallest distance from the sample to the model tips commanded between
    ``age + lag_s`` and ``age - period`` s ago.
    """

    def __init__(self, capacity: int) -> None:
        # Plain lists of floats: a few dozen entries, looked through every cycle, cost less
        # than the ten numpy calls on arrays this small (the same doubles, the same results).
        self._t = [-math.inf] * capacity
        self._tip = [(math.nan, math.nan, math.nan)] * capacity
        self._i = 0
        #: Every time added so far was >= the one before (the loop's clock): the entries with
        #: t >= a bound are then the newest ones, and :meth:`distance` looks at those only.
        self._ordered = True

    def add(self, t_s: float, tip_mm: np.ndarray | Sequence[float]) -> None:
        n = len(self._t)
        i = self._i % n
        t = float(t_s)
        if self._i and not t >= self._t[(i - 1) % n]:
            self._ordered = False
        self._t[i] = t
        x, y, z = np.asarray(tip_mm, dtype=float).tolist()
        self._tip[i] = (x, y, z)
        self._i += 1

    def distance(
        self,
        now_s: float,
        tip_mm: np.ndarray | list[float],
        age_s: float,
        lag_s: float,
        period_s: float,
    ) -> float:
        """Smallest distance (mm) from the measured ``tip_mm`` to the model tips commanded in
        [now - age - lag, now - age + period]; the newest model tip when none is in the window;
        NaN when any of those tips is NaN. The squares summed left to right, the least of them
        taken and one square root of it (the square root is monotonic: the least root).

        One pass, newest first: while the times were added in order it stops at the first entry
        older than the window (the loop's clock: a few entries, not the whole history), else it
        looks at every entry."""
        px, py, pz = tip_mm if type(tip_mm) is list else np.asarray(tip_mm, dtype=float).tolist()
        t_sample = now_s - age_s
        lo, hi = t_sample - lag_s, t_sample + period_s
        ts, tips, i, ordered = self._t, self._tip, self._i, self._ordered
        n = len(ts)
        if ordered and i < n and lo == -math.inf:
            return math.nan  # the entries never written (t = -inf, NaN tips) are in the window
        best = math.inf
        while True:
            found = False
            for j in range(min(i, n) if ordered else n):
                k = (i - 1 - j) % n
                t = ts[k]
                if t < lo:
                    if ordered:
                        break
                    continue
                if t <= hi:
                    found = True
                    x, y, z = tips[k]
                    dx, dy, dz = x - px, y - py, z - pz
                    d2 = dx * dx + dy * dy + dz * dz
                    if d2 != d2:
                        return math.nan
                    if d2 < best:
                        best = d2
            if found:
                return math.sqrt(best)
            lo = hi = max(ts)  # none in the window: the newest tip(s), by a full pass
            ordered = False
