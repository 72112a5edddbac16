"""The daemon: owns the rig I/O and the control loop, answers the control socket, talks to systemd.

Start-up order makes a bad config harmless: the config is validated before anything is opened;
the bus, drives and sensors are opened next; the drives stay disabled until ``enable``. Shutdown
(SIGTERM, ``shutdown`` request) ends the running trajectory, closes its log, disables the drives and
closes the bus, in that order, and every step runs even if an earlier one failed.
"""

from __future__ import annotations

import logging
import math
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.control.clock import LoopClock
from cdcr_ctl.control.loop import OPERATOR_STOP, ControlLoop, LoopConfig, RunInfo
from cdcr_ctl.control.ports import RigIO, RobotModelPort
from cdcr_ctl.control.supervisor import Reaction, Supervisor, Trip
from cdcr_ctl.daemon import recovery
from cdcr_ctl.daemon.intake import Intake
from cdcr_ctl.daemon.joystick import JoystickSession
from cdcr_ctl.daemon.notify import SystemdNotifier
from cdcr_ctl.daemon.planning import LEAD_IN_CABLE_FRACTION, peak_cable_speed, plan_lead_in
from cdcr_ctl.daemon.protocol import ProtocolError, Request, check_jog_speed
from cdcr_ctl.daemon.server import ControlServer
from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.annotate import annotate_when_ended
from cdcr_ctl.runlog.live import LiveView, live_view_for

log = logging.getLogger(__name__)

#: How long shutdown waits for the loop thread to finish its last cycle (s).
LOOP_JOIN_TIMEOUT_S = 2.0
#: Commands answered without the command lock: they never wait behind loading or planning.
UNLOCKED_COMMANDS = ("stop", "shutdown", "status")
#: Longest wait of a run request (trajectory, jog, joystick) for the loop to take it up (s).
RUN_PICKUP_TIMEOUT_S = 1.0


class Daemon:
    """Wires config, model, I/O, loop and control socket; :meth:`serve` runs until stopped."""

    def __init__(
        self,
        cfg: RigConfig,
        config_path: Path,
        io: RigIO,
        model: RobotModelPort,
        run_sink_factory: Callable[..., Any],
        trajectory_factory: Callable[..., Any],
        notifier: SystemdNotifier | None = None,
        joystick_opener: Callable[..., Any] | None = None,
        clock: LoopClock | None = None,
    ) -> None:
        """``joystick_opener(JoystickConfig)`` opens the rig's joystick for a ``joystick``
        session (default :func:`cdcr_ctl.sensors.joystick.open_joystick`). ``clock``: the
        loop's clock (default the wall clock; the lock-step simulator passes its own)."""
        self.cfg = cfg
        self.config_path = config_path
        self.io = io
        self.model = model
        self.new_sink = run_sink_factory
        self.new_trajectory = trajectory_factory
        self.notifier = notifier or SystemdNotifier()
        self.state = "starting"
        self._stop = threading.Event()
        self._stop_reason = ""
        self._cmd_lock = threading.Lock()
        self.supervisor = Supervisor(
            cfg.limits,
            use_tension=cfg.sensors.load_cells is not None,
            use_tracker=cfg.sensors.tracker is not None,
        )
        cable_order = [c.name for c in cfg.robot.cables]
        by_cable = {d.cable: d for d in cfg.drives}
        counts_per_mm = np.array([by_cable[c].counts_per_mm for c in cable_order])
        self.loop = ControlLoop(
            LoopConfig(
                period_s=1.0 / cfg.control.rate_hz,
                counts_per_mm=counts_per_mm,
                compensation=cfg.control.compensation,
                cable_velocity_mm_s=cfg.limits.cable_velocity_mm_s,
            ),
            model,
            io.drives,
            io.tensions,
            io.tip,
            self.supervisor,
            on_trip=self._on_trip,
            clock=clock,
        )
        self.enabled = False
        self.homed = False
        self._manual_sink: Any = None
        self.server: ControlServer | None = None
        self._open_joystick = joystick_opener
        self._session: JoystickSession | None = None
        #: The last run handed to the loop: "running" from then on, even before the loop takes
        #: it up, until the loop ends it.
        self._last_run: Any = None
        #: The live view (``live.enabled``), started with the loop.
        self.live: LiveView | None = None
        #: Big requests and trajectory files are parsed in this worker process, not here.
        self.intake = Intake(model.n_segments, cfg.limits.bend_rad)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        # The arm may be bent (a restart): no tracker check until the loop holds the pose the
        # drives report (recovery.adopt_start_pose, in the background).
        restore_tracker = recovery.hold_tracker_check(self.supervisor)
        # Start the loop before the socket so a connecting client always sees live status.
        self.loop.start()
        if self.cfg.live.enabled:
            self.live = live_view_for(
                self.cfg,
                lambda: self.loop.last_row,
                lambda: self.supervisor.trip,
                str(self.config_path),
            ).start()
        threading.Thread(
            target=recovery.adopt_start_pose,
            args=(self, restore_tracker),
            name="start-pose",
            daemon=True,
        ).start()
        self.intake.start()
        self.server = ControlServer(
            self.cfg.daemon.socket_path,
            self.handle,
            mode=self.cfg.daemon.socket_mode,
            spooler=self.intake.parse_spooled,
            spool_dir=self.intake.dir,
        ).start()
        self.state = "ready"
        self.notifier.ready(f"ready: {self.cfg.name}, drives disabled")
        log.info("daemon ready on %s", self.cfg.daemon.socket_path)

    def serve(self, install_signals: bool = True) -> str:
        """Run until SIGTERM/SIGINT or a ``shutdown`` request; return the stop reason."""
        previous: dict[int, Any] = {}
        if install_signals:
            for sig in (signal.SIGTERM, signal.SIGINT):
                previous[sig] = signal.signal(sig, self._signal)
            # A file-size limit (RLIMIT_FSIZE) must fail the write (EFBIG, handled like a full
            # disk by the run log) rather than kill the controller with the drives enabled.
            previous[signal.SIGXFSZ] = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        try:
            period = self.notifier.watchdog_period_s() or 1.0
            while not self._stop.wait(min(period, 1.0)):
                if self.loop.running:
                    # Pet the watchdog only while the loop is alive: a hung loop gets us
                    # restarted.
                    self.notifier.watchdog()
                    self.notifier.status(self._status_line())
                else:
                    log.error("control loop thread died; stopping")
                    self._stop_reason = "control loop died"
                    break
            self.shutdown(self._stop_reason or "stopped")
        finally:
            # The process's handlers as they were (a daemon embedded in a larger program).
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        return self._stop_reason

    def _signal(self, signum: int, frame: object) -> None:
        self._stop_reason = f"signal {signal.Signals(signum).name}"
        self._stop.set()

    def request_stop(self, reason: str) -> None:
        self._stop_reason = reason
        self._stop.set()

    def shutdown(self, reason: str) -> None:
        """Ramp down (end the run, hold), close logs, disable drives, close I/O; never raises."""
        self.state = "stopping"
        self.notifier.stopping()
        steps: list[tuple[str, Callable[[], None]]] = [
            ("halt", lambda: self.loop.stop_flag.request(Reaction.HALT)),
            ("settle", lambda: time.sleep(3 * self.loop.cfg.period_s)),
            ("joystick", lambda: self._session.shutdown() if self._session else None),
            ("manual log", self._close_manual_sink),
            ("disable drives", self.io.drives.disable),
            ("traffic log", lambda: getattr(self.io.drives, "log_traffic", lambda p: None)(None)),
            ("stop loop", lambda: self.loop.stop(LOOP_JOIN_TIMEOUT_S)),
            ("close socket", lambda: self.server.close() if self.server else None),
            ("live view", lambda: self.live.stop() if self.live else None),
            ("intake", self.intake.close),
            ("close io", self.io.close),
        ]
        for name, step in steps:
            try:
                step()
            except Exception:
                log.exception("shutdown step %r failed", name)
        self.state = "stopped"
        log.info("daemon stopped: %s", reason)

    # ------------------------------------------------------------------ control socket
    def handle(self, req: Request) -> Any:
        method = getattr(self, f"_cmd_{req.cmd}")
        if req.cmd in UNLOCKED_COMMANDS:
            return method(req.args)
        with self._cmd_lock:
            return method(req.args)

    def _cmd_status(self, args: Any) -> dict[str, Any]:
        fb = self.io.drives.feedback()
        force, force_age = self.io.tensions.latest()
        tip, tip_age = self.io.tip.latest()
        trip = self.supervisor.trip
        snap = self.loop.snapshot()
        return {
            "state": self.state,
            "rig": self.cfg.name,
            "design": self.cfg.design,
            "config": str(self.config_path),
            "enabled": self.enabled,
            "homed": self.homed,
            "compensation": self.loop.cfg.compensation,
            "drives": recovery.drive_status(self.cfg, fb),
            "tension_N": [None if not math.isfinite(v) else round(float(v), 3) for v in force],
            "tension_age_s": [
                None if not math.isfinite(v) else round(float(v), 4) for v in force_age
            ],
            "tip_mm": [None if not math.isfinite(v) else round(float(v), 3) for v in tip],
            "tip_age_s": None if not math.isfinite(tip_age) else round(tip_age, 4),
            "fault": None if trip is None else _trip_dict(trip),
            "trips": [_trip_dict(t) for t in self.supervisor.history[-20:]],
            "safety": self._safety_status(),
            "run": snap.pop("run"),
            "runs": [r.__dict__ for r in self.loop.history[-10:]],
            "loop": snap,
            "logging": self._manual_sink is not None,
            "joystick": None if self._session is None else self._session.status(),
        }

    def _cmd_enable(self, args: Any) -> dict[str, Any]:
        if self.supervisor.trip is not None:
            raise RigError(f"supervisor tripped ({self.supervisor.trip.cause}): reset-fault first")
        self.io.drives.enable()
        self.loop.drives_reenabled()
        self.enabled = True
        self.state = "enabled"
        return {"enabled": True}

    def _cmd_disable(self, args: Any) -> dict[str, Any]:
        self.loop.request_stop(Reaction.HALT)
        self.io.drives.disable()
        self.enabled = False
        self.state = "ready"
        return {"enabled": False}

    def _cmd_home(self, args: Any) -> dict[str, Any]:
        if self.loop.current_run is not None:
            raise RigError("a run is in progress: stop it before homing")
        if self.enabled:
            # Homing on the current position (37) declares the arm straight there: bring a bent
            # arm straight first, at the lead-in's cable speed.
            recovery.straighten(self)
        self.loop.pause(True)
        home: list[int] | None = None
        try:
            home = self.io.drives.home()
            # The new home before the loop sends again: no cycle with the old one.
            self.loop.set_home(home)
        finally:
            self.loop.pause(False)
        # Reply once the loop has taken the home up (status shows the new home).
        self._wait_cycles(2)
        self.homed = True
        return {
            "home_counts": list(home),
            "position_counts": [f.position_counts for f in self.io.drives.feedback()],
        }

    def _require_ready(self) -> None:
        if not self.enabled:
            raise RigError("drives are disabled: run `cdcr-ctl enable` first")
        if self.supervisor.trip is not None:
            raise RigError(f"supervisor tripped ({self.supervisor.trip.cause}): reset-fault first")

    def _cmd_jog(self, args: Any) -> dict[str, Any]:
        self._require_ready()
        S, K = self.model.n_segments, self.model.n_cables
        if args.segment is not None:
            if args.segment > S:
                raise ProtocolError(f"rig has {S} segment(s)", field="args.segment")
            if not 0 <= args.theta_rad <= self.cfg.limits.bend_rad:
                raise ProtocolError(
                    f"outside [0, {self.cfg.limits.bend_rad}] rad (limits.bend_rad)",
                    field="args.theta_rad",
                )
            check_jog_speed(args.speed, self.cfg.limits.bend_rad)
            start = self.loop.psi_cmd
            goal = start.copy()
            goal[args.segment - 1] = (args.theta_rad, args.phi_rad)
            traj = self._jog_move(start, goal, args.speed)
            run = self._last_run = self.loop.follow(traj, f"jog seg{args.segment}", None, None)
            self._wait_picked_up(run)
            return {"run": run.id, "duration_s": run.duration_s}
        if args.cable > K:
            raise ProtocolError(f"rig has {K} cables", field="args.cable")
        lo, hi = self.cfg.limits.cable_displacement_mm
        if not lo - hi <= args.delta_mm <= hi - lo:
            raise ProtocolError("larger than the displacement range", field="args.delta_mm")
        self.loop.jog_cable(args.cable - 1, args.delta_mm)
        return {"cable": args.cable, "delta_mm": args.delta_mm}

    def _jog_move(self, start: np.ndarray, goal: np.ndarray, speed: float) -> Any:
        """A jog move at ``speed`` (rad/s), slowed so its fastest cable (in the mode in force)
        stays within ``LEAD_IN_CABLE_FRACTION`` of the velocity limit."""
        tj = self.new_trajectory
        traj = tj.move(start, goal, speed_rad_s=speed)
        v_allowed = LEAD_IN_CABLE_FRACTION * self.cfg.limits.cable_velocity_mm_s
        peak = peak_cable_speed(self.model, traj, self.loop.cfg.compensation)
        if peak > v_allowed:
            speed *= 0.98 * v_allowed / peak
            log.info("jog slowed to %.4f rad/s (cables %.1f mm/s at the speed asked)", speed, peak)
            traj = tj.move(start, goal, speed_rad_s=speed)
        return traj

    def _with_lead_in(self, traj: Any, mode: str | None = None) -> Any:
        """``traj`` after a hold for a compensation switch and a lead-in move from the commanded
        pose, each within the cable velocity limit (:func:`.planning.plan_lead_in`)."""
        mode = mode or self.loop.cfg.compensation
        force_N, _ = self.io.tensions.latest()
        plan = plan_lead_in(
            self.model,
            np.array(self.loop.psi_cmd, dtype=float),
            self.loop.q_cmd if self.loop.counters.cycles else None,
            traj,
            mode,
            self.cfg.limits.cable_velocity_mm_s,
            measured_N=force_N if np.isfinite(force_N).all() else None,
            state=self.loop.model_state(),
        )
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

    def _cmd_stop(self, args: Any) -> dict[str, Any]:
        """Set the loop's stop flag (no lock, no queue) and answer once the loop has acted:
        the reply names the cycle that sent the stop and how many cycles it took."""
        reaction = Reaction.QUICK_STOP if args.mode == "quick_stop" else Reaction.HALT
        acted = recovery.stop_now(self, reaction)
        if reaction is Reaction.QUICK_STOP:
            self.enabled = False
            self.state = "stopped"
        return {"stopped": args.mode, **acted}

    def _cmd_log_start(self, args: Any) -> dict[str, Any]:
        if self._manual_sink is not None:
            raise RigError("a manual log is already running")
        self._manual_sink = self.new_sink(args.name, self.loop.cfg.compensation)
        self._log_traffic(self._manual_sink)
        self.loop.attach_sink(self._manual_sink)
        return {"log_dir": str(getattr(self._manual_sink, "run_dir", ""))}

    def _cmd_log_stop(self, args: Any) -> dict[str, Any]:
        if self._manual_sink is None:
            raise RigError("no manual log is running")
        out = str(getattr(self._manual_sink, "run_dir", ""))
        self._close_manual_sink()
        return {"log_dir": out}

    def _close_manual_sink(self) -> None:
        sink, self._manual_sink = self._manual_sink, None
        if sink is not None:
            self.loop.attach_sink(None)
            sink.close("log stopped", outcome="completed")

    def _cmd_compensation(self, args: Any) -> dict[str, Any]:
        self.loop.set_compensation(args.mode)
        return {"compensation": args.mode}

    def _cmd_reset_fault(self, args: Any) -> dict[str, Any]:
        if not args.confirm:
            raise ProtocolError("set confirm: true to reset a fault", field="args.confirm")
        return recovery.reset_fault(self)

    def _cmd_shutdown(self, args: Any) -> dict[str, Any]:
        self.request_stop("shutdown requested")
        return {"stopping": True}

    # ------------------------------------------------------------------ helpers
    def _log_traffic(self, sink: Any) -> None:
        """Raw CAN traffic into the run directory, from now until the next run or shutdown."""
        start = getattr(self.io.drives, "log_traffic", None)
        path = getattr(sink, "can_log_path", None)
        if start is not None and path is not None and self.cfg.can.log_traffic:
            tap = getattr(sink, "can_tap", None)  # the run's MCAP /can channel
            start(path("asc"), tap) if tap is not None else start(path("asc"))

    def _on_trip(self, trip: Trip) -> None:
        if trip.reaction is Reaction.QUICK_STOP:
            self.enabled = False
            self.state = "stopped" if trip.cause == OPERATOR_STOP else "fault"
        if trip.cause == "log_write_failed":
            # The run directory is gone or the disk full: stop the CAN log writing into it.
            stop = getattr(self.io.drives, "log_traffic", None)
            if stop is not None:
                threading.Thread(target=stop, args=(None,), daemon=True).start()
        self.notifier.status(f"TRIP {trip.cause}: {trip.detail}")
        # A drive fault ending a logged run: its 0x603F/0x1003 come later (read by SDO after
        # the fault); record them in the run's run.yaml once both are there (own thread).
        group = getattr(self.io.drives, "group", None)
        fault = group.fault() if group is not None else None
        run = getattr(self.loop, "_run", None)
        if fault is not None and fault.cause == trip.cause and getattr(run, "log_dir", ""):
            threading.Thread(
                target=record_drive_fault,
                args=(group, fault, run.log_dir),
                name="drive-fault-record",
                daemon=True,
            ).start()

    def _safety_status(self) -> dict[str, Any]:
        """What the layers below the supervisor latched: the drive group's first fault with the
        SYNC counts when it was latched and when the quick stop went out, and a sensor link
        that failed (each only when the I/O offers it)."""
        out: dict[str, Any] = {"later_trips": self.supervisor.later_trips}
        group = getattr(self.io.drives, "group", None)
        if group is not None:
            fault = group.fault()
            out["drives"] = {
                "sync_count": group.sync_count,
                "fault": None if fault is None else fault.text,
                # the faulted drive's 0x603F and 0x1003, read after the fault ('' until then)
                "diagnosis": None if fault is None else getattr(fault, "diagnosis", ""),
                "fault_at_sync": group.fault_at_sync,
                "quick_stop_at_sync": group.quick_stop_at_sync,
                "traffic_log_failure": getattr(group, "traffic_failure", None),
            }
        sampler = getattr(self.io.tensions, "sampler", None)
        if sampler is not None:
            failure = getattr(sampler, "failure", None)
            out["load_cells"] = {"failure": None if failure is None else str(failure)}
        tracker = getattr(self.io.tip, "tracker", None)
        if tracker is not None:
            failure = getattr(tracker, "failure", None)
            out["tracker"] = {"failure": None if failure is None else str(failure)}
        return out

    def _status_line(self) -> str:
        run = self.loop.snapshot()["run"]
        trip = self.supervisor.trip
        parts = [self.state, "enabled" if self.enabled else "disabled"]
        if run:
            parts.append(f"run {run['name']} {run['elapsed_s']:.1f}/{run['duration_s']:.1f} s")
        if trip:
            parts.append(f"trip {trip.cause}")
        return ", ".join(parts)


#: How long the run.yaml record of a drive fault waits for the drive's diagnosis (s).
DIAGNOSIS_WAIT_S = 3.0


def record_drive_fault(group: Any, fault: Any, run_dir: str) -> None:
    """``drive_fault`` in ``run_dir``/run.yaml: the group's fault with the faulted drive's
    0x603F and 0x1003 (waits up to :data:`DIAGNOSIS_WAIT_S` for them). Never raises."""
    try:
        end = time.monotonic() + DIAGNOSIS_WAIT_S
        while time.monotonic() < end:
            f = group.fault()
            if f is not fault and (f is None or f.cause != fault.cause):
                break  # reset meanwhile: keep what was seen
            fault = f
            if f.diagnosis:
                break
            time.sleep(0.05)
        record = {
            "cause": fault.cause,
            "node": fault.node,
            "code": f"0x{fault.code:04X}",
            "text": fault.text,
            "diagnosis": fault.diagnosis or None,
            "fault_at_sync": fault.at_sync,
        }
        annotate_when_ended(run_dir, "drive_fault", record)
    except Exception:  # a record must never take the daemon down
        log.exception("recording the drive fault in %s failed", run_dir)


def _trip_dict(t: Trip) -> dict[str, Any]:
    return {
        "cause": t.cause,
        "reaction": t.reaction.name,
        "detail": t.detail,
        "t_s": round(t.t_s, 4),
    }
