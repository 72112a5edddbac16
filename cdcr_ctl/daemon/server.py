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
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cdcr_ctl.daemon.protocol import (
    INLINE_PARSE_BYTES,
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
#: Pending connections the kernel queues before refusing (bursts of clients connect at once).
LISTEN_BACKLOG = 512
#: Clients served at once; one more is told so and closed (each has a thread).
MAX_CLIENTS = 256
#: How long an oversized request is read on (and discarded) to reply with the refusal (s).
DISCARD_TIMEOUT_S = 30.0

#: ``spool(path) -> Request``: parse a big request spooled to ``path`` (in another process).
Spooler = Callable[[Path], Request]


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


def bind_unix_socket(path: Path, mode: int, backlog: int) -> socket.socket:
    """A listening Unix stream socket at ``path`` with file mode ``mode``. A socket file left by
    a killed daemon is removed first, but only if nobody answers on it; CommError if one does."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        if path.is_socket() and not _answers(path):
            path.unlink()
    if path.exists():
        raise CommError(f"{path}: exists and is in use (another daemon running?)")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
    old = os.umask(0o777 & ~mode)
    try:
        sock.bind(str(path))
    finally:
        os.umask(old)
    os.chmod(path, mode)
    sock.listen(backlog)
    return sock


class ControlServer:
    """Serve ``handler`` on a Unix socket at ``path``; ``close()`` removes the socket file."""

    def __init__(
        self,
        path: str | Path,
        handler: Handler,
        mode: int = 0o660,
        spooler: Spooler | None = None,
        spool_dir: str | Path | None = None,
    ) -> None:
        """``spooler``: parse lines above ``INLINE_PARSE_BYTES`` (written to a file in
        ``spool_dir`` while they arrive) elsewhere; None parses every line here."""
        self.path = Path(path)
        self._handler = handler
        self._spooler = spooler
        self._spool_dir = Path(spool_dir) if spool_dir is not None else None
        self._spool_n = 0
        self._clients = 0
        self._clients_lock = threading.Lock()
        self._stop = threading.Event()
        self._sock = bind_unix_socket(self.path, mode, LISTEN_BACKLOG)
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
            with self._clients_lock:
                busy = self._clients >= MAX_CLIENTS
                if not busy:
                    self._clients += 1
            if busy:
                with contextlib.suppress(OSError):
                    conn.sendall(
                        encode_reply(0, error=f"busy: MAX_CLIENTS = {MAX_CLIENTS} connected")
                    )
                conn.close()
                continue
            threading.Thread(
                target=self._serve, args=(conn,), name=f"client-{pid}", daemon=True
            ).start()

    def _serve(self, conn: socket.socket) -> None:
        try:
            self._serve_lines(conn)
        finally:
            with self._clients_lock:
                self._clients -= 1

    def _serve_lines(self, conn: socket.socket) -> None:
        """Read lines; a line is kept in memory up to ``INLINE_PARSE_BYTES``, spooled to a file
        beyond (with a spooler), and read to its end and refused beyond ``MAX_LINE_BYTES``.
        Chunks are collected in a list: no quadratic re-copying of a big line."""
        conn.settimeout(CLIENT_IDLE_TIMEOUT_S)
        parts: list[bytes] = []
        size = 0
        spool: Any = None
        spool_path: Path | None = None
        oversize = False
        with conn:
            try:
                while not self._stop.is_set():
                    try:
                        chunk = conn.recv(65536)
                    except (OSError, TimeoutError):
                        return
                    if not chunk:
                        return
                    while chunk:
                        nl = chunk.find(b"\n")
                        head, chunk = (chunk, b"") if nl < 0 else (chunk[:nl], chunk[nl + 1 :])
                        size += len(head)
                        if oversize or size > MAX_LINE_BYTES:
                            if not oversize:
                                oversize = True
                                conn.settimeout(DISCARD_TIMEOUT_S)
                                parts, spool = [], self._drop_spool(spool, spool_path)
                        elif spool is not None:
                            spool.write(head)
                        else:
                            parts.append(head)
                            if size > INLINE_PARSE_BYTES and self._spooler is not None:
                                spool, spool_path = self._open_spool()
                                spool.write(b"".join(parts))
                                parts = []
                        if nl < 0:
                            break
                        # A whole line.
                        if oversize:
                            ok = self._send(conn, encode_reply(0, error=_too_long(size)))
                        elif spool is not None:
                            spool.close()
                            spool = None
                            ok = self._reply_spooled(conn, spool_path)
                        else:
                            line = b"".join(parts)
                            ok = not line.strip() or self._reply(conn, line)
                        parts, size, oversize = [], 0, False
                        conn.settimeout(CLIENT_IDLE_TIMEOUT_S)
                        if not ok:
                            return
            finally:
                self._drop_spool(spool, spool_path)

    def _open_spool(self) -> tuple[Any, Path]:
        self._spool_n += 1
        base = self._spool_dir or Path(tempfile.gettempdir())
        path = base / f"line{self._spool_n}-{threading.get_ident()}.json"
        return open(path, "xb"), path

    @staticmethod
    def _drop_spool(spool: Any, path: Path | None) -> None:
        if spool is not None:
            with contextlib.suppress(OSError):
                spool.close()
            if path is not None:
                with contextlib.suppress(OSError):
                    path.unlink()
        return None

    def _reply_spooled(self, conn: socket.socket, path: Path | None) -> bool:
        assert path is not None and self._spooler is not None
        try:
            req = self._spooler(path)
        except RigError as exc:
            return self._send(conn, encode_reply(0, error=exc))
        except Exception as exc:
            log.exception("control socket: intake failed")
            return self._send(conn, encode_reply(0, error=f"intake failed: {exc}"))
        finally:
            with contextlib.suppress(OSError):
                path.unlink()
        return self._reply(conn, b"", req)

    def _reply(self, conn: socket.socket, line: bytes, parsed: Request | None = None) -> bool:
        rid = 0
        try:
            req = parsed if parsed is not None else parse_request(line)
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


def _too_long(size: int) -> ProtocolError:
    return ProtocolError(
        f"request line of more than {size} bytes: longer than MAX_LINE_BYTES = {MAX_LINE_BYTES}"
        " (send a big trajectory as a file)"
    )


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
