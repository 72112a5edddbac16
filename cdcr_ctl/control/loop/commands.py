"""The loop's commands from any thread (start, stop, follow, jog, home, sink, mode, pose, stop
requests, status snapshot) and their queue: posted under a lock, taken up at the start of the
next cycle by :meth:`LoopCommands._take_pending` and applied in order on the loop thread.

:class:`LoopCommands` is a mixin of :class:`~cdcr_ctl.control.loop.cycle.ControlLoop`; it uses
the state the loop's ``__init__`` sets up and the loop's ``_react``/``_finish_run``.
"""

from __future__ import annotations

import copy
import math
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from cdcr_ctl.control.loop.records import (
    GIL_SWITCH_INTERVAL_S,
    OPERATOR_STOP,
    Hold,
    RunInfo,
)
from cdcr_ctl.control.ports import SetpointSource
from cdcr_ctl.control.stopflag import StopFlag
from cdcr_ctl.control.supervisor import Reaction, Trip
from cdcr_ctl.errors import ModelError


class LoopCommands:
    """Commands posted to the loop thread and their application there (see the module)."""

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
            # The clock's time (``time.monotonic`` on the wall clock) of the loop's start: a
            # row's ``t_s`` plus this is when its cycle was due (to line rows up with a probe).
            "t0_clock_s": self.t_start_s,
            "timing": self.ticker.stats.summary(),
            "cycle_time_max_us": round(self.counters.max_cycle_us, 1),
            "long_cycles": self.counters.long_cycles,
            "long_cycles_ms": {
                "wall": round(self.counters.long_wall_s * 1e3, 3),
                "cpu": round(self.counters.long_cpu_s * 1e3, 3),
                **{k: round(v * 1e3, 3) for k, v in self.counters.long_stage_s.items()},
            },
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

    def _take_pending(self, now: float) -> None:
        self.stop_flag.tick(self.counters.cycles)
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
            self._model_state = self.model.new_state()
            self._measured_slew.reset()
            # Home makes the drives' zero the straight pose. A model whose compensation is not
            # zero there (a fitted mount tilt: the sideways disk weights need uneven tensions
            # at straight) would step the first command by it (0.17 mm in one cycle on the
            # hard simulated world: a velocity trip): start from it in the offset and ramp it
            # out at once, as a mode switch does.
            try:
                q_home = self._hold_command(self._psi_cmd)
            except ModelError:  # the cycle trips on it (model_unreachable) as before
                q_home = np.zeros_like(self._q_offset)
            self._q_offset = -np.asarray(q_home, dtype=float)
            self._q_offset_target = np.zeros_like(self._q_offset)
            self._q_cmd = np.zeros_like(self._q_offset)
        elif kind == "sink":
            self._manual_sink = payload
        elif kind == "pose":
            # Hold where the arm is: the command of the pose plus an offset that makes it the
            # drives' actual positions, so no cycle (sent or only checked) steps.
            self._psi_cmd = payload
            self._source, self._t_source0 = Hold(payload), now
            self._model_state = self.model.new_state()
            self._measured_slew.reset()
            q_pose = self._hold_command(payload)
            q_act = self._q_act_mm(self.drives.feedback())
            self._q_offset = q_act - q_pose
            self._q_offset_target = self._q_offset.copy()
            self._q_cmd = q_act.copy()
        else:  # pragma: no cover - a programming error
            raise ValueError(f"unknown loop command {kind!r}")

    def _hold_command(self, psi: np.ndarray) -> np.ndarray:
        """The model's cable command (mm) holding segment pose ``psi`` (rad) from the current
        model state, without load-cell tensions (mode ``measured`` uses ``model`` here)."""
        mode = "model" if self._mode == "measured" else self._mode
        return self.model.q_command(psi, self.model.q_nominal(psi), self._model_state, mode, None)

    def _q_act_mm(self, fb: Sequence[Any]) -> np.ndarray:
        """Cable displacements (mm) from the drives' feedback (counts, relative to home)."""
        counts = np.array([f.position_counts for f in fb]) - self.home_counts
        return counts / self.cfg.counts_per_mm

    def drives_reenabled(self) -> None:
        """Called by the daemon after re-enabling drives: resume sending computed targets."""
        with self._lock:
            self._post("reenabled")

    def _resume_after_enable(self) -> None:
        # Plan from where the drives are: the next command starts at their actual positions and
        # the difference to the model's command of that cycle (computed then, from the tensions
        # of then) goes into the cable offset, held there: no jump on re-enable. The next run
        # ramps it out. (Not from the command computed, but not sent, while they were stopped.)
        q_act = self._q_act_mm(self.drives.feedback())
        self._q_offset = self._q_offset + (q_act - self._q_cmd)
        self._q_offset_target = self._q_offset.copy()
        self._q_cmd = q_act.copy()
        self._absorb_step = True
        self._stopped_drives = False
