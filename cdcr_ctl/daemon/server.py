"""Unix-domain control socket: one thread per client, JSON lines, peer credentials checked.

The socket file is created with mode ``socket_mode`` (0660 by default) so only the daemon's user and
group can connect; on top of the file mode every connection's peer credentials (SO_PEERCRED) are
checked: root, the daemon's own uid, or a member of the socket's group. There is no TCP listener.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import struct
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cdcr_ctl.daemon.protocol import (
    MAX_LINE_BYTES,
    ProtocolError,
    Request,
    encode_reply,
    parse_request,
)
from cdcr_ctl.errors import CommError, RigError

log = logging.getLogger(__name__)

Handler = Callable[[Request], Any]

#: How long one client may stay silent mid-line before it is dropped (s).
CLIENT_IDLE_TIMEOUT_S = 600.0


def peer_credentials(conn: socket.socket) -> tuple[int, int, int]:
    """(pid, uid, gid) of the process at the other end of a Unix stream socket (Linux)."""
    raw = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    pid, uid, gid = struct.unpack("3i", raw)
    return pid, uid, gid


def peer_allowed(uid: int, gid: int, sock_gid: int, own_uid: int) -> bool:
    """Root, the daemon's own user, or a process in the group that owns the socket.

    Supplementary groups are read from ``/proc/<pid>/status`` by the caller when needed; here the
    primary gid is checked.
    """
    return uid in (0, own_uid) or gid == sock_gid


def _supplementary_groups(pid: int) -> set[int]:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("Groups:"):
                return {int(g) for g in line.split()[1:]}
    except (OSError, ValueError):
        pass
    return set()


class ControlServer:
    """Serve ``handler`` on a Unix socket at ``path``; ``close()`` removes the socket file."""

    def __init__(self, path: str | Path, handler: Handler, mode: int = 0o660) -> None:
        self.path = Path(path)
        self._handler = handler
        self._stop = threading.Event()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(FileNotFoundError):
            # A socket left by a killed daemon: remove it only if nobody answers on it.
            if self.path.is_socket() and not _answers(self.path):
                self.path.unlink()
        if self.path.exists():
            raise CommError(f"{self.path}: exists and is in use (another daemon running?)")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        old = os.umask(0o777 & ~mode)
        try:
            self._sock.bind(str(self.path))
        finally:
            os.umask(old)
        os.chmod(self.path, mode)
        self._sock.listen(8)
        self._sock_gid = self.path.stat().st_gid
        self._own_uid = os.getuid()
        self._thread = threading.Thread(
            target=self._accept_loop, name="control-socket", daemon=True
        )
        self.refused = 0

    def start(self) -> ControlServer:
        self._thread.start()
        return self

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return
            pid, uid, gid = peer_credentials(conn)
            groups = {gid} | _supplementary_groups(pid)
            if not any(peer_allowed(uid, g, self._sock_gid, self._own_uid) for g in groups):
                self.refused += 1
                log.warning(
                    "control socket: refused pid %d uid %d (not in group %d)",
                    pid,
                    uid,
                    self._sock_gid,
                )
                with contextlib.suppress(OSError):
                    conn.sendall(encode_reply(0, error="permission denied"))
                conn.close()
                continue
            threading.Thread(
                target=self._serve, args=(conn,), name=f"client-{pid}", daemon=True
            ).start()

    def _serve(self, conn: socket.socket) -> None:
        conn.settimeout(CLIENT_IDLE_TIMEOUT_S)
        buf = b""
        with conn:
            while not self._stop.is_set():
                try:
                    chunk = conn.recv(65536)
                except (OSError, TimeoutError):
                    return
                if not chunk:
                    return
                buf += chunk
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    if not line.strip():
                        continue
                    if not self._reply(conn, line):
                        return
                if len(buf) > MAX_LINE_BYTES:
                    self._send(conn, encode_reply(0, error=ProtocolError("request line too long")))
                    return

    def _reply(self, conn: socket.socket, line: bytes) -> bool:
        rid = 0
        try:
            req = parse_request(line)
            rid = req.id
            result = self._handler(req)
            reply = encode_reply(rid, result)
        except RigError as exc:
            reply = encode_reply(rid, error=exc)
        except Exception as exc:  # a handler bug must not kill the daemon; report it
            log.exception("control socket handler failed")
            reply = encode_reply(rid, error=f"internal error: {type(exc).__name__}: {exc}")
        return self._send(conn, reply)

    @staticmethod
    def _send(conn: socket.socket, data: bytes) -> bool:
        try:
            conn.sendall(data)
            return True
        except OSError:
            return False

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def _answers(path: Path) -> bool:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(0.5)
    try:
        s.connect(str(path))
        return True
    except OSError:
        return False
    finally:
        s.close()
