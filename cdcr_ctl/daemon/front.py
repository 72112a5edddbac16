"""The daemon's front process (issue #21): the control socket, the intake and the protocol, with
the rig side (loop, supervisor, drive bus) in a child process of its own
(:mod:`cdcr_ctl.daemon.rigproc`).

``cdcr-ctl daemon`` runs this: it is systemd's main process (``sd_notify``), owns the control
socket (:class:`~cdcr_ctl.daemon.server.ControlServer`: its client threads, size limits, slow
clients) and the :class:`~cdcr_ctl.daemon.intake.Intake` worker; each validated request goes to
the rig process over a pipe, and the reply comes back. None of that holds the rig process's
interpreter lock.

- the operator's ``stop`` line: a process of its own (:mod:`cdcr_ctl.daemon.stopline`) serves
  the stop socket beside the control socket, writes the shared stop flag and forwards the request
  to the rig process over a pipe of its own: no client of the control socket can delay it. It is
  started beside the rig process and waited for before the control socket opens.
- the front runs :data:`FRONT_NICE` nicer than the rig and stop processes: a flood of clients
  takes its CPU, not theirs.
- ``stop`` and ``shutdown`` on the control socket: the front writes the shared-memory
  :class:`~cdcr_ctl.control.stopflag.StopFlag` itself (no pipe, no lock, nothing queued before
  it), then forwards the request for the bus timing and bookkeeping; if the rig process does not
  answer in time the front answers from the flag's acted cycle.
- ``status``: coalesced: at most one round trip to the rig process is in flight; requests that
  arrive meanwhile share the next one (its answer is never older than their request).
- a trajectory ``file`` (or a big request, spooled) is prepared by the intake here; the rig
  process maps the prepared file.
- the rig process's end is noticed on the pipe: the front reports ``fault: rig process exited
  <code>`` for :data:`RIG_EXIT_REPORT_S` and then exits non-zero (systemd restarts the unit).
- SIGTERM/SIGINT or ``shutdown``: the rig process is told to shut down in order (halt, run log
  closed, drives disabled, bus closed) and waited for; then the socket and the intake close.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import time
from multiprocessing.connection import wait
from pathlib import Path
from typing import Any

from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.control.stopflag import StopFlag
from cdcr_ctl.daemon.coalesce import Coalescer
from cdcr_ctl.daemon.intake import Intake
from cdcr_ctl.daemon.notify import SystemdNotifier
from cdcr_ctl.daemon.outcome import outcome
from cdcr_ctl.daemon.protocol import COMMANDS, Request, check_jog_speed, stop_socket_path
from cdcr_ctl.daemon.rigshare import HEARTBEAT, SHARED_SLOTS, STOP_ACK_TIMEOUT_S, stop_reaction
from cdcr_ctl.daemon.server import ControlServer
from cdcr_ctl.daemon.serving import open_control_server, stop_signals
from cdcr_ctl.daemon.stopline import stop_main
from cdcr_ctl.errors import RigError

log = logging.getLogger(__name__)

#: Longest wait for the rig process to open the rig and start its loop (s): spawning an
#: interpreter, importing numpy/scipy and booting the drives over the bus.
RIG_START_TIMEOUT_S = 120.0
#: Longest wait for the rig process to end after ``shutdown`` (s): its ordered shutdown, inside
#: the unit's TimeoutStopSec (15 s).
RIG_STOP_TIMEOUT_S = 12.0
#: How long the front keeps answering after the rig process died, before it exits (s).
RIG_EXIT_REPORT_S = 3.0
#: Longest wait for a ``status`` round trip (s).
STATUS_TIMEOUT_S = 10.0
#: Slack on top of the rig's own stop wait before the front answers ``stop`` itself (s).
STOP_REPLY_SLACK_S = 1.0
#: Exit status of the front when the rig process died under it.
EXIT_RIG_DIED = 3
#: How much nicer than the rig and stop processes the front runs once they are started (its
#: threads serve every client: under a flood of clients they must not take the CPU the loop and
#: the stop line need; nice 10 weighs a tenth of nice 0 in the kernel's fair scheduler).
FRONT_NICE = 10
#: Longest wait for the stop process to open the stop socket (s): an interpreter's start.
STOP_LINE_START_TIMEOUT_S = 30.0


class _Pending:
    """One request's reply slot."""

    __slots__ = ("done", "out")

    def __init__(self) -> None:
        self.done = threading.Event()
        self.out: tuple[Any, ...] = ("rig", "no reply")


def rig_process(*args: Any) -> None:
    """The rig process's target: :func:`cdcr_ctl.daemon.rigproc.rig_main` (same arguments).

    Imported here, in the spawned child: the front itself imports none of the rig side (the
    loop, the drives and their CAN stack, the sensors, the run-log writer, the planner), which
    the child needs and the front does not (:mod:`cdcr_ctl.daemon.rigshare`)."""
    from cdcr_ctl.daemon.rigproc import rig_main

    rig_main(*args)


class FrontDaemon:
    """The front process (see the module docstring): ``start()``, then ``serve()`` until
    stopped; ``serve`` returns (reason, exit status)."""

    def __init__(
        self,
        cfg: RigConfig,
        config_path: Path,
        socket_path: str | None = None,
        verbose: bool = False,
        notifier: SystemdNotifier | None = None,
    ) -> None:
        self.cfg = cfg
        self.config_path = config_path
        self.notifier = notifier or SystemdNotifier()
        self.state = "starting"
        ctx = multiprocessing.get_context("spawn")
        self.shared = ctx.RawArray("q", SHARED_SLOTS)
        self.shared[StopFlag.ACTED_CYCLE] = -1
        self.flag = StopFlag(self.shared)
        n_segments = build_model(cfg, source=str(config_path)).n_segments
        self.intake = Intake(n_segments, cfg.limits.bend_rad)
        self._conn, child_conn = ctx.Pipe()
        # The stop line's own pipe to the rig process (see :mod:`.stopline`).
        self._stop_rig_conn, rig_stop_conn = ctx.Pipe()
        self.proc = ctx.Process(
            target=rig_process,
            args=(
                child_conn,
                self.shared,
                str(config_path),
                socket_path,
                str(self.intake.dir),
                verbose,
                rig_stop_conn,
            ),
            name="cdcr-rig",
        )
        self._rig_stop_conn = rig_stop_conn
        self._stop_ready, stop_ready_child = ctx.Pipe(duplex=False)
        self.stop_path = stop_socket_path(socket_path or cfg.daemon.socket_path)
        self.stop_proc = ctx.Process(
            target=stop_main,
            args=(
                str(self.stop_path),
                cfg.daemon.socket_mode,
                self.shared,
                self._stop_rig_conn,
                stop_ready_child,
                cfg.control.realtime_priority,
            ),
            name="cdcr-stop",
        )
        self._stop_ready_child = stop_ready_child
        self._child_conn = child_conn
        self._send_lock = threading.Lock()
        self._pending: dict[int, _Pending] = {}
        self._pending_lock = threading.Lock()
        self._tag = 0
        self._stop = threading.Event()
        self._stop_reason = ""
        self._exit_status = 0
        self._rig_exit: str | None = None
        self._rig_reason = ""
        self.server: ControlServer | None = None
        self.status_coalescer = Coalescer(lambda: self._call("status", None, STATUS_TIMEOUT_S))
        self._status_req: Request | None = None
        self._last_status: dict[str, Any] = {}

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> FrontDaemon:
        """Spawn the rig process, wait for its ``ready``, then open the control socket."""
        self.proc.start()
        self._child_conn.close()
        self._rig_stop_conn.close()
        # Started beside the rig process (its interpreter starts meanwhile); waited for below.
        self.stop_proc.start()
        self._stop_ready_child.close()
        self._stop_rig_conn.close()  # the stop process holds it now
        # This thread's nice is inherited by every thread and process the front starts later
        # (client threads, the intake); the rig and stop processes keep theirs.
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, os.getpriority(os.PRIO_PROCESS, 0) + FRONT_NICE)
        if not self._conn.poll(RIG_START_TIMEOUT_S):
            self._kill_rig()
            self._end_stop_line()
            raise RigError(f"rig process did not start within {RIG_START_TIMEOUT_S:g} s")
        try:
            _, (kind, detail) = self._conn.recv()
        except (EOFError, OSError) as exc:
            self.proc.join(5)
            raise RigError(f"rig process exited {self.proc.exitcode} during start-up") from exc
        if kind != "ready":
            self.proc.join(10)
            raise RigError(f"rig process failed to start: {detail}")
        threading.Thread(target=self._read, name="front-pipe", daemon=True).start()
        try:
            self._start_stop_line()
        except RigError:
            self.shutdown("stop line failed to start")
            raise
        self.server = open_control_server(self.cfg, self.handle, self.intake)
        self.state = "ready"
        self.notifier.ready(f"ready: {self.cfg.name}, drives disabled (rig pid {self.proc.pid})")
        log.info("daemon ready on %s (rig process %d)", self.cfg.daemon.socket_path, self.proc.pid)
        return self

    def serve(self, install_signals: bool = True) -> tuple[str, int]:
        """Run until SIGTERM/SIGINT, ``shutdown`` or the rig process's end; shut down in order
        and return (reason, exit status)."""
        with stop_signals(install_signals, self._signal):
            period = min(self.notifier.watchdog_period_s() or 1.0, 1.0)
            beat = self.shared[HEARTBEAT]
            while not self._stop.wait(period):
                now = self.shared[HEARTBEAT]
                if now != beat:
                    # Pet the watchdog only while the rig's loop is alive.
                    self.notifier.watchdog()
                    self.notifier.status(self._status_line())
                beat = now
            self.shutdown(self._stop_reason or "stopped")
        return self._stop_reason, self._exit_status

    def _signal(self, signum: int, frame: object) -> None:
        self._stop_reason = f"signal {signal.Signals(signum).name}"
        self._stop.set()

    def shutdown(self, reason: str) -> None:
        """The rig process shuts down in order (halt, logs, drives, bus) and is waited for;
        then the socket and the intake close. Never raises."""
        self.state = "stopping"
        self.notifier.stopping()
        if self.proc.is_alive():
            self.flag.request(stop_reaction("halt"))
            with contextlib.suppress(Exception):
                self._call("shutdown", None, 2.0)
            # Its sentinel, not is_alive(): the pipe thread may be reaping it at the same
            # moment (_rig_gone), and a waitpid lost to that thread reads as "alive".
            if not wait([self.proc.sentinel], RIG_STOP_TIMEOUT_S):
                log.error("rig process did not end in %g s; terminating", RIG_STOP_TIMEOUT_S)
                self._kill_rig()
            self.proc.join(5)
        for name, step in (
            ("stop line", self._end_stop_line),
            ("close socket", lambda: self.server.close() if self.server else None),
            ("intake", self.intake.close),
            ("pipe", self._conn.close),
        ):
            try:
                step()
            except Exception:
                log.exception("shutdown step %r failed", name)
        self.state = "stopped"
        log.info("daemon stopped: %s (rig process exit %s)", reason, self.proc.exitcode)

    def _start_stop_line(self) -> None:
        """Wait for the stop process's socket (see :mod:`.stopline`)."""
        if not self._stop_ready.poll(STOP_LINE_START_TIMEOUT_S):
            raise RigError(f"stop process did not start within {STOP_LINE_START_TIMEOUT_S:g} s")
        try:
            kind, detail = self._stop_ready.recv()
        except (EOFError, OSError) as exc:
            raise RigError(f"stop process exited {self.stop_proc.exitcode} at start") from exc
        if kind != "ready":
            raise RigError(f"stop process failed to start: {detail}")
        log.info("stop line on %s (pid %d, %s)", self.stop_path, self.stop_proc.pid, detail)

    def _end_stop_line(self) -> None:
        if self.stop_proc.pid is None:
            return
        self.stop_proc.terminate()
        self.stop_proc.join(5)
        if self.stop_proc.is_alive():
            self.stop_proc.kill()
            self.stop_proc.join(5)

    def _kill_rig(self) -> None:
        self.proc.terminate()
        self.proc.join(5)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5)

    # ------------------------------------------------------------------ the pipe
    def _read(self) -> None:
        while True:
            try:
                tag, out = self._conn.recv()
            except (EOFError, OSError):
                break
            if tag == 0:
                if out[0] == "exited":
                    self._rig_reason = str(out[1])
                continue
            with self._pending_lock:
                slot = self._pending.pop(tag, None)
            if slot is not None:
                slot.out = out
                slot.done.set()
        self._rig_gone()

    def _rig_gone(self) -> None:
        self.proc.join(RIG_STOP_TIMEOUT_S)
        code = self.proc.exitcode
        self._rig_exit = f"rig process exited {code}" + (
            f" ({self._rig_reason})" if self._rig_reason else ""
        )
        with self._pending_lock:
            pending, self._pending = self._pending, {}
        for slot in pending.values():
            slot.out = ("rig", self._rig_exit)
            slot.done.set()
        if self._stop.is_set() or self.state == "stopping":
            return  # an ordered shutdown
        self.state = f"fault: {self._rig_exit}"
        log.error("%s; the daemon exits (systemd restarts it)", self._rig_exit)
        self.notifier.status(f"FAULT {self._rig_exit}")
        self._exit_status = EXIT_RIG_DIED
        timer = threading.Timer(
            RIG_EXIT_REPORT_S, self._request_stop, args=(f"fault: {self._rig_exit}",)
        )
        timer.daemon = True
        timer.start()

    def _request_stop(self, reason: str) -> None:
        self._stop_reason = reason
        self._stop.set()

    def _call(self, cmd: str, req: Request | None, timeout_s: float | None, **extra: Any) -> Any:
        """Forward ``req`` (or an argument-less ``cmd``) to the rig process; its result, or its
        error raised here."""
        if self._rig_exit is not None:
            raise RigError(self._rig_exit)
        if req is None:
            req = _request(cmd)
        slot = _Pending()
        with self._pending_lock:
            self._tag += 1
            tag = self._tag
            self._pending[tag] = slot
        try:
            with self._send_lock:
                self._conn.send((tag, req, extra))
        except (OSError, ValueError) as exc:
            with self._pending_lock:
                self._pending.pop(tag, None)
            raise RigError(f"rig process unreachable: {exc}") from exc
        if not slot.done.wait(timeout_s):
            with self._pending_lock:
                self._pending.pop(tag, None)
            raise RigError(f"rig process did not answer {cmd!r} within {timeout_s:g} s")
        return outcome(slot.out)

    # ------------------------------------------------------------------ requests
    def handle(self, req: Request) -> Any:
        if req.cmd == "stop":
            return self._stop_cmd(req)
        if req.cmd == "shutdown":
            self.flag.request(stop_reaction("halt"))
            with contextlib.suppress(RigError):
                self._call("shutdown", req, 2.0)
            self._request_stop("shutdown requested")
            return {"stopping": True}
        if req.cmd == "status":
            return self._status()
        if req.cmd == "jog" and req.args.segment is not None:
            check_jog_speed(req.args.speed, self.cfg.limits.bend_rad)
        if req.cmd == "trajectory" and req.args.file is not None:
            # Read and validated here, in the intake worker; the rig process maps the result.
            prepared = self.intake.prepare_file(req.args.file)
            req = Request(
                id=req.id,
                cmd=req.cmd,
                args=req.args.model_copy(update={"file": prepared}),
            )
        return self._call(req.cmd, req, None)

    def _stop_cmd(self, req: Request) -> dict[str, Any]:
        arrived = time.time()
        cycle0 = self.flag.cycle
        reaction = stop_reaction(req.args.mode)
        seq = self.flag.request(reaction)
        extra = {"seq": seq, "cycle": cycle0, "arrived_wall_s": arrived}
        try:
            return self._call("stop", req, STOP_ACK_TIMEOUT_S + STOP_REPLY_SLACK_S, **extra)
        except RigError as exc:
            # The rig process is busy or gone: answer from the flag itself.
            end = time.monotonic() + STOP_ACK_TIMEOUT_S
            acted = self.flag.acted_cycle(seq)
            while acted is None and time.monotonic() < end and self._rig_exit is None:
                time.sleep(0.001)
                acted = self.flag.acted_cycle(seq)
            return {
                "stopped": req.args.mode,
                "acted_cycle": acted,
                "cycles_waited": None if acted is None else acted - cycle0,
                "bus": None,
                "note": str(exc),
            }

    def _status(self) -> dict[str, Any]:
        if self._rig_exit is not None:
            return self._dead_status()
        try:
            st = self.status_coalescer.get()
        except RigError:
            if self._rig_exit is not None:
                return self._dead_status()
            raise
        self._last_status = st
        return {**st, "front": self._front_status()}

    def _front_status(self) -> dict[str, Any]:
        """The front's own: its pid, the rig process's, and what status requests cost."""
        c = self.status_coalescer
        return {
            "pid": os.getpid(),
            "rig_pid": self.proc.pid,
            "status_requests": c.calls,
            "status_round_trips": c.fetches,
        }

    def _dead_status(self) -> dict[str, Any]:
        cause = {"cause": "rig_process_exited", "reaction": "QUICK_STOP", "detail": self._rig_exit}
        return {
            **self._last_status,
            "front": self._front_status(),
            "state": f"fault: {self._rig_exit}",
            "enabled": False,
            "fault": {**cause, "t_s": 0.0},
        }

    def _status_line(self) -> str:
        st = self._last_status
        if not st:
            return self.state
        parts = [str(st.get("state")), "enabled" if st.get("enabled") else "disabled"]
        if st.get("fault"):
            parts.append(f"trip {st['fault'].get('cause')}")
        return ", ".join(parts)


def _request(cmd: str) -> Request:
    return Request(id=0, cmd=cmd, args=COMMANDS[cmd]())


__all__ = ["EXIT_RIG_DIED", "Coalescer", "FrontDaemon"]
