"""The real-time loop: setpoint -> inverse kinematics -> compensation -> limits -> RPDOs + SYNC.

One thread, fixed rate on absolute monotonic deadlines (:class:`~cdcr_ctl.control.timing.Ticker`).
Per cycle:

1. read the latest drive feedback, load-cell tensions and tracker tip (non-blocking);
2. sample the setpoint source (trajectory, jog move or hold) at the cycle time;
3. ideal inverse kinematics ``q_nominal`` and the compensated command ``q_cmd`` (Qi et al. 2023
   eq. 37, mode off/model/measured);
4. the safety supervisor checks commands and measurements; a trip applies its reaction;
5. targets in counts (``home + q_cmd * counts_per_mm``) go out as RPDOs followed by SYNC;
6. one row goes to the run log (queued; the loop keeps the cycle's numbers in one array, the
   writer thread makes the columns and does the disk I/O: :class:`CycleRow`).

Commands from the daemon's socket threads are posted under a lock and picked up at the start of a
cycle (the lock is looked at only when something was posted); nothing on the loop's path blocks
on them. :class:`LoopCounters` times each stage of the cycle (:data:`STAGES`) and its CPU time.
"""

from __future__ import annotations

import copy
import gc
import itertools
import logging
import math
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cdcr_ctl.control.clock import LoopClock, wall_clock
from cdcr_ctl.control.ports import (
    DrivePort,
    RobotModelPort,
    SetpointSource,
    TensionPort,
    TipPort,
)
from cdcr_ctl.control.stopflag import StopFlag
from cdcr_ctl.control.supervisor import CycleCheck, Reaction, Supervisor, Trip
from cdcr_ctl.errors import ModelError

log = logging.getLogger(__name__)

#: Cable offsets (jogs, re-enable slack, compensation switches) ramp out at this fraction of the
#: cable velocity limit.
OFFSET_RAMP_FRACTION = 0.5
#: Python's GIL switch interval while the loop runs (s); see :meth:`ControlLoop.start`.
GIL_SWITCH_INTERVAL_S = 5e-5
#: Tracker-vs-model divergence: how much longer than the tracker sample's age the world may lag
#: the command (drive following delay, the tracker's own exposure-to-send latency), s.
DIVERGENCE_LAG_S = 0.05
#: Cause of a stop the operator (or the daemon's shutdown) asked for: the run ends "stopped".
OPERATOR_STOP = "operator_stop"


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


@dataclass
class LoopConfig:
    """Loop parameters derived from the rig config (see :func:`cdcr_ctl.control.build`)."""

    period_s: float
    counts_per_mm: np.ndarray  # (K,)
    compensation: str = "model"
    cable_velocity_mm_s: float = 50.0


class RowLayout:
    """The columns of a loop row (run-log names) and, per column, where its value sits in the
    cycle's flat array ``[psi (S x 2), q_nominal, q_cmd, q_act, tension (K each), tip (3)]``."""

    def __init__(self, n_segments: int, n_cables: int) -> None:
        S, K = n_segments, n_cables
        per_cable = ("q_nominal_mm", "q_cmd_mm", "q_act_mm", "tension_N")
        self.keys = (
            [f"seg{i}_{a}_cmd_rad" for i in range(1, S + 1) for a in ("theta", "phi")]
            + [f"cable{k}_{c}" for k in range(1, K + 1) for c in per_cable]
            + ["tip_x_mm", "tip_y_mm", "tip_z_mm"]
        )
        order = list(range(2 * S))
        order += [2 * S + c * K + k for k in range(K) for c in range(len(per_cable))]
        order += [2 * S + len(per_cable) * K + j for j in range(3)]
        self.order = np.array(order, dtype=np.intp)


class CycleRow(Mapping[str, Any]):
    """One cycle's log row: ``t_s``, ``cycle``, the :class:`RowLayout` columns, ``lateness_us``,
    ``event``. The loop thread only keeps the cycle's numbers (one array); the mapping is made
    on first use, by the run-log writer's thread or a status request, off the loop's path."""

    __slots__ = ("_cycle", "_dict", "_event", "_lateness_s", "_layout", "_t_s", "_values")

    def __init__(
        self,
        layout: RowLayout,
        t_s: float,
        cycle: int,
        values: np.ndarray,
        lateness_s: float,
        event: str,
    ) -> None:
        self._layout, self._t_s, self._cycle = layout, t_s, cycle
        self._values, self._lateness_s, self._event = values, lateness_s, event
        self._dict: dict[str, Any] | None = None

    def columns(self) -> dict[str, Any]:
        """The row as a plain dict (made once)."""
        d = self._dict
        if d is None:
            values = self._values[self._layout.order].tolist()
            d = {"t_s": round(self._t_s, 6), "cycle": self._cycle}
            d.update(zip(self._layout.keys, values, strict=True))
            d["lateness_us"] = round(self._lateness_s * 1e6, 1)
            d["event"] = self._event
            self._dict = d
        return d

    def __getitem__(self, key: str) -> Any:
        return self.columns()[key]

    def get(self, key: str, default: Any = None) -> Any:
        return self.columns().get(key, default)

    def __contains__(self, key: object) -> bool:
        return key in self.columns()

    def __iter__(self) -> Iterator[str]:
        return iter(self.columns())

    def __len__(self) -> int:
        return len(self.columns())

    def __repr__(self) -> str:
        return f"CycleRow({self.columns()!r})"


RowSink = Callable[[Mapping[str, float | str]], None]


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
    _timed_from: int = 0

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
        total, worst = self.stage_s, self.stage_max_us
        for name, t0, t1 in zip(STAGES, marks, marks[1:], strict=False):
            dt = t1 - t0
            total[name] += dt
            if dt * 1e6 > worst[name]:
                worst[name] = dt * 1e6


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
        self._t = np.full(capacity, -np.inf)
        self._tip = np.full((capacity, 3), np.nan)
        self._i = 0

    def add(self, t_s: float, tip_mm: np.ndarray) -> None:
        i = self._i % len(self._t)
        self._t[i] = t_s
        self._tip[i] = tip_mm
        self._i += 1

    def distance(
        self, now_s: float, tip_mm: np.ndarray, age_s: float, lag_s: float, period_s: float
    ) -> float:
        """Smallest distance (mm) from the measured ``tip_mm`` to the model tips commanded in
        [now - age - lag, now - age + period]; the newest model tip when none is in the window."""
        t_sample = now_s - age_s
        sel = (self._t >= t_sample - lag_s) & (self._t <= t_sample + period_s)
        if not sel.any():
            sel = self._t == self._t.max()
        return float(np.min(np.linalg.norm(self._tip[sel] - tip_mm, axis=1)))


class ControlLoop:
    """The fixed-rate loop. Start with :meth:`start`, stop with :meth:`stop` (joins the thread).

    ``clock`` paces the cycles (:class:`~cdcr_ctl.control.clock.LoopClock`): by default a fresh
    wall clock (:func:`~cdcr_ctl.control.clock.wall_clock`) made when the loop starts; the
    lock-step simulator passes its simulated clock. Every time the loop keeps (cycle time, run
    time) is on that clock.
    """

    def __init__(
        self,
        cfg: LoopConfig,
        model: RobotModelPort,
        drives: DrivePort,
        tensions: TensionPort,
        tip: TipPort,
        supervisor: Supervisor,
        home_counts: Sequence[int] | None = None,
        on_trip: Callable[[Trip], None] | None = None,
        clock: LoopClock | None = None,
    ) -> None:
        self.cfg = cfg
        self.model = model
        self.drives = drives
        self.tensions = tensions
        self.tip_port = tip
        self.supervisor = supervisor
        self.on_trip = on_trip
        K = model.n_cables
        self.home_counts = (
            np.zeros(K, dtype=np.int64) if home_counts is None else np.array(home_counts)
        )
        self._clock = clock
        self.ticker: LoopClock = clock if clock is not None else wall_clock(cfg.period_s)
        self.counters = LoopCounters()
        self._lock = threading.Lock()
        self._pending: list[_Command] = []
        #: Set (under the lock) with every posted command: the cycle looks at the lock only then.
        self._has_pending = False
        self._stop_evt = threading.Event()
        #: Read first thing in every cycle; see :class:`StopFlag`.
        self.stop_flag = StopFlag()
        self._flag_seen = 0
        self._missed_now = 0
        #: An event of this cycle decided outside the checks (an operator stop) for its row.
        self._row_event = ""
        self._thread: threading.Thread | None = None
        self._run_ids = itertools.count(1)
        # State owned by the loop thread.
        S = model.n_segments
        self._psi_cmd = np.zeros((S, 2))
        self._source: SetpointSource = Hold(self._psi_cmd)
        self._t_source0 = 0.0
        self._run: RunInfo | None = None
        self._sink: Any = None
        self._q_cmd = np.zeros(K)
        self._q_prev = np.zeros(K)
        self._q_offset = np.zeros(K)
        self._q_offset_target = np.zeros(K)
        self._model_state = model.new_state()
        self._last_row: Mapping[str, Any] = {}
        self._row_layout = RowLayout(S, K)
        self._stopped_drives = False
        self._paused = False
        self._manual_sink: Any = None
        self._end_after_cycle: tuple[str, str] | None = None
        self._t_last_cmd = -math.inf
        # The compensation mode of the last run stays in force while holding, so a run's end does
        # not step the command; the ``compensation`` command changes it.
        self._mode = cfg.compensation
        self._mode_applied = cfg.compensation
        self.history: list[RunInfo] = []
        self._tips = TipHistory(
            max(
                4,
                math.ceil((supervisor.limits.sensor_timeout_s + DIVERGENCE_LAG_S) / cfg.period_s)
                + 2,
            )
        )

    # ---------------------------------------------------------------- commands (any thread)
    def start(self) -> None:
        # The loop thread must get the GIL back soon after its deadline: with the default 5 ms
        # switch interval a busy sensor or bus thread could hold it for a whole cycle.
        sys.setswitchinterval(min(sys.getswitchinterval(), GIL_SWITCH_INTERVAL_S))
        self._thread = threading.Thread(target=self._run_loop, name="control-loop", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop_evt.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def busy(self) -> bool:
        """Whether the loop has more to do than hold still: a run, a posted command not yet
        taken up, a run ending, a cable offset still ramping, stopping. (The lock-step clock
        advances only while it has: an idle simulated rig stands still.)"""
        return (
            self._run is not None
            or self._has_pending
            or self._end_after_cycle is not None
            or bool((self._q_offset_target != self._q_offset).any())
            or self._stop_evt.is_set()
        )

    @property
    def current_run(self) -> RunInfo | None:
        """The run the loop is following now (None: holding); posted runs count once taken up."""
        return self._run

    def follow(
        self, source: SetpointSource, name: str, compensation: str | None, sink: Any = None
    ) -> RunInfo:
        """Start following ``source`` from the next cycle; ``sink`` receives one row per cycle."""
        run = RunInfo(
            id=f"run{next(self._run_ids)}",
            name=name,
            state="running",
            duration_s=source.duration_s,
            compensation=compensation or self.cfg.compensation,
            started_t_s=time.monotonic(),
            log_dir=str(getattr(sink, "run_dir", "") or ""),
        )
        with self._lock:
            self._post("follow", (source, run, sink))
        return run

    def _post(self, kind: str, payload: Any = None) -> None:
        """Queue a command for the loop thread (caller holds the lock)."""
        self._pending.append((kind, payload))
        self._has_pending = True

    def jog_cable(self, cable: int, delta_mm: float) -> None:
        """Move cable ``cable`` (0-based) by ``delta_mm`` at the cable velocity limit."""
        with self._lock:
            target = self._offset_target_after_pending()
            target[cable] += delta_mm
            self._post("offset", target)

    def _offset_target_after_pending(self) -> np.ndarray:
        """The cable offset target (mm) once the posted commands are applied (caller holds the
        lock): the last jog's, zero after a new run or a home, else the loop's own."""
        for kind, payload in reversed(self._pending):
            if kind == "offset":
                return payload.copy()
            if kind in ("follow", "home"):
                return np.zeros_like(self._q_offset_target)
        return self._q_offset_target.copy()

    def pause(self, paused: bool) -> None:
        """While paused the loop keeps reading feedback and logging but sends no RPDO or SYNC
        (homing runs the drives in their own mode)."""
        self._paused = paused

    def set_home(self, home_counts: Sequence[int]) -> None:
        """New home positions (counts at q = 0): the robot is straight there."""
        with self._lock:
            self._post("home", np.array(home_counts, dtype=np.int64))

    def attach_sink(self, sink: Any) -> None:
        """Log every cycle to ``sink`` (a manual log) or stop doing so (``None``)."""
        with self._lock:
            self._post("sink", sink)

    def set_compensation(self, mode: str) -> None:
        """Compensation mode for holding and for runs that do not name one."""
        with self._lock:
            self._post("mode", mode)

    def request_stop(self, reaction: Reaction) -> None:
        with self._lock:
            self._post("stop", reaction)

    @property
    def last_row(self) -> Mapping[str, Any]:
        """The latest cycle's log row (immutable once made; empty before the first cycle)."""
        return self._last_row

    @property
    def psi_cmd(self) -> np.ndarray:
        return self._psi_cmd.copy()

    def model_state(self) -> object:
        """A copy of the model's friction memory (for planning from where the loop is; a copy
        taken from another thread may mix two cycles' values: an estimate, not the state)."""
        return copy.deepcopy(self._model_state)

    @property
    def q_cmd(self) -> np.ndarray:
        """The last command sent (mm, offset included)."""
        return self._q_cmd.copy()

    def adopt_pose(self, psi: np.ndarray) -> None:
        """Hold at ``psi`` from the next cycle (the pose the arm was found in at start-up);
        the rest between the drives and its command is absorbed on enable."""
        with self._lock:
            self._post("pose", np.array(psi, dtype=float))

    def snapshot(self) -> dict[str, Any]:
        """Status for the socket: last cycle's values, timing, current run."""
        run = self._run
        return {
            "cycles": self.counters.cycles,
            "timing": self.ticker.stats.summary(),
            "cycle_time_max_us": round(self.counters.max_cycle_us, 1),
            "long_cycles": self.counters.long_cycles,
            "missed_cycles": self.counters.missed_cycles,
            "flag_stops": self.counters.flag_stops,
            "rows_logged": self.counters.rows_logged,
            "rows_dropped": self.counters.rows_dropped,
            "cpu_s": round(self.counters.cpu_s, 3),
            "psi_cmd_rad": self._psi_cmd.tolist(),
            "last": {
                k: v
                for k, v in self._last_row.items()
                if not isinstance(v, float) or math.isfinite(v)
            },
            "run": None if run is None else run.__dict__.copy(),
        }

    # ---------------------------------------------------------------- the loop thread
    def _run_loop(self) -> None:
        # Everything allocated during start-up moves to the permanent generation, so the
        # collector's full passes stay short while the loop runs (they run in whatever thread
        # allocates, this one included).
        gc.freeze()
        cpu0 = time.thread_time()
        if self._clock is None:
            self.ticker = wall_clock(self.cfg.period_s)
        t_start = self.ticker.now()
        while not self._stop_evt.is_set():
            deadline, lateness = self.ticker.wait()
            t0 = time.perf_counter()
            c0 = time.thread_time()
            try:
                self._cycle(deadline - t_start, deadline, lateness)
            except Exception as exc:  # a bug must not leave the drives running unattended
                log.exception("control loop cycle failed")
                self._cycle_failed(exc, deadline - t_start)
            self.counters.work_cpu_s += time.thread_time() - c0
            dt_us = (time.perf_counter() - t0) * 1e6
            self.counters.last_cycle_us = dt_us
            self.counters.max_cycle_us = max(self.counters.max_cycle_us, dt_us)
            self.counters.cycles += 1
            if dt_us > self.cfg.period_s * 1e6:
                self.counters.long_cycles += 1
            skipped = self.ticker.stats.skipped
            self.ticker.done()
            # Deadlines skipped after this cycle: the next row says so (its lateness counts
            # from the first missed deadline) and so do the counters.
            self._missed_now = self.ticker.stats.skipped - skipped
            self.counters.missed_cycles += self._missed_now
        self.counters.cpu_s = time.thread_time() - cpu0
        self._finish_run("stopped", "loop stopped")

    def _cycle_failed(self, exc: Exception, t_s: float) -> None:
        """A cycle raised (a bug): latch it and quick-stop the drives; the loop goes on."""
        trip = Trip("loop_exception", Reaction.QUICK_STOP, f"{type(exc).__name__}: {exc}", t_s)
        try:
            self.supervisor.external(trip.cause, trip.reaction, trip.detail, t_s)
            self._react(trip)
        except Exception:
            log.exception("reacting to a failed cycle failed")

    def _take_pending(self, now: float) -> None:
        seq = self.stop_flag.requested
        if seq != self._flag_seen:
            self._flag_seen = seq
            reaction = Reaction(self.stop_flag.store[StopFlag.REACTION])
            self.counters.flag_stops += 1
            self._row_event = OPERATOR_STOP
            self._react(Trip(OPERATOR_STOP, reaction, "stop requested", now))
            self.stop_flag.acted(seq, self.counters.cycles)
        if not self._has_pending:
            return
        with self._lock:
            commands, self._pending = self._pending, []
            self._has_pending = False
        for kind, payload in commands:
            self._apply(kind, payload, now)

    def _apply(self, kind: str, payload: Any, now: float) -> None:
        """One posted command, on the loop thread."""
        if kind == "stop":
            self._row_event = OPERATOR_STOP
            self._react(Trip(OPERATOR_STOP, payload, "stop requested", now))
        elif kind == "follow":
            source, run, sink = payload
            if self.supervisor.trip is not None:
                reason = f"refused: supervisor tripped ({self.supervisor.trip.cause})"
                run.state, run.end_reason = "refused", reason
                self.history.append(run)
                if sink is not None:
                    sink.close(reason, outcome="refused", wait=False)
            else:
                self._finish_run("stopped", "replaced by a new run")
                self._source, self._t_source0 = source, now
                # Cable offsets (single-cable jogs, re-enable slack) ramp out at the velocity
                # limit: a run commands absolute displacements.
                self._q_offset_target = np.zeros_like(self._q_offset)
                self._run, self._sink = run, sink
        elif kind == "offset":
            self._q_offset_target = payload
        elif kind == "mode":
            self._mode = payload
            self.cfg.compensation = payload
        elif kind == "reenabled":
            self._resume_after_enable()
        elif kind == "home":
            self.home_counts = payload
            self._psi_cmd = np.zeros_like(self._psi_cmd)
            self._source, self._t_source0 = Hold(self._psi_cmd), now
            self._q_offset[:] = 0.0
            self._q_offset_target[:] = 0.0
            self._model_state = self.model.new_state()
        elif kind == "sink":
            self._manual_sink = payload
        elif kind == "pose":
            # Hold where the arm is: the command of the pose plus an offset that makes it the
            # drives' actual positions, so no cycle (sent or only checked) steps.
            self._psi_cmd = payload
            self._source, self._t_source0 = Hold(payload), now
            self._model_state = self.model.new_state()
            mode = "model" if self._mode == "measured" else self._mode
            q_pose = self.model.q_command(
                payload, self.model.q_nominal(payload), self._model_state, mode, None
            )
            fb = self.drives.feedback()
            q_act = (
                np.array([f.position_counts for f in fb]) - self.home_counts
            ) / self.cfg.counts_per_mm
            self._q_offset = q_act - q_pose
            self._q_offset_target = self._q_offset.copy()
            self._q_cmd = q_act.copy()
        else:  # pragma: no cover - a programming error
            raise ValueError(f"unknown loop command {kind!r}")

    def _cycle(self, t_s: float, now: float, lateness_s: float) -> None:
        clock = time.perf_counter
        m0 = clock()
        self._take_pending(now)
        fb = self.drives.feedback()
        force_N, force_age = self.tensions.latest()
        tip_mm, tip_age = self.tip_port.latest()

        # Setpoint
        t_run = now - self._t_source0
        psi = np.asarray(self._source.sample(min(t_run, self._source.duration_s)), dtype=float)
        run = self._run
        if run is not None:
            run.elapsed_s = min(t_run, run.duration_s)
        # Offsets ramp at half the velocity limit, leaving the other half to the trajectory.
        gap = self._q_offset_target - self._q_offset
        if gap.any():
            step = OFFSET_RAMP_FRACTION * self.cfg.cable_velocity_mm_s * self.cfg.period_s
            self._q_offset += np.clip(gap, -step, step)
        m1 = clock()

        # Inverse kinematics and compensation
        q_nom = self.model.q_nominal(psi)
        if run is not None:
            self._mode = run.compensation
        mode = self._mode
        mode_changed = mode != self._mode_applied
        self._mode_applied = mode
        measured = force_N if mode == "measured" else None
        try:
            q_cmd = self.model.q_command(psi, q_nom, self._model_state, mode, measured)
        except ModelError as exc:
            # The pose needs tension the cables cannot give (or the solver failed): hold the last
            # command rather than guess.
            self._react(Trip("model_unreachable", Reaction.HOLD, str(exc), t_s))
            psi, q_cmd = self._psi_cmd, self._q_cmd - self._q_offset
        if mode_changed and self.counters.cycles > 0:
            # Switching compensation steps the command by delta: take the step into the offset
            # and let it ramp out instead of jumping (and tripping the velocity limit).
            self._q_offset = self._q_cmd - q_cmd
            self._q_offset_target = np.zeros_like(self._q_offset)
        q_cmd = q_cmd + self._q_offset
        m2 = clock()

        # Limits
        tip_err = math.nan  # no tracker (sample): nothing to compare the model tip with
        if self.supervisor.use_tracker:
            self._tips.add(now, self.model.tip(psi))
            if np.isfinite(tip_mm).all():
                tip_err = self._tips.distance(
                    now, tip_mm, tip_age, DIVERGENCE_LAG_S, self.cfg.period_s
                )
        moving = run is not None and run.state == "running"
        trip = self.supervisor.check(
            CycleCheck(
                t_s=t_s,
                # Real time since the last command: after a late cycle the step is larger but so
                # is the time it covers (the velocity limit is on mm/s, not mm per cycle).
                dt_s=max(now - self._t_last_cmd, self.cfg.period_s),
                q_cmd_mm=q_cmd.tolist(),
                q_prev_mm=self._q_cmd.tolist(),
                tension_N=force_N.tolist(),
                tension_age_s=force_age.tolist(),
                tip_error_mm=tip_err,
                tip_age_s=tip_age,
                moving=moving,
            )
        )
        fault = self.drives.first_fault()
        if fault is not None and not self._stopped_drives:
            trip = self.supervisor.external(fault[0], Reaction.QUICK_STOP, fault[1], t_s) or trip
        event = ""
        if trip is not None:
            event = trip.cause
            self._react(trip)
        worst = self.supervisor.cycle_worst
        if worst is not None and worst.reaction >= Reaction.HOLD:
            q_cmd = self._q_cmd.copy()  # never send a command that violates a limit
            psi = self._psi_cmd
        if run is not None and run.state == "running" and t_run >= run.duration_s:
            self._end_after_cycle = ("completed", "trajectory completed")
        m3 = clock()

        # Targets out: RPDOs then SYNC
        if self._paused:
            targets = None
        elif self._stopped_drives:
            # Drives are quick-stopped: follow the actual positions so re-enabling does not jump.
            targets = [f.position_counts for f in fb]
        else:
            targets = np.rint(self.home_counts + q_cmd * self.cfg.counts_per_mm).astype(np.int64)
            targets = targets.tolist()
        if targets is not None:
            self.drives.send_cycle(targets)
        self._q_prev, self._q_cmd, self._psi_cmd = self._q_cmd, q_cmd, psi
        self._t_last_cmd = now
        m4 = clock()

        # Log: the row keeps this cycle's numbers; the writer thread makes the columns.
        q_act = (
            np.array([f.position_counts for f in fb]) - self.home_counts
        ) / self.cfg.counts_per_mm
        row = self._row(t_s, psi, q_nom, q_cmd, q_act, force_N, tip_mm, lateness_s, event)
        self._last_row = row
        for sink in (self._sink, self._manual_sink):
            if sink is None:
                continue
            if sink.write(row):
                self.counters.rows_logged += 1
            else:
                self.counters.rows_dropped += 1
            failure = getattr(sink, "failure", None)
            if failure and self.supervisor.trip is None:
                # Latched in the supervisor like any trip: status names it, runs are refused.
                trip = self.supervisor.external(
                    "log_write_failed", Reaction.HALT, str(failure), t_s
                )
                if trip is not None:
                    self._react(trip)
        if self._end_after_cycle is not None:
            self._finish_run(*self._end_after_cycle)
            self._end_after_cycle = None
        self.counters._stages((m0, m1, m2, m3, m4, clock()))

    def _row(self, t_s, psi, q_nom, q_cmd, q_act, force_N, tip_mm, lateness_s, event) -> CycleRow:
        layout = self._row_layout
        # One fresh array: later cycles may reuse the arrays they were given.
        values = np.concatenate((np.ravel(psi), q_nom, q_cmd, q_act, force_N, tip_mm))
        if self._row_event:
            event = f"{self._row_event}; {event}" if event else self._row_event
            self._row_event = ""
        missed = self._missed_now
        if missed:
            # The deadlines before this cycle were skipped: its lateness counts from the first.
            lateness_s += missed * self.cfg.period_s
            note = f"late: {missed} cycles missed"
            event = f"{event}; {note}" if event else note
        return CycleRow(layout, t_s, self.counters.cycles, values, lateness_s, event)

    def _react(self, trip: Trip) -> None:
        self.counters.trips += 1
        log.warning("supervisor: %s -> %s (%s)", trip.cause, trip.reaction.name, trip.detail)
        if trip.reaction is Reaction.QUICK_STOP and not self._stopped_drives:
            self.drives.quick_stop()
            self._stopped_drives = True
        if trip.reaction >= Reaction.HOLD:
            self._source, self._t_source0 = Hold(self._psi_cmd), self.ticker.now()
            self._q_offset_target = self._q_offset.copy()
            if self._run is not None:
                state = "stopped" if trip.cause == OPERATOR_STOP else "tripped"
                self._end_after_cycle = (state, f"{trip.cause}: {trip.detail}")
        if self.on_trip is not None:
            self.on_trip(trip)

    def _finish_run(self, state: str, reason: str) -> None:
        run, sink = self._run, self._sink
        self._run, self._sink = None, None
        if run is not None:
            run.state, run.end_reason = state, reason
            self.history.append(run)
            if state != "completed":
                self._source, self._t_source0 = Hold(self._psi_cmd), self.ticker.now()
        if sink is not None:
            # Never wait for the writer's fsync on the loop thread.
            sink.close(reason, outcome=state, wait=False)

    def drives_reenabled(self) -> None:
        """Called by the daemon after re-enabling drives: resume sending computed targets."""
        with self._lock:
            self._post("reenabled")

    def _resume_after_enable(self) -> None:
        # Absorb the difference between where the drives are and where the command is into the
        # cable offset and hold there: no jump on re-enable. The next run ramps it out.
        fb = self.drives.feedback()
        q_act = (
            np.array([f.position_counts for f in fb]) - self.home_counts
        ) / self.cfg.counts_per_mm
        self._q_offset = self._q_offset + (q_act - self._q_cmd)
        self._q_offset_target = self._q_offset.copy()
        # The drives are at q_act: the next command's velocity is measured from there, not from
        # the command computed (but not sent) while they were stopped.
        self._q_cmd = q_act.copy()
        self._stopped_drives = False


__all__ = [
    "STAGES",
    "ControlLoop",
    "CycleRow",
    "Hold",
    "LoopConfig",
    "RowLayout",
    "RunInfo",
    "StopFlag",
    "field",
]
