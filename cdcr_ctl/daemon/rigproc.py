"""The rig process: the control loop, its supervisor and the drive bus in a process of their own
(issue #21), fed by the daemon's front process (:mod:`cdcr_ctl.daemon.front`) over a pipe.

Why a process: the loop shares the Python interpreter lock with every thread of its process.
Socket threads (hundreds of clients, slow clients, status floods), protocol parsing and the
intake's bookkeeping all take it; in one process the loop at 1 kHz ran up to several ms late
behind them (README, "The control plane cannot stall the loop"). Here the process holds only the
rig side: the loop, the CAN notifier and traffic log, the sensors, the run-log writer (which
owns its own writer child when the run log has one) and two command threads. The loop sets the
process's interpreter switch interval to
:data:`~cdcr_ctl.control.loop.GIL_SWITCH_INTERVAL_S` (50 us) when it starts: another thread of
this process keeps the lock at most that long once the loop asks for it.

:func:`rig_main` builds exactly what the one-process daemon builds (config, model, run-log
factory, rig I/O, :class:`~cdcr_ctl.daemon.service.Daemon` with its loop and command handlers)
but no control socket; it raises its priority before any of its threads start. Requests arrive
already parsed and validated, as ``(tag, Request, extra)`` on a
:class:`multiprocessing.connection.Connection`; replies go back as ``(tag, outcome)`` where
``outcome`` is :func:`encode_outcome`'s tuple (the project's errors do not survive pickling).
A big trajectory never crosses the pipe: the front's intake prepares it as a file in its own
directory, which this process maps (``numpy.load(mmap_mode="r")``).

The stop line's ``stop`` requests (:mod:`cdcr_ctl.daemon.stopline`) arrive on a pipe of their
own, read by a thread of their own, and are answered on it.

Two command threads: ``status``, ``stop`` and ``shutdown`` on one (never behind a long command),
every other command on the other, in arrival order (the daemon's command lock serialises them
as before). ``stop`` has already been acted on when it arrives here: the front wrote the
shared-memory :class:`~cdcr_ctl.control.stopflag.StopFlag`; this process only times it on the
bus and updates its state (:func:`cdcr_ctl.daemon.recovery.await_stop`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory
from cdcr_ctl.control.io import open_rig_io
from cdcr_ctl.control.ports import attach_attitude
from cdcr_ctl.control.timing import try_realtime
from cdcr_ctl.daemon import recovery
from cdcr_ctl.daemon.gcwatch import GcWatch, thread_cpu_s
from cdcr_ctl.daemon.intake import Intake
from cdcr_ctl.daemon.notify import SystemdNotifier
from cdcr_ctl.daemon.outcome import encode_outcome as _encode
from cdcr_ctl.daemon.outcome import outcome
from cdcr_ctl.daemon.planner import Planner
from cdcr_ctl.daemon.rigshare import HEARTBEAT, SHARED_SLOTS, stop_reaction
from cdcr_ctl.daemon.service import Daemon
from cdcr_ctl.daemon.workers import watch_process
from cdcr_ctl.runlog.writer.factory import RunLogFactory

log = logging.getLogger(__name__)

#: How often the rig process's heartbeat counts (s).
HEARTBEAT_PERIOD_S = 0.2
#: Command handlings remembered for ``status`` ``rig_command_log`` (the last ones).
COMMAND_LOG_LEN = 256
#: Commands served on the quick thread (never behind loading, planning or homing).
QUICK_COMMANDS = ("status", "stop", "shutdown")


def _handler_bug(exc: Exception) -> tuple[Any, ...]:
    """A handler bug: its type and text, as the one-process daemon."""
    log.exception("rig process: handler failed")
    return ("internal", type(exc).__name__, str(exc))


def encode_outcome(fn: Any, *args: Any) -> tuple[Any, ...]:
    """Run ``fn(*args)``; ``("ok", result)`` or the error as a plain tuple :func:`outcome`
    raises again on the other side."""
    return _encode(fn, *args, on_bug=_handler_bug)


class RigCommandServer:
    """Serves the front's requests to ``daemon`` over ``conn`` (see the module docstring)."""

    def __init__(self, daemon: Any, conn: Any, shared: Any, stop_conn: Any = None) -> None:
        """``stop_conn``: the stop line's pipe (:mod:`.stopline`): its ``stop`` requests, served
        on the quick thread and answered on it."""
        self.d, self.conn, self.shared = daemon, conn, shared
        self.gc_watch = GcWatch(1.0 / daemon.cfg.control.rate_hz).install()
        #: Per command name: (count, longest wall ms, longest CPU ms) of its handling here.
        self.command_ms: dict[str, tuple[int, float, float]] = {}
        #: The last handlings: (command, start, end (``time.monotonic``, s), CPU ms), to line
        #: the loop's late cycles up with what this process was doing (benchmarks).
        self.command_log: deque[tuple[str, float, float, float]] = deque(maxlen=COMMAND_LOG_LEN)
        self._send_lock = threading.Lock()
        self._quick: queue.Queue[Any] = queue.Queue()
        self._slow: queue.Queue[Any] = queue.Queue()
        self._closed = threading.Event()
        self._threads = [
            threading.Thread(target=self._read, args=(conn,), name="rig-pipe", daemon=True),
            threading.Thread(target=self._work, args=(self._quick,), name="rig-quick", daemon=True),
            threading.Thread(target=self._work, args=(self._slow,), name="rig-cmd", daemon=True),
            threading.Thread(target=self._beat, name="rig-heartbeat", daemon=True),
        ]
        if stop_conn is not None:
            self._threads.append(
                threading.Thread(
                    target=self._read, args=(stop_conn,), name="rig-stop-pipe", daemon=True
                )
            )

    def start(self) -> RigCommandServer:
        for th in self._threads:
            th.start()
        return self

    def send(self, message: Any, conn: Any = None) -> None:
        # OSError/ValueError: the front is gone (its end of the pipe closed).
        with self._send_lock, contextlib.suppress(OSError, ValueError):
            (conn or self.conn).send(message)

    def _read(self, conn: Any) -> None:
        while not self._closed.is_set():
            try:
                tag, req, extra = conn.recv()
            except (EOFError, OSError):
                if conn is self.conn and not self._closed.is_set():
                    log.error("rig process: the front process is gone; shutting down")
                    self.d.request_stop("front process exited")
                return
            if conn is not self.conn and req.cmd != "stop":
                continue  # the stop line sends only stop
            q = self._quick if req.cmd in QUICK_COMMANDS else self._slow
            q.put((conn, tag, req, extra))

    def _work(self, q: queue.Queue[Any]) -> None:
        while True:
            item = q.get()
            if item is None:
                return
            conn, tag, req, extra = item
            c0, t0 = time.thread_time(), time.monotonic()
            out = encode_outcome(self._handle, req, extra)
            t1, cpu_s = time.monotonic(), time.thread_time() - c0
            self._timed(req.cmd, t1 - t0, cpu_s)
            self.command_log.append((req.cmd, t0, t1, round(cpu_s * 1e3, 3)))
            self.send((tag, out), conn)

    def _timed(self, cmd: str, wall_s: float, cpu_s: float) -> None:
        # Per command: count, longest wall and CPU time (ms) of its handling in this process
        # (status ``rig_commands``): a command thread's CPU is interpreter lock the loop waited
        # for unless the work released it.
        n, wall, cpu = self.command_ms.get(cmd, (0, 0.0, 0.0))
        self.command_ms[cmd] = (n + 1, max(wall, wall_s * 1e3), max(cpu, cpu_s * 1e3))

    def _handle(self, req: Any, extra: dict[str, Any]) -> Any:
        if req.cmd == "stop" and "seq" in extra:
            d = self.d
            reaction = stop_reaction(req.args.mode)
            acted = recovery.await_stop(
                d, reaction, extra["seq"], extra["cycle"], extra["arrived_wall_s"]
            )
            return d.stopped(req.args.mode, acted)
        out = self.d.handle(req)
        if req.cmd == "status" and isinstance(out, dict):
            out = {
                **out,
                "rig_gc": self.gc_watch.summary(),
                "rig_threads_cpu_s": thread_cpu_s(),
                "rig_commands": {
                    k: {"n": n, "wall_max_ms": round(w, 3), "cpu_max_ms": round(c, 3)}
                    for k, (n, w, c) in self.command_ms.items()
                },
                "rig_command_log": list(self.command_log),
                # Lead-ins and jogs planned in the planner's worker, and those planned here
                # because it could not (None: this process plans them itself).
                "rig_planner": None
                if self.d.planner is None
                else {"plans": self.d.planner.plans, "failures": self.d.planner.failures},
            }
        return out

    def _beat(self) -> None:
        while not self._closed.wait(HEARTBEAT_PERIOD_S):
            if self.d.loop.running:
                self.shared[HEARTBEAT] += 1

    def close(self, reason: str) -> None:
        """Tell the front why this process ends, and stop serving."""
        self._closed.set()
        self.gc_watch.remove()
        self.send((0, ("exited", reason)))
        self._quick.put(None)
        self._slow.put(None)


def _tell(conn: Any, message: tuple[Any, ...]) -> None:
    """Send the front a start-up message; a front already gone (its end closed) is not an error
    here (:func:`rig_main` watches its process)."""
    with contextlib.suppress(OSError, ValueError):
        conn.send((0, message))


def build_daemon(config_path: str, socket_path: str | None, intake_dir: str) -> Daemon:
    """What the one-process ``cdcr-ctl daemon`` builds, with the front's intake directory and
    no systemd notifications (the front is systemd's main process)."""
    path = Path(config_path)
    cfg = load_rig_config(path)
    if socket_path:
        cfg = cfg.model_copy(
            update={"daemon": cfg.daemon.model_copy(update={"socket_path": socket_path})}
        )
    model = build_model(cfg, source=str(path))
    # The run log's /tip/model: a model instance of its own (the writer's, not the loop's).
    sinks = RunLogFactory.from_config(
        cfg, path, tip_from_psi=build_model(cfg, source=str(path)).tip
    )
    # Lead-ins and jog moves are planned in a worker of this process's (started before the
    # priority is raised, so it runs at the ordinary policy), unless the model reads a live
    # sensor of this process (attitude), which a worker would not have.
    planner = None
    if getattr(model, "attach_attitude", None) is None or cfg.sensors.attitude is None:
        planner = Planner(path).start()
    # Before any thread of this process exists: every thread inherits the policy.
    try_realtime(cfg.control.realtime_priority, cfg.control.lock_memory)
    io = open_rig_io(cfg, path, traffic_dir=sinks.base_dir)
    attach_attitude(model, io)
    intake = Intake(model.n_segments, cfg.limits.bend_rad, directory=intake_dir)
    return Daemon(
        cfg,
        path,
        io,
        model,
        sinks,
        trajectory,
        notifier=SystemdNotifier(address=""),
        intake=intake,
        planner=planner,
    )


def rig_main(
    conn: Any,
    shared: Any,
    config_path: str,
    socket_path: str | None,
    intake_dir: str,
    verbose: bool,
    stop_conn: Any = None,
) -> None:
    """(the rig process's main) Build the daemon, start its loop, tell the front ``ready`` and
    serve until SIGTERM/SIGINT, ``shutdown`` or the front's end; exits 0 after an ordered
    shutdown (halt, logs closed, drives disabled, bus closed), 2 when start-up failed."""
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s[rig]: %(message)s",
        stream=sys.stderr,
    )
    front_gone = watch_process(os.getppid())
    try:
        d = build_daemon(config_path, socket_path, intake_dir)
    except BaseException as exc:
        _tell(conn, ("failed", f"{type(exc).__name__}: {exc}"))
        raise SystemExit(2) from exc
    d.loop.stop_flag.store = shared  # the front raises it directly
    try:
        d.start(serve_socket=False)
    except BaseException as exc:
        d.shutdown("start-up failed")
        _tell(conn, ("failed", f"{type(exc).__name__}: {exc}"))
        raise SystemExit(2) from exc
    server = RigCommandServer(d, conn, shared, stop_conn).start()
    # A front killed during this start-up: its pipe is closed (the reader thread sees EOF too)
    # and its process is gone; the daemon is stopped in order before it serves anyone.
    _tell(conn, ("ready", {"rig": d.cfg.name, "at": time.time()}))
    threading.Thread(
        target=lambda: front_gone.wait() and d.request_stop("front process exited"),
        name="rig-front-watch",
        daemon=True,
    ).start()
    reason = d.serve()
    server.close(reason)
    log.info("rig process ends: %s", reason)


__all__ = [
    "HEARTBEAT",
    "QUICK_COMMANDS",
    "SHARED_SLOTS",
    "RigCommandServer",
    "build_daemon",
    "encode_outcome",
    "outcome",
    "rig_main",
]
