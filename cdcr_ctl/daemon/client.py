"""Client side of the control socket, used by the CLI.

``stop`` goes to the daemon's stop socket (:mod:`cdcr_ctl.daemon.stopline`) when there is one
beside the control socket: a line of its own that no other client's load delays. Without it (the
one-process daemon) ``stop`` goes on the control socket like every other command."""

from __future__ import annotations

import itertools
import json
import socket
from pathlib import Path
from typing import Any

from cdcr_ctl.daemon.protocol import ProtocolError, encode_request, stop_socket_path
from cdcr_ctl.errors import CommError, RigError

#: How long the CLI waits for one reply (s); long operations (home) reply when started.
REPLY_TIMEOUT_S = 30.0


def recv_line(sock: socket.socket, name: str) -> bytes:
    """One reply line (without its newline) from a fresh connection ``sock`` (``name`` for the
    error); CommError if the other end closes first."""
    buf = b""
    while b"\n" not in buf:
        chunk = sock.recv(4096)
        if not chunk:
            raise CommError(f"{name}: the daemon closed the connection")
        buf += chunk
    return buf.split(b"\n", 1)[0]


class DaemonError(RigError):
    """The daemon refused or failed a request; ``field`` names the argument at fault, if any."""

    def __init__(self, message: str, field: str = "") -> None:
        self.field = field
        super().__init__(message)


class ControlClient:
    """A connection to the daemon's control socket; ``call(cmd, **args)`` returns the result."""

    def __init__(self, path: str | Path, timeout_s: float = REPLY_TIMEOUT_S) -> None:
        self.path = str(path)
        self._ids = itertools.count(1)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        self._sock.settimeout(timeout_s)
        try:
            self._sock.connect(self.path)
        except OSError as exc:
            self._sock.close()
            raise CommError(
                f"{self.path}: cannot connect to the daemon ({exc.strerror or exc})"
            ) from exc
        self._buf = b""

    def call(self, cmd: str, **args: Any) -> Any:
        rid = next(self._ids)
        try:
            line = encode_request(cmd, {k: v for k, v in args.items() if v is not None}, rid)
        except ProtocolError as exc:
            raise DaemonError(str(exc), exc.field) from exc
        reply = self._stop_line(line) if cmd == "stop" else None
        if reply is None:
            try:
                self._sock.sendall(line)
                reply = self._read_line()
            except (OSError, TimeoutError) as exc:
                raise CommError(f"{self.path}: daemon did not answer {cmd!r} ({exc})") from exc
        obj = json.loads(reply)
        if not obj.get("ok"):
            raise DaemonError(obj.get("error", "unknown error"), obj.get("field", ""))
        return obj.get("result")

    def _stop_line(self, line: bytes) -> bytes | None:
        """``line`` sent on the stop socket and its reply; None when there is no stop socket
        (or it refused the connection): the caller sends on the control socket."""
        path = stop_socket_path(self.path)
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        s.settimeout(self._sock.gettimeout())
        try:
            try:
                s.connect(str(path))
            except OSError:
                return None
            try:
                s.sendall(line)
                return recv_line(s, str(path))
            except (OSError, TimeoutError) as exc:
                raise CommError(f"{path}: daemon did not answer 'stop' ({exc})") from exc
        finally:
            s.close()

    def _read_line(self) -> bytes:
        while b"\n" not in self._buf:
            chunk = self._sock.recv(65536)
            if not chunk:
                raise CommError(f"{self.path}: daemon closed the connection")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        return line

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
