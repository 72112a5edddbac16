"""Control socket server and client over a real Unix socket in a temp dir."""

from __future__ import annotations

import os
import socket
import stat

import pytest

from cdcr_ctl.daemon.client import ControlClient, DaemonError
from cdcr_ctl.daemon.server import ControlServer, peer_allowed
from cdcr_ctl.errors import CommError, RigError


def handler(req):
    if req.cmd == "status":
        return {"state": "idle", "nan": float("nan")}
    if req.cmd == "home":
        raise RigError("node 2: homing timed out")
    if req.cmd == "enable":
        raise ValueError("bug")
    return {"cmd": req.cmd}


@pytest.fixture
def server(tmp_path):
    srv = ControlServer(tmp_path / "run" / "ctl.sock", handler, mode=0o660).start()
    yield srv
    srv.close()


def test_socket_mode_and_round_trip(server):
    mode = stat.S_IMODE(os.stat(server.path).st_mode)
    assert mode == 0o660
    with ControlClient(server.path) as c:
        assert c.call("status") == {"state": "idle", "nan": None}
        assert c.call("stop", mode="halt") == {"cmd": "stop"}


def test_errors_come_back_as_daemon_errors(server):
    with ControlClient(server.path) as c:
        with pytest.raises(DaemonError, match="homing timed out"):
            c.call("home")
        with pytest.raises(DaemonError, match="internal error: ValueError"):
            c.call("enable")
        with pytest.raises(DaemonError) as info:
            c.call("jog", segment=1, theta_rad="a", phi_rad=0.0)
        assert info.value.field == "args.theta_rad"
        assert c.call("status")["state"] == "idle"  # the connection survives errors


def test_garbage_line_gets_an_error_reply_and_connection_stays(server):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(5)
    s.connect(str(server.path))
    s.sendall(b"\x00\xffnot json\n" + b'{"cmd": "status", "id": 2}\n')
    data = b""
    while data.count(b"\n") < 2:
        data += s.recv(4096)
    first, second = data.split(b"\n")[:2]
    assert b'"ok": false' in first and b"not" in first
    assert b'"id": 2' in second and b'"ok": true' in second
    s.close()


def test_stale_socket_file_is_replaced_but_live_one_is_not(tmp_path):
    path = tmp_path / "ctl.sock"
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(str(path))
    dead.close()  # a socket file with nobody listening, as a SIGKILLed daemon leaves it
    srv = ControlServer(path, handler).start()
    try:
        with pytest.raises(CommError, match="in use"):
            ControlServer(path, handler)
    finally:
        srv.close()
    assert not path.exists()


def test_peer_policy():
    assert peer_allowed(uid=0, gid=5, sock_gid=100, own_uid=1000)
    assert peer_allowed(uid=1000, gid=5, sock_gid=100, own_uid=1000)
    assert peer_allowed(uid=1234, gid=100, sock_gid=100, own_uid=1000)
    assert not peer_allowed(uid=1234, gid=5, sock_gid=100, own_uid=1000)


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to connect as another uid")
def test_peer_without_permission_is_refused():
    # pytest's tmp dirs are 0700; the other user must reach the socket through the directory.
    import shutil
    import tempfile
    from pathlib import Path

    d = Path(tempfile.mkdtemp(prefix="cdcr-sock-"))
    os.chmod(d, 0o755)
    server = ControlServer(d / "ctl.sock", handler, mode=0o660).start()
    os.chmod(server.path, 0o666)  # let the file mode through, so the credential check refuses
    try:
        _connect_as_nobody(server)
    finally:
        server.close()
        shutil.rmtree(d)


def _connect_as_nobody(server):
    # A separate process running as nobody (not fork(): this process has threads).
    import subprocess

    script = (
        "import socket, sys\n"
        "s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)\n"
        "s.settimeout(5)\n"
        f"s.connect({str(server.path)!r})\n"
        "try:\n"
        '    s.sendall(b\'{"cmd": "status"}\\n\')\n'
        "except BrokenPipeError:\n"
        "    pass  # refused: the server may have answered and closed already\n"
        "sys.stdout.buffer.write(s.recv(4096))\n"
    )
    # nobody cannot run this venv's python (it lives under root's home): use the system one.
    python = next((p for p in ("/usr/bin/python3", "/bin/python3") if os.path.exists(p)), None)
    if python is None:
        pytest.skip("no system python3 that another user may run")
    res = subprocess.run(
        [python, "-c", script],
        user=65534,
        group=65534,
        extra_groups=[],
        capture_output=True,
        timeout=30,
    )
    assert b"permission denied" in res.stdout, res.stderr
    assert server.refused == 1
