"""The daemon's run commands: ``jog``, ``trajectory`` and ``joystick`` (with the lead-in and jog
speed planning they go through), and the waits that make a reply mean the loop took the run up.

:class:`RunCommands` is a mixin of :class:`~cdcr_ctl.daemon.service.Daemon`.
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

from cdcr_ctl.control.loop import RunInfo
from cdcr_ctl.daemon.joystick import JoystickSession
from cdcr_ctl.daemon.planner import PlannerUnavailable
from cdcr_ctl.daemon.planning import attach_lead, plan_jog, plan_lead
from cdcr_ctl.daemon.protocol import ProtocolError, check_jog_speed
from cdcr_ctl.errors import RigError

# The handlers log under the daemon's name, as when they were one module.
log = logging.getLogger("cdcr_ctl.daemon.service")

#: Longest wait of a run request (trajectory, jog, joystick) for the loop to take it up (s).
RUN_PICKUP_TIMEOUT_S = 1.0


class RunCommands:
    """Run commands (mixin of the daemon)."""

    def _require_ready(self) -> None:
        if not self.enabled:
            raise RigError("drives are disabled: run `cdcr-ctl enable` first")
        if self.supervisor.trip is not None:
            raise RigError(f"supervisor tripped ({self.supervisor.trip.cause}): reset-fault first")

    def _cmd_jog(self, args: Any) -> dict[str, Any]:
        # The request's own limits first: a bad request is refused naming its limit whatever
        # state the rig is in.
        S, K = self.model.n_segments, self.model.n_cables
        if args.segment is not None:
            if args.segment > S:
                raise ProtocolError(
                    f"segment {args.segment} outside [1, {S}]: the rig has {S} segment(s)",
                    field="args.segment",
                )
            if not 0 <= args.theta_rad <= self.cfg.limits.bend_rad:
                raise ProtocolError(
                    f"{args.theta_rad:g} rad outside [0, {self.cfg.limits.bend_rad:g}] rad"
                    " (limits.bend_rad)",
                    field="args.theta_rad",
                )
            check_jog_speed(args.speed, self.cfg.limits.bend_rad)
            self._require_ready()
            start = self.loop.psi_cmd
            goal = start.copy()
            goal[args.segment - 1] = (args.theta_rad, args.phi_rad)
            traj = self._jog_move(start, goal, args.speed)
            run = self._last_run = self.loop.follow(traj, f"jog seg{args.segment}", None, None)
            self._wait_picked_up(run)
            return {"run": run.id, "duration_s": run.duration_s}
        if args.cable > K:
            raise ProtocolError(
                f"cable {args.cable} outside [1, {K}]: the rig has {K} cables", field="args.cable"
            )
        lo, hi = self.cfg.limits.cable_displacement_mm
        if not lo - hi <= args.delta_mm <= hi - lo:
            raise ProtocolError(
                f"{args.delta_mm:g} mm outside [{lo - hi:g}, {hi - lo:g}] mm (the span of"
                f" limits.cable_displacement_mm = [{lo:g}, {hi:g}] mm)",
                field="args.delta_mm",
            )
        self._require_ready()
        self.loop.jog_cable(args.cable - 1, args.delta_mm)
        return {"cable": args.cable, "delta_mm": args.delta_mm}

    def _jog_move(self, start: np.ndarray, goal: np.ndarray, speed: float) -> Any:
        """A jog move at ``speed`` (rad/s), slowed so its fastest cable (in the mode in force)
        stays within ``LEAD_IN_CABLE_FRACTION`` of the velocity limit
        (:func:`.planning.plan_jog`; in the planner's worker when the daemon has one)."""
        mode, v_max = self.loop.cfg.compensation, self.cfg.limits.cable_velocity_mm_s
        bend = self.cfg.limits.bend_rad
        planned = None
        if self.planner is not None:
            try:
                planned = self.planner.jog(start, goal, speed, mode, v_max, bend)
            except PlannerUnavailable as exc:
                log.warning("%s; planning the jog here", exc)
        traj, used, peak = planned or plan_jog(self.model, start, goal, speed, mode, v_max)
        if used != speed:
            log.info("jog slowed to %.4f rad/s (cables %.1f mm/s at the speed asked)", used, peak)
        return traj

    def _with_lead_in(self, traj: Any, mode: str | None = None) -> Any:
        """``traj`` after a hold for a compensation switch and a lead-in move from the commanded
        pose, each within the cable velocity limit (:func:`.planning.plan_lead_in`). The model
        work runs in the planner's worker when the daemon has one (:mod:`.planner`); here
        only the inputs are gathered and the lead put in front of ``traj``."""
        mode = mode or self.loop.cfg.compensation
        force_N, _ = self.io.tensions.latest()
        args = (
            np.array(self.loop.psi_cmd, dtype=float),
            self.loop.q_cmd if self.loop.counters.cycles else None,
            np.array(traj.psi[0], dtype=float),
            mode,
            self.cfg.limits.cable_velocity_mm_s,
        )
        measured = force_N if np.isfinite(force_N).all() else None
        state = self.loop.model_state()
        move = None
        if self.planner is not None:
            try:
                move = self.planner.lead(*args, self.cfg.limits.bend_rad, measured, state)
            except PlannerUnavailable as exc:
                log.warning("%s; planning the lead-in here", exc)
        if move is None:
            move = plan_lead(self.model, *args, measured_N=measured, state=state)
        plan = attach_lead(move, traj)
        if plan.hold_s or plan.speed_rad_s != self.new_trajectory.LEAD_IN_SPEED_RAD_S:
            log.info(
                "lead-in: hold %.2f s for the mode switch, move at %.4f rad/s (cables %.1f mm/s)",
                plan.hold_s,
                plan.speed_rad_s,
                plan.peak_mm_s,
            )
        return plan.trajectory

    def _cmd_trajectory(self, args: Any) -> dict[str, Any]:
        self._require_ready()
        if args.file is not None:
            # Read, parsed and validated in the intake process; mapped here.
            traj = self.intake.load(self.intake.prepare_file(args.file), args.name)
        else:
            traj = self.new_trajectory.from_samples(
                args.samples,
                n_segments=self.model.n_segments,
                bend_limit_rad=self.cfg.limits.bend_rad,
                source=f"request {args.name!r}",
            )
        traj = self._with_lead_in(traj, args.compensation)
        sink = None
        if args.log:
            sink = self.new_sink(args.name, args.compensation or self.loop.cfg.compensation)
            self._log_traffic(sink)
        run = self._last_run = self.loop.follow(traj, args.name, args.compensation, sink)
        return self._started(run)

    def _started(self, run: RunInfo, **extra: Any) -> dict[str, Any]:
        """Reply to a command that started ``run``, once the loop has taken it up."""
        self._wait_picked_up(run)
        return {
            "run": run.id,
            "duration_s": run.duration_s,
            "log_dir": run.log_dir,
            "compensation": run.compensation,
            **extra,
        }

    def _cmd_joystick(self, args: Any) -> dict[str, Any]:
        """A live end-following session from the rig's joystick (:mod:`.joystick`): the stick
        is opened now and closed when the run ends (stop, ``seconds``, a trip, a new run)."""
        self._require_ready()
        prev = self._session
        if prev is not None and prev.active:
            if prev.run.state == "running":
                raise RigError(
                    f"joystick session {prev.run.id} is running: `cdcr-ctl stop` it first"
                )
            prev.close()  # its run has ended; its watcher had not caught up yet
        last = self._last_run
        if last is not None and last.state == "running":
            # The session plans from the commanded pose: it must be standing still.
            raise RigError(f"run {last.name!r} is in progress: stop it first")
        opener = self._open_joystick
        if opener is None:
            from cdcr_ctl.sensors.joystick import open_joystick as opener
        session = JoystickSession.open(
            self.cfg,
            self.config_path,
            self.loop.psi_cmd,
            opener,
            duration_s=math.inf if args.seconds is None else args.seconds,
        )
        try:
            sink = None
            if args.log:
                sink = self.new_sink(args.name, args.compensation or self.loop.cfg.compensation)
                self._log_traffic(sink)
            self.supervisor.add_check(session.check)
            run = self._last_run = self.loop.follow(
                session.source, args.name, args.compensation, sink
            )
        except BaseException:
            session.close()
            raise
        session.attach(run, self.supervisor)
        self._session = session
        return self._started(run, device=session.device)

    def _wait_picked_up(self, run: Any) -> None:
        """Return once the loop runs ``run`` (or ended it), so the reply to a run request
        (trajectory, jog, joystick) means the run is running and a ``status`` right after it
        shows it. Bounded: ``RUN_PICKUP_TIMEOUT_S`` (a loop that is not running does not hold
        the reply up)."""
        end = time.monotonic() + RUN_PICKUP_TIMEOUT_S
        while self.loop.running and time.monotonic() < end and run.state == "running":
            if self.loop.current_run is run:
                return
            time.sleep(self.loop.cfg.period_s / 2)

    def _wait_cycles(self, n: int) -> None:
        """Return after ``n`` more loop cycles (a command posted before them has been taken
        up); bounded by ``RUN_PICKUP_TIMEOUT_S``, at once when the loop is not running."""
        start = self.loop.counters.cycles
        end = time.monotonic() + RUN_PICKUP_TIMEOUT_S
        while (
            self.loop.running and self.loop.counters.cycles < start + n and time.monotonic() < end
        ):
            time.sleep(self.loop.cfg.period_s / 2)
