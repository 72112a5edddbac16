"""Fault injection into a running simulated rig, through a Unix socket beside it.

``cdcr-ctl sim CONFIG --faults PATH`` serves this channel at ``PATH`` (mode 0600: only the user
running the simulator may break it). One JSON object per line each way::

    -> {"fault": "emcy", "node": 2, "code": "following_error"}
    <- {"ok": true, "fault": "emcy", "t_s": 1234.5678, "syncs": {"1": 812, "2": 812, "3": 812}}

``t_s`` is ``time.monotonic()`` in the simulator at the moment of injection (CLOCK_MONOTONIC is
system-wide on Linux, so other processes on the machine can compare it with theirs); ``syncs``
the SYNC count each simulated drive had seen then. Errors answer ``{"ok": false, "error": ...}``
naming the field.

Faults (:data:`FAULTS`):

- ``emcy`` ``node``, ``code`` (``following_error`` 0x8611, ``over_current`` 0x2310 or any EMCY
  code as an integer or ``"0x...."``): the drive faults (power stage off) and sends the EMCY;
- ``drive_reboot`` ``node``: the drive restarts (boot-up message, factory configuration);
- ``heartbeat_stop`` / ``heartbeat_start`` ``node``: the drive stops / resumes its heartbeat;
- ``bus_off`` / ``bus_recover`` ``node``: the drive's CAN controller goes bus off (the drive
  faults and answers nothing) / comes back and reports it;
- ``adapter_unplug``: the USB-CAN adapter vanishes (its pty closes);
- ``loadcell_disconnect`` / ``loadcell_reconnect``: the transmitter's serial link is pulled /
  plugged back (a new pty at the same path);
- ``loadcell_garbage`` ``duration_s``: every reply is line noise and a bad CRC for that long;
- ``tracker_dropout`` ``duration_s`` (default: until ``tracker_resume``): the tracker sends
  nothing;
- ``tension_spike`` ``cable`` (name), ``add_N``, ``duration_s``: the cable's load cell reads
  ``add_N`` more (a snagged cable).

Queries (:data:`QUERIES`): ``drives`` (per drive: state, SYNCs seen, when its CSP target last
changed), ``transitions`` ``since_t_s`` (every state change of every drive after that time, with
time and SYNC count), ``counters`` (the simulator's, and ``host_frames``: the controller's frames
by CiA 301 service, :func:`cdcr_ctl.sim.epos.rig.frame_kind`).

Production code never imports this module; tests and benchmarks talk to it with
:class:`FaultClient`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import socketserver
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cdcr_ctl.drives.emcy import FOLLOWING_ERROR, OVER_CURRENT

log = logging.getLogger(__name__)

#: Longest request line accepted (bytes).
MAX_LINE_BYTES = 4096
#: How long a client waits for an answer (s).
CLIENT_TIMEOUT_S = 10.0

#: Named EMCY codes for the ``emcy`` fault.
EMCY_CODES = {"following_error": FOLLOWING_ERROR, "over_current": OVER_CURRENT}

#: The drive states that are safe: no torque, or a quick stop ramping the motor down.
SAFE_STATES = ("QUICK STOP ACTIVE", "SWITCH ON DISABLED", "FAULT", "FAULT REACTION ACTIVE")


class FaultError(ValueError):
    """A fault request that cannot be carried out; ``field`` names the offending field."""

    def __init__(self, field: str, msg: str) -> None:
        super().__init__(f"{field}: {msg}")
        self.field = field


class FaultInjector:
    """The injectors, bound to one :class:`~cdcr_ctl.sim.rig.SimRig` (started)."""

    def __init__(self, rig: Any) -> None:
        self.rig = rig
        self._timers: list[threading.Timer] = []
        self.injected: list[tuple[float, str]] = []

    # ------------------------------------------------------------------ helpers
    def _node(self, args: dict[str, Any]) -> Any:
        nid = args.get("node")
        if not isinstance(nid, int) or isinstance(nid, bool):
            raise FaultError("node", f"expected a node id (integer), got {nid!r}")
        try:
            return self.rig.drives.node(nid)
        except KeyError:
            ids = [n.node_id for n in self.rig.drives.nodes]
            raise FaultError("node", f"no simulated drive {nid} (have {ids})") from None

    def _loadcells(self) -> Any:
        if self.rig.load_cells is None:
            raise FaultError("fault", "this rig has no load cells")
        return self.rig.load_cells

    def _tracker(self) -> Any:
        if self.rig.tracker is None:
            raise FaultError("fault", "this rig has no tracker")
        return self.rig.tracker

    @staticmethod
    def _seconds(args: dict[str, Any], key: str, default: float | None = None) -> float | None:
        v = args.get(key, default)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, int | float) or not 0 < v <= 3600:
            raise FaultError(key, f"expected seconds in (0, 3600], got {v!r}")
        return float(v)

    def _later(self, delay_s: float, fn: Callable[[], None]) -> None:
        t = threading.Timer(delay_s, fn)
        t.daemon = True
        t.start()
        self._timers = [x for x in self._timers if x.is_alive()] + [t]

    def drive_syncs(self) -> dict[str, int]:
        return {str(n.node_id): n.sync_count for n in self.rig.drives.nodes}

    # ------------------------------------------------------------------ faults
    def emcy(self, args: dict[str, Any]) -> None:
        node = self._node(args)
        code = args.get("code", "following_error")
        if isinstance(code, str):
            if code in EMCY_CODES:
                code = EMCY_CODES[code]
            else:
                try:
                    code = int(code, 0)
                except ValueError:
                    names = list(EMCY_CODES)
                    raise FaultError("code", f"{code!r}: one of {names} or 0x....") from None
        if isinstance(code, bool) or not isinstance(code, int) or not 0 < code <= 0xFFFF:
            raise FaultError("code", f"EMCY code must be in 0x0001..0xFFFF, got {code!r}")
        node.inject_fault(code)

    def heartbeat_stop(self, args: dict[str, Any]) -> None:
        self._node(args).stop_heartbeat()

    def heartbeat_start(self, args: dict[str, Any]) -> None:
        self._node(args).start_heartbeat()

    def drive_reboot(self, args: dict[str, Any]) -> None:
        """The drive restarts (power dip, watchdog): boot-up message, factory configuration."""
        self._node(args).power_cycle()

    def bus_off(self, args: dict[str, Any]) -> None:
        self._node(args).enter_bus_off()

    def bus_recover(self, args: dict[str, Any]) -> None:
        self._node(args).recover_from_bus_off()

    def adapter_unplug(self, args: dict[str, Any]) -> None:
        self.rig.drives.unplug()

    def loadcell_disconnect(self, args: dict[str, Any]) -> None:
        self._loadcells().disconnect()

    def loadcell_reconnect(self, args: dict[str, Any]) -> None:
        self._loadcells().reconnect()

    def loadcell_garbage(self, args: dict[str, Any]) -> None:
        self._loadcells().garble_for(self._seconds(args, "duration_s", 1.0))

    def tracker_dropout(self, args: dict[str, Any]) -> None:
        tracker = self._tracker()
        tracker.pause()
        duration = self._seconds(args, "duration_s")
        if duration is not None:
            self._later(duration, tracker.resume)

    def tracker_resume(self, args: dict[str, Any]) -> None:
        self._tracker().resume()

    def tension_spike(self, args: dict[str, Any]) -> None:
        lc = self._loadcells()
        cable = args.get("cable")
        cells = [c.cable for c in self.rig.rig.sensors.load_cells.cells]
        if cable not in cells:
            raise FaultError("cable", f"{cable!r} has no load cell (cells on {cells})")
        add = args.get("add_N")
        if isinstance(add, bool) or not isinstance(add, int | float) or not abs(add) < 1e4:
            raise FaultError("add_N", f"expected newtons, got {add!r}")
        lc.feed.spike(cells.index(cable), float(add), self._seconds(args, "duration_s", 1.0))

    # ------------------------------------------------------------------ queries
    def drives(self, args: dict[str, Any]) -> dict[str, Any]:
        return {
            "drives": [
                {
                    "node": n.node_id,
                    "state": n.state.value,
                    "syncs": n.sync_count,
                    "silent": n.silent,
                    "target_changed": list(n.last_target_change),
                    "error_code": n.error_code,
                }
                for n in self.rig.drives.nodes
            ]
        }

    def transitions(self, args: dict[str, Any]) -> dict[str, Any]:
        since = args.get("since_t_s", 0.0)
        if isinstance(since, bool) or not isinstance(since, int | float):
            raise FaultError("since_t_s", f"expected a monotonic time (s), got {since!r}")
        return {
            "transitions": [
                {"node": n.node_id, "t_s": t, "sync": s, "state": st.value}
                for n in self.rig.drives.nodes
                for t, s, st in list(n.transitions)
                if t >= since
            ]
        }

    def counters(self, args: dict[str, Any]) -> dict[str, Any]:
        c = self.rig.counters
        # The controller's frames by CiA 301 service (what a second master would add to).
        frames = dict(getattr(self.rig.drives, "host_frames", {}))
        return {"counters": dict(c.__dict__), "injected": len(self.injected), "host_frames": frames}

    # ------------------------------------------------------------------ dispatch
    def handle(self, req: Any) -> dict[str, Any]:
        """Carry out one request; the answer (never raises)."""
        if not isinstance(req, dict):
            return {"ok": False, "error": "request: expected a JSON object"}
        fault, query = req.get("fault"), req.get("query")
        try:
            if (fault is None) == (query is None):
                raise FaultError("fault", "give exactly one of 'fault' or 'query'")
            if query is not None:
                if query not in QUERIES:
                    raise FaultError("query", f"{query!r}: one of {sorted(QUERIES)}")
                return {"ok": True, **getattr(self, query)(req)}
            if fault not in FAULTS:
                raise FaultError("fault", f"{fault!r}: one of {sorted(FAULTS)}")
            t_s = time.monotonic()
            syncs = self.drive_syncs()
            getattr(self, fault)(req)
            self.injected.append((t_s, fault))
            self.rig.counters.faults_injected.append(fault)
            log.warning("fault injected: %s", json.dumps(req))
            return {"ok": True, "fault": fault, "t_s": t_s, "syncs": syncs}
        except FaultError as exc:
            return {"ok": False, "error": str(exc), "field": exc.field}
        except Exception as exc:  # the channel must survive whatever a fault does to the rig
            log.exception("fault request failed")
            return {"ok": False, "error": f"{type(exc).__name__}: {exc}"}

    def close(self) -> None:
        for t in self._timers:
            t.cancel()


FAULTS = frozenset(
    {
        "emcy",
        "heartbeat_stop",
        "heartbeat_start",
        "drive_reboot",
        "bus_off",
        "bus_recover",
        "adapter_unplug",
        "loadcell_disconnect",
        "loadcell_reconnect",
        "loadcell_garbage",
        "tracker_dropout",
        "tracker_resume",
        "tension_spike",
    }
)
QUERIES = frozenset({"drives", "transitions", "counters"})


class _Handler(socketserver.StreamRequestHandler):
    server: _Server

    def handle(self) -> None:
        while True:
            line = self.rfile.readline(MAX_LINE_BYTES + 1)
            if not line:
                return
            if len(line) > MAX_LINE_BYTES:
                answer: dict[str, Any] = {"ok": False, "error": "request: line too long"}
            else:
                try:
                    answer = self.server.injector.handle(json.loads(line))
                except (ValueError, UnicodeDecodeError) as exc:
                    answer = {"ok": False, "error": f"request: not JSON ({exc})"}
            self.wfile.write((json.dumps(answer) + "\n").encode())
            self.wfile.flush()


class _Server(socketserver.ThreadingUnixStreamServer):
    daemon_threads = True
    injector: FaultInjector


class FaultServer:
    """Serves :class:`FaultInjector` for ``rig`` on the Unix socket ``path`` (mode 0600)."""

    def __init__(self, rig: Any, path: str | Path) -> None:
        self.path = Path(path)
        self.injector = FaultInjector(rig)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        old = os.umask(0o177)
        try:
            self._server = _Server(str(self.path), _Handler)
        finally:
            os.umask(old)
        self._server.injector = self.injector
        self._thread = threading.Thread(
            target=self._server.serve_forever, name="sim-faults", daemon=True
        )

    def start(self) -> FaultServer:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        self.injector.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def __enter__(self) -> FaultServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class FaultClient:
    """Talks to a :class:`FaultServer`: ``inject(fault, **args)``, ``query(name, **args)``."""

    def __init__(self, path: str | Path, timeout_s: float = CLIENT_TIMEOUT_S) -> None:
        self.path = str(path)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._sock.settimeout(timeout_s)
        self._sock.connect(self.path)
        self._file = self._sock.makefile("rwb")

    def _call(self, req: dict[str, Any]) -> dict[str, Any]:
        self._file.write((json.dumps(req) + "\n").encode())
        self._file.flush()
        line = self._file.readline()
        if not line:
            raise ConnectionError(f"{self.path}: the simulator closed the fault channel")
        answer = json.loads(line)
        if not answer.get("ok"):
            raise FaultError(answer.get("field", "request"), answer.get("error", "failed"))
        return answer

    def inject(self, fault: str, **args: Any) -> dict[str, Any]:
        """Inject ``fault``; the answer with ``t_s`` (simulator monotonic time) and ``syncs``."""
        return self._call({"fault": fault, **args})

    def query(self, name: str, **args: Any) -> dict[str, Any]:
        return self._call({"query": name, **args})

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._file.close()
        self._sock.close()

    def __enter__(self) -> FaultClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = [
    "EMCY_CODES",
    "FAULTS",
    "QUERIES",
    "SAFE_STATES",
    "FaultClient",
    "FaultError",
    "FaultInjector",
    "FaultServer",
]
