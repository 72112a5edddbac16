"""The operator's stop line: a Unix socket of its own, served by a process of its own, that raises
the rig's stop flag whatever the control socket is doing.

The control socket's front process (:mod:`cdcr_ctl.daemon.front`) serves every client with a
thread; hundreds of clients flooding ``status``, 16 MB requests or slow clients share its
interpreter lock, and a ``stop`` sent there waits behind them before the front can raise the flag.
This process shares no lock with them: it only accepts connections on the stop socket
(:func:`~cdcr_ctl.daemon.protocol.stop_socket_path`: ``control-stop.sock`` beside
``control.sock``), reads one short line per connection, and writes the shared-memory
:class:`~cdcr_ctl.control.stopflag.StopFlag` that the rig process's loop reads at the start of
every cycle. Then it forwards the request over a pipe of its
own to the rig process (which times the stop on the bus and updates the daemon's state:
:func:`cdcr_ctl.daemon.recovery.await_stop`) and relays the answer; if none comes within
:data:`STOP_REPLY_TIMEOUT_S` it answers from the flag (the cycle that acted).

- One thread, one :mod:`selectors` loop: a slow client (a line that never ends) holds nothing;
  each connection has :data:`LINE_TIMEOUT_S` to send its line, lines are at most
  :data:`MAX_STOP_LINE_BYTES`, and with :data:`MAX_CONNECTIONS` open the oldest connection without
  a request is dropped for a new one.
- Only ``stop`` is served (``{"id": 1, "cmd": "stop", "args": {"mode": "quick_stop"}}``); the reply
  is the control socket's ``stop`` reply.
- The same access rule as the control socket (file mode, then peer credentials).
- Scheduling: SCHED_FIFO at ``control.realtime_priority`` when that is set (and permitted), else
  nice :data:`STOP_NICE` when permitted.
- The process ends when its parent (the front) is gone, removing its socket file.

:class:`~cdcr_ctl.daemon.client.ControlClient` sends ``stop`` here when the socket exists
(``cdcr-ctl stop`` included), and on the control socket otherwise.
"""

from __future__ import annotations

import contextlib
import logging
import os
import selectors
import signal
import socket
import time
from pathlib import Path
from typing import Any

from cdcr_ctl.control.stopflag import StopFlag
from cdcr_ctl.daemon.outcome import outcome
from cdcr_ctl.daemon.protocol import (
    ProtocolError,
    encode_reply,
    parse_request,
)
from cdcr_ctl.daemon.rigshare import STOP_ACK_TIMEOUT_S, stop_reaction
from cdcr_ctl.daemon.server import (
    _supplementary_groups,
    bind_unix_socket,
    peer_allowed,
    peer_credentials,
)
from cdcr_ctl.errors import RigError

log = logging.getLogger(__name__)

#: Longest stop request line (bytes): a ``stop`` is under 100.
MAX_STOP_LINE_BYTES = 4096
#: How long a connection may take to send its line (s).
LINE_TIMEOUT_S = 2.0
#: Connections open at once; beyond, the oldest one without a request is dropped.
MAX_CONNECTIONS = 64
#: Connections the kernel queues before this process accepts them (all are accepted at once).
LISTEN_BACKLOG = 512
#: Longest wait for the rig process's answer before answering from the flag (s): the loop's
#: acknowledgement wait and the bus tap's (``recovery.BUS_TAP_WAIT_S``), and a second.
STOP_REPLY_TIMEOUT_S = STOP_ACK_TIMEOUT_S + 3.0
#: Nice level of the stop process without a real-time priority (needs CAP_SYS_NICE).
STOP_NICE = -10
#: How often the process checks that its parent is alive (s).
PARENT_CHECK_S = 0.5


class _Conn:
    __slots__ = ("buf", "opened", "sock", "waiting")

    def __init__(self, sock: socket.socket, now: float) -> None:
        self.sock = sock
        self.buf = b""
        self.opened = now
        self.waiting = False  # a stop was read: waiting for its answer


class StopLine:
    """The stop socket's server (see the module); :meth:`serve` runs it in the calling thread."""

    def __init__(
        self, path: str | Path, mode: int, shared: Any, rig_conn: Any, parent_pid: int
    ) -> None:
        self.path = Path(path)
        self.flag = StopFlag(shared)
        self.rig = rig_conn
        self.parent_pid = parent_pid
        self.sel = selectors.DefaultSelector()
        self.conns: dict[int, _Conn] = {}
        #: tag -> (connection, request id, seq, cycle at arrival, mode, deadline)
        self.pending: dict[int, tuple[_Conn, int, int, int, str, float]] = {}
        self._tag = 0
        self.sock = bind_unix_socket(self.path, mode, LISTEN_BACKLOG)
        self.sock.setblocking(False)
        self._sock_gid = self.path.stat().st_gid
        self._own_uid = os.getuid()
        self.sel.register(self.sock, selectors.EVENT_READ, "accept")
        self.sel.register(self.rig, selectors.EVENT_READ, "rig")

    def serve(self) -> None:
        next_check = time.monotonic() + PARENT_CHECK_S
        try:
            while True:
                timeout = self._timeout()
                for key, _ in self.sel.select(timeout):
                    if key.data == "accept":
                        self._accept()
                    elif key.data == "rig":
                        if not self._rig_answer():
                            return
                    else:
                        self._read(key.data)
                now = time.monotonic()
                self._expire(now)
                if now >= next_check:
                    next_check = now + PARENT_CHECK_S
                    if os.getppid() != self.parent_pid:
                        return
        finally:
            self.close()

    def _timeout(self) -> float:
        deadlines = [p[5] for p in self.pending.values()]
        deadlines += [c.opened + LINE_TIMEOUT_S for c in self.conns.values() if not c.waiting]
        if not deadlines:
            return PARENT_CHECK_S
        return max(0.0, min(min(deadlines) - time.monotonic(), PARENT_CHECK_S))

    def _accept(self) -> None:
        """Every connection waiting in the backlog (a burst must not fill it)."""
        while True:
            try:
                sock, _ = self.sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            self._admit(sock)

    def _admit(self, sock: socket.socket) -> None:
        pid, uid, gid = peer_credentials(sock)
        if not any(
            peer_allowed(uid, g, self._sock_gid, self._own_uid)
            for g in {gid} | _supplementary_groups(pid)
        ):
            with contextlib.suppress(OSError):
                sock.sendall(encode_reply(0, error="permission denied"))
            sock.close()
            return
        if len(self.conns) >= MAX_CONNECTIONS:
            idle = [c for c in self.conns.values() if not c.waiting]
            if not idle:
                sock.close()
                return
            self._drop(min(idle, key=lambda c: c.opened))
        sock.setblocking(False)
        conn = _Conn(sock, time.monotonic())
        self.conns[sock.fileno()] = conn
        self.sel.register(sock, selectors.EVENT_READ, conn)

    def _read(self, conn: _Conn) -> None:
        try:
            chunk = conn.sock.recv(MAX_STOP_LINE_BYTES)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            chunk = b""
        if not chunk:
            self._drop(conn)
            return
        if conn.waiting:
            return  # one request per connection; the rest is ignored
        conn.buf += chunk
        nl = conn.buf.find(b"\n")
        if nl < 0:
            if len(conn.buf) > MAX_STOP_LINE_BYTES:
                self._answer(conn, 0, error=ProtocolError("stop line too long"))
            return
        self._request(conn, conn.buf[:nl])

    def _request(self, conn: _Conn, line: bytes) -> None:
        arrived = time.time()
        rid = 0
        try:
            req = parse_request(line)
            rid = req.id
            if req.cmd != "stop":
                raise ProtocolError(f"only stop on the stop socket, not {req.cmd!r}", field="cmd")
        except ProtocolError as exc:
            self._answer(conn, rid, error=exc)
            return
        # The stop itself: the loop reads the flag at the start of its next cycle.
        cycle0 = self.flag.cycle
        seq = self.flag.request(stop_reaction(req.args.mode))
        conn.waiting = True
        self._tag += 1
        extra = {"seq": seq, "cycle": cycle0, "arrived_wall_s": arrived}
        deadline = time.monotonic() + STOP_REPLY_TIMEOUT_S
        self.pending[self._tag] = (conn, rid, seq, cycle0, req.args.mode, deadline)
        try:
            self.rig.send((self._tag, req, extra))
        except (OSError, ValueError) as exc:
            log.warning("stop line: rig process unreachable (%s)", exc)
            self._from_flag(self._tag, f"rig process unreachable: {exc}")

    def _rig_answer(self) -> bool:
        try:
            tag, out = self.rig.recv()
        except (EOFError, OSError):
            # The rig process is gone: every waiting stop is answered from the flag.
            for tag in list(self.pending):
                self._from_flag(tag, "rig process gone")
            return False
        slot = self.pending.pop(tag, None)
        if slot is None:
            return True
        conn, rid = slot[0], slot[1]
        try:
            self._answer(conn, rid, result=outcome(out))
        except RigError as exc:
            self._answer(conn, rid, error=exc)
        return True

    def _from_flag(self, tag: int, note: str) -> None:
        conn, rid, seq, cycle0, mode, _ = self.pending.pop(tag)
        acted = self.flag.acted_cycle(seq)
        result = {
            "stopped": mode,
            "acted_cycle": acted,
            "cycles_waited": None if acted is None else acted - cycle0,
            "bus": None,
            "note": note,
        }
        self._answer(conn, rid, result=result)

    def _expire(self, now: float) -> None:
        for tag, slot in list(self.pending.items()):
            if now > slot[5]:
                self._from_flag(tag, f"rig process did not answer within {STOP_REPLY_TIMEOUT_S} s")
        for conn in list(self.conns.values()):
            if not conn.waiting and now > conn.opened + LINE_TIMEOUT_S:
                self._drop(conn)

    def _answer(self, conn: _Conn, rid: int, result: Any = None, error: Any = None) -> None:
        data = encode_reply(rid, result) if error is None else encode_reply(rid, error=error)
        with contextlib.suppress(OSError):
            # A reply is far below a socket's buffer: never blocks, whatever the client does.
            conn.sock.send(data)
        self._drop(conn)

    def _drop(self, conn: _Conn) -> None:
        fd = conn.sock.fileno()
        if fd >= 0 and self.conns.pop(fd, None) is not None:
            with contextlib.suppress(KeyError, ValueError):
                self.sel.unregister(conn.sock)
        conn.sock.close()

    def close(self) -> None:
        for conn in list(self.conns.values()):
            self._drop(conn)
        with contextlib.suppress(OSError):
            self.sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def stop_main(
    path: str, mode: int, shared: Any, rig_conn: Any, ready_conn: Any, rt_priority: int
) -> None:
    """(the stop process's main) Serve the stop socket until the parent is gone or SIGTERM."""
    signal.signal(signal.SIGTERM, _exit)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the front's Ctrl-C is the front's
    notes = _raise_priority(rt_priority)
    parent = os.getppid()
    try:
        line = StopLine(path, mode, shared, rig_conn, parent)
    except (OSError, RigError) as exc:
        with contextlib.suppress(OSError):
            ready_conn.send(("failed", str(exc)))
        return
    try:
        ready_conn.send(("ready", notes))
        ready_conn.close()
    except OSError:
        line.close()  # the front is gone (killed during its start): leave no socket behind
        return
    with contextlib.suppress(SystemExit, KeyboardInterrupt):
        line.serve()
    line.close()


def _exit(signum: int, frame: object) -> None:
    raise SystemExit(0)


def _raise_priority(rt_priority: int) -> str:
    if rt_priority > 0:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
            return f"SCHED_FIFO {rt_priority}"
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, 0, STOP_NICE)
        return f"nice {STOP_NICE}"
    return "SCHED_OTHER nice 0"


__all__ = [
    "MAX_STOP_LINE_BYTES",
    "STOP_REPLY_TIMEOUT_S",
    "StopLine",
    "stop_main",
]
