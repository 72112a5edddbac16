"""The daemon: owns the rig I/O and the control loop, answers the control socket, talks to systemd.

Start-up order makes a bad config harmless: the config is validated before anything is opened;
the bus, drives and sensors are opened next; the drives stay disabled until ``enable``. Shutdown
(SIGTERM, ``shutdown`` request) ends the running trajectory, closes its log, disables the drives and
closes the bus, in that order, and every step runs even if an earlier one failed.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.control.clock import LoopClock
from cdcr_ctl.control.loop import OPERATOR_STOP, ControlLoop, LoopConfig
from cdcr_ctl.control.ports import RigIO
from cdcr_ctl.control.supervisor import Reaction, Supervisor, Trip
from cdcr_ctl.daemon import recovery
from cdcr_ctl.daemon.bustap import StopBusTap
from cdcr_ctl.daemon.commands_drive import DriveCommands, stopped
from cdcr_ctl.daemon.commands_log import LogCommands
from cdcr_ctl.daemon.commands_run import RUN_PICKUP_TIMEOUT_S, RunCommands
from cdcr_ctl.daemon.intake import Intake
from cdcr_ctl.daemon.joystick import JoystickSession
from cdcr_ctl.daemon.notify import SystemdNotifier
from cdcr_ctl.daemon.planner import Planner
from cdcr_ctl.daemon.protocol import Request
from cdcr_ctl.daemon.server import ControlServer
from cdcr_ctl.daemon.serving import open_control_server, stop_signals
from cdcr_ctl.daemon.status import StatusCommands, _trip_dict
from cdcr_ctl.model.port import RobotModelPort
from cdcr_ctl.runlog.annotate import annotate_when_ended
from cdcr_ctl.runlog.live import LiveView, live_view_for

log = logging.getLogger(__name__)

#: How long shutdown waits for the loop thread to finish its last cycle (s).
LOOP_JOIN_TIMEOUT_S = 2.0
#: Commands answered without the command lock: they never wait behind loading or planning.
UNLOCKED_COMMANDS = ("stop", "shutdown", "status")


class Daemon(RunCommands, LogCommands):
    """Wires config, model, I/O, loop and control socket; :meth:`serve` runs until stopped.

    The drive and status commands are handlers over the daemon as a
    :class:`~cdcr_ctl.daemon.rig.Rig` (:class:`DriveCommands`, :class:`StatusCommands`); the run
    and log commands are its ``_cmd_*`` methods."""

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
        intake: Intake | None = None,
        planner: Planner | None = None,
        before_command: Callable[[Request], None] | None = None,
    ) -> None:
        """``joystick_opener(JoystickConfig)`` opens the rig's joystick for a ``joystick``
        session (default :func:`cdcr_ctl.sensors.joystick.open_joystick`). ``clock``: the
        loop's clock (default the wall clock; the lock-step simulator passes its own).
        ``intake``: where trajectory files are prepared (default a worker of this daemon's; the
        rig process passes its front process's, whose prepared files it maps). ``planner``:
        plans lead-ins and jog moves in a worker process (:mod:`.planner`); None plans them in
        this process (the one-process daemon, lock-step). ``before_command(req)``: called
        before each command that takes the command lock (the lock-step simulator waits there
        for its loop to settle, so that a command's simulated time does not depend on the
        host's scheduling)."""
        self.cfg = cfg
        self._before_command = before_command
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
        group = getattr(io.drives, "group", None)
        if group is not None and hasattr(group, "traffic_quiet"):
            # The traffic log's writer formats frames only between the loop's cycles.
            group.traffic_quiet = self.loop.between_cycles
        if hasattr(run_sink_factory, "quiet"):
            # The run log's rows go into its writer process's ring between the loop's cycles.
            run_sink_factory.quiet = self.loop.between_cycles
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
        self.intake = intake or Intake(model.n_segments, cfg.limits.bend_rad)
        self.planner = planner
        #: Times ``stop`` on the CAN traffic a run logs (first quick-stop frame after a request).
        self.bus_tap = StopBusTap()
        self.status_commands = StatusCommands(self)
        #: Command name -> handler; the rest are this class's ``_cmd_<name>`` methods.
        self.handlers: dict[str, Callable[[Any], Any]] = {
            **DriveCommands(self).handlers,
            **self.status_commands.handlers,
        }

    # ------------------------------------------------------------------ lifecycle
    def start(self, serve_socket: bool = True) -> None:
        """Start the loop, the live view and the start-pose adoption; with ``serve_socket``
        also the intake worker and the control socket (the rig process of
        :mod:`cdcr_ctl.daemon.front` leaves both to its front process)."""
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
        if serve_socket:
            self.server = open_control_server(self.cfg, self.handle, self.intake)
        self.state = "ready"
        self.notifier.ready(f"ready: {self.cfg.name}, drives disabled")
        log.info("daemon ready on %s", self.cfg.daemon.socket_path)

    def serve(self, install_signals: bool = True) -> str:
        """Run until SIGTERM/SIGINT or a ``shutdown`` request; return the stop reason."""
        with stop_signals(install_signals, self._signal):
            period = self.notifier.watchdog_period_s() or 1.0
            while not self._stop.wait(min(period, 1.0)):
                if self.loop.running:
                    # Pet the watchdog only while the loop is alive: a hung loop gets us
                    # restarted.
                    self.notifier.watchdog()
                    self.notifier.status(self.status_commands.line())
                else:
                    log.error("control loop thread died; stopping")
                    self._stop_reason = "control loop died"
                    break
            self.shutdown(self._stop_reason or "stopped")
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
            # The run logs' writers finish their files (the loop closed them without waiting).
            ("run logs", lambda: getattr(self.new_sink, "close_all", lambda r: None)(reason)),
            ("close socket", lambda: self.server.close() if self.server else None),
            ("live view", lambda: self.live.stop() if self.live else None),
            ("intake", self.intake.close),
            ("planner", lambda: self.planner.close() if self.planner else None),
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
        method = self.handlers.get(req.cmd) or getattr(self, f"_cmd_{req.cmd}")
        if req.cmd in UNLOCKED_COMMANDS:
            return method(req.args)
        with self._cmd_lock:
            if self._before_command is not None:
                self._before_command(req)
            return method(req.args)

    def stopped(self, mode: str, acted: dict[str, Any]) -> dict[str, Any]:
        """The reply to a ``stop`` whose flag the front process raised (see
        :func:`~cdcr_ctl.daemon.commands_drive.stopped`)."""
        return stopped(self, mode, acted)

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


__all__ = [
    "DIAGNOSIS_WAIT_S",
    "LOOP_JOIN_TIMEOUT_S",
    "RUN_PICKUP_TIMEOUT_S",
    "UNLOCKED_COMMANDS",
    "Daemon",
    "DriveCommands",
    "LogCommands",
    "RigIO",
    "RunCommands",
    "StatusCommands",
    "_trip_dict",
    "record_drive_fault",
]
