"""The real-time loop: setpoint -> inverse kinematics -> compensation -> limits -> RPDOs + SYNC.

One thread, fixed rate on absolute monotonic deadlines (:class:`~cdcr_ctl.control.timing.Ticker`).
Per cycle:

1. read the latest drive feedback, load-cell tensions and tracker tip (non-blocking);
2. sample the setpoint source (trajectory, jog move or hold) at the cycle time;
3. ideal inverse kinematics ``q_nominal`` and the compensated command ``q_cmd`` (Qi et al. 2023
   eq. 37, mode off/model/measured);
4. the safety supervisor checks commands and measurements; a trip applies its reaction;
5. targets in counts (``home + q_cmd * counts_per_mm``) go out as RPDOs followed by SYNC;
6. one row goes to the run log (queued; the writer thread does the disk I/O).

Commands from the daemon's socket threads are posted under a lock and picked up at the start of a
cycle; nothing on the loop's path blocks on them.
"""

from __future__ import annotations

import gc
import itertools
import logging
import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cdcr_ctl.control.ports import (
    DrivePort,
    RobotModelPort,
    SetpointSource,
    TensionPort,
    TipPort,
)
from cdcr_ctl.control.supervisor import CycleCheck, Reaction, Supervisor, Trip
from cdcr_ctl.control.timing import Ticker
from cdcr_ctl.errors import ModelError

log = logging.getLogger(__name__)

#: Cable offsets (jogs, re-enable slack, compensation switches) ramp out at this fraction of the
#: cable velocity limit.
OFFSET_RAMP_FRACTION = 0.5
#: Python's GIL switch interval while the loop runs (s); see :meth:`ControlLoop.start`.
GIL_SWITCH_INTERVAL_S = 5e-5
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


RowSink = Callable[[dict[str, float | str]], None]


@dataclass
class _Pending:
    source: SetpointSource | None = None
    run: RunInfo | None = None
    sink: Any = None
    cable_offset_target: np.ndarray | None = None
    stop: Reaction | None = None
    mode: str | None = None
    reenabled: bool = False
    home: np.ndarray | None = None
    sink_change: bool = False
    new_sink: Any = None


@dataclass
class LoopCounters:
    cycles: int = 0
    rows_logged: int = 0
    rows_dropped: int = 0
    trips: int = 0
    last_cycle_us: float = 0.0
    max_cycle_us: float = 0.0
    cpu_s: float = 0.0


class ControlLoop:
    """The fixed-rate loop. Start with :meth:`start`, stop with :meth:`stop` (joins the thread)."""

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
        self.ticker = Ticker(cfg.period_s)
        self.counters = LoopCounters()
        self._lock = threading.Lock()
        self._pending = _Pending()
        self._stop_evt = threading.Event()
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
        self._last_row: dict[str, Any] = {}
        self._row_keys: list[str] | None = None
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
            self._pending.source = source
            self._pending.run = run
            self._pending.sink = sink
        return run

    def jog_cable(self, cable: int, delta_mm: float) -> None:
        """Move cable ``cable`` (0-based) by ``delta_mm`` at the cable velocity limit."""
        with self._lock:
            target = (
                self._q_offset_target.copy()
                if self._pending.cable_offset_target is None
                else (self._pending.cable_offset_target.copy())
            )
            target[cable] += delta_mm
            self._pending.cable_offset_target = target

    def pause(self, paused: bool) -> None:
        """While paused the loop keeps reading feedback and logging but sends no RPDO or SYNC
        (homing runs the drives in their own mode)."""
        self._paused = paused

    def set_home(self, home_counts: Sequence[int]) -> None:
        """New home positions (counts at q = 0): the robot is straight there."""
        with self._lock:
            self._pending.home = np.array(home_counts, dtype=np.int64)

    def attach_sink(self, sink: Any) -> None:
        """Log every cycle to ``sink`` (a manual log) or stop doing so (``None``)."""
        with self._lock:
            self._pending.sink_change = True
            self._pending.new_sink = sink

    def set_compensation(self, mode: str) -> None:
        """Compensation mode for holding and for runs that do not name one."""
        with self._lock:
            self._pending.mode = mode

    def request_stop(self, reaction: Reaction) -> None:
        with self._lock:
            self._pending.stop = reaction

    @property
    def psi_cmd(self) -> np.ndarray:
        return self._psi_cmd.copy()

    def snapshot(self) -> dict[str, Any]:
        """Status for the socket: last cycle's values, timing, current run."""
        run = self._run
        return {
            "cycles": self.counters.cycles,
            "timing": self.ticker.stats.summary(),
            "cycle_time_max_us": round(self.counters.max_cycle_us, 1),
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
        t_start = time.monotonic()
        self.ticker = Ticker(self.cfg.period_s)
        while not self._stop_evt.is_set():
            deadline, lateness = self.ticker.wait()
            t0 = time.perf_counter()
            try:
                self._cycle(deadline - t_start, deadline, lateness)
            except Exception as exc:  # a bug must not leave the drives running unattended
                log.exception("control loop cycle failed")
                self._trip(
                    Trip("loop_exception", Reaction.QUICK_STOP, f"{type(exc).__name__}: {exc}", 0.0)
                )
            dt_us = (time.perf_counter() - t0) * 1e6
            self.counters.last_cycle_us = dt_us
            self.counters.max_cycle_us = max(self.counters.max_cycle_us, dt_us)
            self.counters.cycles += 1
            self.ticker.done()
        self.counters.cpu_s = time.thread_time() - cpu0
        self._finish_run("stopped", "loop stopped")

    def _take_pending(self, now: float) -> None:
        with self._lock:
            p = self._pending
            self._pending = _Pending()
        if p.stop is not None:
            self._react(Trip(OPERATOR_STOP, p.stop, "stop requested", now))
        if p.source is not None:
            if self.supervisor.trip is not None:
                reason = f"refused: supervisor tripped ({self.supervisor.trip.cause})"
                assert p.run is not None
                p.run.state, p.run.end_reason = "refused", reason
                self.history.append(p.run)
                if p.sink is not None:
                    p.sink.close(reason, outcome="refused", wait=False)
            else:
                self._finish_run("stopped", "replaced by a new run")
                self._source, self._t_source0 = p.source, now
                # Cable offsets (single-cable jogs, re-enable slack) ramp out at the velocity
                # limit: a run commands absolute displacements.
                self._q_offset_target = np.zeros_like(self._q_offset)
                self._run, self._sink = p.run, p.sink
        if p.cable_offset_target is not None:
            self._q_offset_target = p.cable_offset_target
        if p.mode is not None:
            self._mode = p.mode
            self.cfg.compensation = p.mode
        if p.reenabled:
            self._resume_after_enable()
        if p.home is not None:
            self.home_counts = p.home
            self._psi_cmd = np.zeros_like(self._psi_cmd)
            self._source, self._t_source0 = Hold(self._psi_cmd), now
            self._q_offset[:] = 0.0
            self._q_offset_target[:] = 0.0
            self._model_state = self.model.new_state()
        if p.sink_change:
            self._manual_sink = p.new_sink

    def _cycle(self, t_s: float, now: float, lateness_s: float) -> None:
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
        step = OFFSET_RAMP_FRACTION * self.cfg.cable_velocity_mm_s * self.cfg.period_s
        self._q_offset += np.clip(self._q_offset_target - self._q_offset, -step, step)

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

        # Limits
        tip_model = self.model.tip(psi)
        tip_err = (
            float(np.linalg.norm(tip_mm - tip_model)) if np.all(np.isfinite(tip_mm)) else math.nan
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

        # Log
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

    def _row(self, t_s, psi, q_nom, q_cmd, q_act, force_N, tip_mm, lateness_s, event):
        keys = self._row_keys
        if keys is None:
            S, K = len(psi), len(q_nom)
            keys = self._row_keys = (
                [f"seg{i}_{a}_cmd_rad" for i in range(1, S + 1) for a in ("theta", "phi")]
                + [
                    f"cable{k}_{c}"
                    for k in range(1, K + 1)
                    for c in ("q_nominal_mm", "q_cmd_mm", "q_act_mm", "tension_N")
                ]
                + ["tip_x_mm", "tip_y_mm", "tip_z_mm"]
            )
        per_cable = np.column_stack((q_nom, q_cmd, q_act, force_N)).ravel()
        values = np.concatenate((np.ravel(psi), per_cable, tip_mm)).tolist()
        row: dict[str, float | str] = {"t_s": round(t_s, 6), "cycle": self.counters.cycles}
        row.update(zip(keys, values, strict=True))
        row["lateness_us"] = round(lateness_s * 1e6, 1)
        row["event"] = event
        return row

    def _react(self, trip: Trip) -> None:
        self.counters.trips += 1
        log.warning("supervisor: %s -> %s (%s)", trip.cause, trip.reaction.name, trip.detail)
        if trip.reaction is Reaction.QUICK_STOP and not self._stopped_drives:
            self.drives.quick_stop()
            self._stopped_drives = True
        if trip.reaction >= Reaction.HOLD:
            self._source, self._t_source0 = Hold(self._psi_cmd), time.monotonic()
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
                self._source, self._t_source0 = Hold(self._psi_cmd), time.monotonic()
        if sink is not None:
            # Never wait for the writer's fsync on the loop thread.
            sink.close(reason, outcome=state, wait=False)

    def drives_reenabled(self) -> None:
        """Called by the daemon after re-enabling drives: resume sending computed targets."""
        with self._lock:
            self._pending.reenabled = True

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


__all__ = ["ControlLoop", "Hold", "LoopConfig", "RunInfo", "field"]
