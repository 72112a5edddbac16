"""Client side of the control socket, used by the CLI."""

from __future__ import annotations

import itertools
import json
import socket
from pathlib import Path
from typing import Any

from cdcr_ctl.daemon.protocol import ProtocolError, encode_request
from cdcr_ctl.errors import CommError, RigError

#: How long the CLI waits for one reply (s); long operations (home) reply when started.
REPLY_TIMEOUT_S = 30.0


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
        try:
            self._sock.sendall(line)
            reply = self._read_line()
        except (OSError, TimeoutError) as exc:
            raise CommError(f"{self.path}: daemon did not answer {cmd!r} ({exc})") from exc
        obj = json.loads(reply)
        if not obj.get("ok"):
            raise DaemonError(obj.get("error", "unknown error"), obj.get("field", ""))
        return obj.get("result")

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
