"""The loop thread: fixed-rate cycles on absolute deadlines, the cycle itself (inputs, setpoint,
inverse kinematics and compensation (Qi et al. 2023 eq. 37), supervisor checks, RPDOs + SYNC,
log row), trip reactions and run ends. Commands and their queue are in
:mod:`cdcr_ctl.control.loop.commands`.
"""

from __future__ import annotations

import gc
import itertools
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from cdcr_ctl.control.clock import LoopClock, wall_clock
from cdcr_ctl.control.loop.commands import LoopCommands
from cdcr_ctl.control.loop.records import (
    COMMAND_STEP_FRACTION,
    DIVERGENCE_LAG_S,
    LOG_OVERFLOW,
    OFFSET_RAMP_FRACTION,
    OPERATOR_STOP,
    Hold,
    LoopConfig,
    LoopCounters,
    RunInfo,
    TipHistory,
    _Command,
)
from cdcr_ctl.control.loop.rows import CycleRow, RowLayout
from cdcr_ctl.control.loop.slew import MeasuredSlew
from cdcr_ctl.control.loop.vectors import actual_mm, added, floats, has_gap, target_counts
from cdcr_ctl.control.ports import DrivePort, SetpointSource, TensionPort, TipPort
from cdcr_ctl.control.stopflag import StopFlag
from cdcr_ctl.control.supervisor import Reaction, Supervisor, Trip
from cdcr_ctl.control.timing import BetweenCycles, Ticker, raise_loop_priority
from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.port import RobotModelPort

# The logger keeps the name it had when the loop was one module.
log = logging.getLogger("cdcr_ctl.control.loop")

#: An offset this far (mm) below its target is still being ramped up: the cable is being pulled
#: back in (a thousandth of a micrometre: far below a count, above rounding of the ramp's sums).
RETENSION_GAP_MM = 1e-6
#: How long after its ramp ended a re-tensioned cable may still read slack (s): the drive's
#: following lag and the load cells' sample age (their stale limit is of the same order).
RETENSION_SETTLE_S = 0.25


class ControlLoop(LoopCommands):
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
        #: True while this loop is between cycles (wall clock only): the CAN traffic log's
        #: writer takes the interpreter lock only then (issue #21).
        self.between_cycles = BetweenCycles()
        #: The previous cycle's work when it ran past the period (us), else 0: its row cannot
        #: know (it is written during the cycle), so the next row says so.
        self._long_prev_us = 0.0
        #: The global (missed, long) counters before the current run's first row.
        self._run_base = (0, 0)
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
        #: Per cable, until when (loop clock s) a slack reading is the re-tension ramp's.
        self._retension_until = np.full(K, -math.inf)
        self._model_state = model.new_state()
        #: Mode ``measured``'s compensation term, rate-bounded (see :mod:`.slew`).
        self._measured_slew = MeasuredSlew(
            COMMAND_STEP_FRACTION * cfg.cable_velocity_mm_s * cfg.period_s
        )
        self._q_nom_prev: np.ndarray | None = None
        #: Set when this cycle's command is to start from the one the drives hold (a refused
        #: command, a re-enable): the step from it goes into the offset (see ``_cycle``).
        self._absorb_step = False
        self._last_row: Mapping[str, Any] = {}
        self._row_layout = RowLayout(S, K)
        self._stopped_drives = False
        self._paused = False
        self._manual_sink: Any = None
        self._end_after_cycle: tuple[str, str] | None = None
        self._t_last_cmd = -math.inf
        #: The clock's time when the loop started (None before): a row's ``t_s`` is from it.
        self.t_start_s: float | None = None
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

    # ---------------------------------------------------------------- the loop thread
    def _run_loop(self) -> None:
        # Everything allocated during start-up moves to the permanent generation, so the
        # collector's full passes stay short while the loop runs (they run in whatever thread
        # allocates, this one included).
        gc.freeze()
        note = raise_loop_priority()
        if note:
            log.info("realtime: %s", note)
        cpu0 = time.thread_time()
        if self._clock is None:
            self.ticker = wall_clock(self.cfg.period_s)
        t_start = self.t_start_s = self.ticker.now()
        # The wall clock's ticker marks the time between cycles; a simulated one never sleeps.
        wall_ticker = self.ticker if isinstance(self.ticker, Ticker) else None
        while not self._stop_evt.is_set():
            deadline, lateness = self.ticker.wait()
            t0 = time.perf_counter()
            c0 = time.thread_time()
            try:
                self._cycle(deadline - t_start, deadline, lateness)
            except Exception as exc:  # a bug must not leave the drives running unattended
                log.exception("control loop cycle failed")
                self._cycle_failed(exc, deadline - t_start)
            cpu_s = time.thread_time() - c0
            self.counters.work_cpu_s += cpu_s
            dt_us = (time.perf_counter() - t0) * 1e6
            self.counters.last_cycle_us = dt_us
            self.counters.max_cycle_us = max(self.counters.max_cycle_us, dt_us)
            self.counters.cycles += 1
            # On a simulated clock (lock-step) the clock waits for the work: no cycle is late
            # on it, and a row must not depend on the host's speed.
            long_cycle = self._clock is None and dt_us > self.cfg.period_s * 1e6
            if long_cycle:
                self.counters.long_cycles += 1
                self.counters._long(dt_us * 1e-6, cpu_s)
            self._long_prev_us = dt_us if long_cycle else 0.0
            skipped = self.ticker.stats.skipped
            self.ticker.done()
            # Deadlines skipped after this cycle: the next row says so (its lateness counts
            # from the first missed deadline) and so do the counters.
            self._missed_now = self.ticker.stats.skipped - skipped
            self.counters.missed_cycles += self._missed_now
            if wall_ticker is not None:
                self.between_cycles.mark(wall_ticker.next_deadline, wall_ticker.spin_margin_s)
        self.between_cycles.clear()
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

    def _cycle(self, t_s: float, now: float, lateness_s: float) -> None:
        # The per-cable values are handled as Python floats (:mod:`.vectors`: the same float64
        # operations numpy did on the (K,) arrays); the loop's state keeps its arrays.
        clock = time.perf_counter
        m0 = clock()
        self._take_pending(now)
        positions = self._positions()
        force_l, age_l = self._tensions()
        tip_mm, tip_age = self.tip_port.latest()

        # Setpoint
        t_run = now - self._t_source0
        psi = np.asarray(self._source.sample(min(t_run, self._source.duration_s)), dtype=float)
        run = self._run
        if run is not None:
            run.elapsed_s = min(t_run, run.duration_s)
        m1 = clock()

        # Inverse kinematics and compensation
        q_nom = self.model.q_nominal(psi)
        if run is not None:
            self._mode = run.compensation
        mode = self._mode
        mode_changed = mode != self._mode_applied
        self._mode_applied = mode
        measured = np.array(force_l, dtype=float) if mode == "measured" else None
        try:
            q_cmd = self.model.q_command(psi, q_nom, self._model_state, mode, measured)
        except ModelError as exc:
            # The pose needs tension the cables cannot give (or the solver failed): hold the last
            # command rather than guess.
            self._react(Trip("model_unreachable", Reaction.HOLD, str(exc), t_s))
            psi, q_cmd = self._psi_cmd, self._q_cmd - self._q_offset
        else:
            if mode != "measured" or mode_changed:
                self._measured_slew.reset()
            if mode == "measured" and self._q_nom_prev is not None:
                # The load-cell tensions move the term as fast as the world changes them: bound
                # its step by what the velocity limit leaves after the trajectory's own.
                q_cmd = self._measured_slew.bound(q_nom, self._q_nom_prev, q_cmd)
        self._q_nom_prev = q_nom
        if self._absorb_step:
            # Plan from where the drives are: after a refused command (a trip) or a re-enable
            # the command starts from the one the drives hold, and the step to this cycle's
            # model command goes into the offset (held; a run ramps it out), so the command the
            # supervisor refused is not asked for again at once (it would trip again at every
            # recovery).
            self._absorb_step = False
            self._q_offset = self._q_cmd - q_cmd
            self._q_offset_target = (
                np.zeros_like(self._q_offset) if self._run is not None else self._q_offset.copy()
            )
        elif mode_changed and self.counters.cycles > 0:
            # Switching compensation steps the command by delta: take the step into the offset
            # and let it ramp out instead of jumping (and tripping the velocity limit).
            self._q_offset = self._q_cmd - q_cmd
            self._q_offset_target = np.zeros_like(self._q_offset)
        q_l = self._offset_command(q_cmd)
        m2 = clock()

        # Limits
        tip_l = floats(tip_mm)
        tip_err = math.nan  # no tracker (sample): nothing to compare the model tip with
        if self.supervisor.use_tracker:
            self._tips.add(now, self.model.tip(psi))
            if all(math.isfinite(v) for v in tip_l):
                tip_err = self._tips.distance(
                    now, tip_l, tip_age, DIVERGENCE_LAG_S, self.cfg.period_s
                )
        moving = run is not None and run.state == "running"
        # A cable whose offset still ramps up (pulled back in after a recovery that left it
        # paid out) may read slack until the ramp has taken the slack up.
        ramping = self._q_offset_target - self._q_offset > RETENSION_GAP_MM
        self._retension_until[ramping] = now + RETENSION_SETTLE_S
        retensioning = (self._retension_until > now).tolist()
        trip = self.supervisor.check_cycle(
            t_s,
            # Real time since the last command: after a late cycle the step is larger but so
            # is the time it covers (the velocity limit is on mm/s, not mm per cycle).
            max(now - self._t_last_cmd, self.cfg.period_s),
            q_l,
            self._q_cmd.tolist(),
            force_l,
            age_l,
            tip_err,
            tip_age,
            moving,
            retensioning,
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
            q_l = self._q_cmd.tolist()  # never send a command that violates a limit
            psi = self._psi_cmd
            self._absorb_step = True
        if run is not None and run.state == "running" and t_run >= run.duration_s:
            self._end_after_cycle = ("completed", "trajectory completed")
        m3 = clock()

        # Targets out: RPDOs then SYNC
        if self._paused:
            targets = None
        elif self._stopped_drives:
            # Drives are quick-stopped: follow the actual positions so re-enabling does not jump.
            targets = list(positions)
        else:
            targets = target_counts(q_l, self.home_counts, self.cfg.counts_per_mm)
        if targets is not None:
            self.drives.send_cycle(targets)
        self._q_prev, self._q_cmd, self._psi_cmd = self._q_cmd, np.array(q_l, dtype=float), psi
        self._t_last_cmd = now
        m4 = clock()

        # Log: the row keeps this cycle's numbers; the writer thread makes the columns.
        q_act = actual_mm(positions, self.home_counts, self.cfg.counts_per_mm)
        row = self._row(t_s, psi, q_nom, q_l, q_act, force_l, tip_l, lateness_s, event)
        self._last_row = row
        for sink in (self._sink, self._manual_sink):
            if sink is None:
                continue
            if sink.write(row):
                self.counters.rows_logged += 1
                if sink is self._sink and self._run is not None:
                    self._count_run_row(self._run)
            else:
                self.counters.rows_dropped += 1
                overflow = getattr(sink, "overflow", None)
                if overflow and self.supervisor.trip is None:
                    # The writer fell behind a real-time loop and its ring is full: stop rather
                    # than go on with rows missing from the log (the log keeps what it holds).
                    trip = self.supervisor.external(
                        LOG_OVERFLOW, Reaction.QUICK_STOP, str(overflow), t_s
                    )
                    if trip is not None:
                        self._react(trip)
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

    def _positions(self) -> list[int]:
        """The drives' positions (counts), cable order: the port's ``positions()`` where it has
        one (the same values as its ``feedback()``, without the per-drive records)."""
        fast = getattr(self.drives, "positions", None)
        if fast is not None:
            return fast()
        return [f.position_counts for f in self.drives.feedback()]

    def _tensions(self) -> tuple[list[float], list[float]]:
        """The cables' tensions (N) and their ages (s) as lists: the port's ``latest_lists()``
        where it has one (the same floats as its ``latest()``, without the arrays)."""
        fast = getattr(self.tensions, "latest_lists", None)
        if fast is not None:
            return fast()
        force_N, force_age = self.tensions.latest()
        return floats(force_N), floats(force_age)

    def _offset_command(self, q_cmd: Any) -> list[float]:
        """The model's command plus the cable offset (mm), the offset first ramped a step towards
        its target. Offsets ramp at up to half the velocity limit, and only within what the
        model's own step this cycle leaves of COMMAND_STEP_FRACTION of the limit: a model that
        rate-limits its own compensation (the universal-joint arm's dead zone) and the offset
        ramp must not add up to more than the limit the supervisor enforces."""
        if has_gap(self._q_offset_target.tolist(), self._q_offset.tolist()):
            gap = self._q_offset_target - self._q_offset
            v_dt = self.cfg.cable_velocity_mm_s * self.cfg.period_s
            ramp = OFFSET_RAMP_FRACTION * v_dt
            budget = COMMAND_STEP_FRACTION * v_dt
            base = q_cmd + self._q_offset - self._q_cmd  # this cycle's step without the ramp
            lo = np.minimum(np.maximum(-ramp, -budget - base), 0.0)
            hi = np.maximum(np.minimum(ramp, budget - base), 0.0)
            self._q_offset += np.clip(gap, lo, hi)
        return added(floats(q_cmd), self._q_offset.tolist())

    def _count_run_row(self, run: RunInfo) -> None:
        """The run's share of the global counters, up to the row just logged (see RunInfo)."""
        c = self.counters
        if run.rows == 0:
            # What the first row reports happened before it: not yet in the base.
            self._run_base = (
                c.missed_cycles - self._missed_now,
                c.long_cycles - (1 if self._long_prev_us else 0),
            )
            run.first_cycle = c.cycles
        run.rows += 1
        run.last_cycle = c.cycles
        run.missed_cycles = c.missed_cycles - self._run_base[0]
        run.long_cycles = c.long_cycles - self._run_base[1]

    def _row(self, t_s, psi, q_nom, q_cmd, q_act, force_N, tip_mm, lateness_s, event) -> CycleRow:
        """The cycle's log row; ``q_cmd``, ``q_act``, ``force_N``, ``tip_mm``: lists of floats.
        The values are those ``np.concatenate((np.ravel(psi), q_nom, q_cmd, q_act, force_N,
        tip_mm))`` made of the arrays, in one fresh array (later cycles may reuse the arrays
        they were given)."""
        layout = self._row_layout
        values = np.array(
            floats(psi) + floats(q_nom) + q_cmd + q_act + force_N + tip_mm, dtype=float
        )
        if self._row_event:
            event = f"{self._row_event}; {event}" if event else self._row_event
            self._row_event = ""
        missed = self._missed_now
        if missed:
            # The deadlines before this cycle were skipped: its lateness counts from the first.
            lateness_s += missed * self.cfg.period_s
            note = f"late: {missed} cycles missed"
            event = f"{event}; {note}" if event else note
        if self._long_prev_us:
            note = f"long: previous cycle {self._long_prev_us:.0f} us"
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
