"""The stop line (``cdcr_ctl/daemon/stopline.py``) in a thread, on a private socket, with a pipe
standing in for the rig process: the flag is raised before anything is forwarded, the rig's answer
is relayed, a silent rig is answered from the flag, and slow, oversized or wrong requests hold
nothing up."""

from __future__ import annotations

import json
import multiprocessing
import os
import socket
import threading
import time

import pytest

from cdcr_ctl.control.stopflag import StopFlag
from cdcr_ctl.control.supervisor import Reaction
from cdcr_ctl.daemon import stopline
from cdcr_ctl.daemon.client import ControlClient, recv_line
from cdcr_ctl.daemon.outcome import encode_outcome
from cdcr_ctl.daemon.protocol import stop_socket_path


@pytest.fixture
def line(tmp_path, monkeypatch):
    """(stop line, the rig's end of its pipe, the flag's store, the control socket path)."""
    monkeypatch.setattr(stopline, "STOP_REPLY_TIMEOUT_S", 0.5)
    monkeypatch.setattr(stopline, "LINE_TIMEOUT_S", 0.3)
    control = tmp_path / "control.sock"
    # A control socket that only listens: the client connects to it first.
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(control))
    listener.listen(4)
    store = [0, 0, 0, -1, 0]
    ours, rig = multiprocessing.Pipe()
    sl = stopline.StopLine(stop_socket_path(control), 0o600, store, ours, os.getppid())
    th = threading.Thread(target=sl.serve, daemon=True)
    th.start()
    yield sl, rig, store, control
    rig.close()  # the stop line ends when the rig process's end closes
    th.join(5)
    listener.close()
    assert not th.is_alive()
    assert not stop_socket_path(control).exists()


def _send(path, data: bytes, timeout_s: float = 5.0) -> dict:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout_s)
        s.connect(str(path))
        s.sendall(data)
        return json.loads(recv_line(s, str(path)))


def test_the_flag_is_raised_then_the_rigs_answer_relayed(line):
    _sl, rig, store, control = line
    flag = StopFlag(store)
    flag.tick(41)
    got: dict = {}

    def rig_side():
        tag, req, extra = rig.recv()
        # The flag was raised before the request was forwarded.
        got.update(requested=flag.requested, reaction=store[StopFlag.REACTION], extra=extra)
        flag.acted(extra["seq"], 42)
        rig.send(
            (tag, encode_outcome(lambda: {"stopped": req.args.mode, "bus": {"x": 1}}, on_bug=repr))
        )

    th = threading.Thread(target=rig_side)
    th.start()
    with ControlClient(control) as c:  # the client finds the stop socket beside control.sock
        reply = c.call("stop")
    th.join(5)
    assert reply == {"stopped": "quick_stop", "bus": {"x": 1}}
    assert got["requested"] == 1 and got["reaction"] == int(Reaction.QUICK_STOP)
    assert got["extra"]["seq"] == 1 and got["extra"]["cycle"] == 41
    assert abs(got["extra"]["arrived_wall_s"] - time.time()) < 5


def test_a_silent_rig_is_answered_from_the_flag(line):
    _sl, rig, store, control = line
    flag = StopFlag(store)
    flag.tick(7)

    def act():
        _tag, _req, extra = rig.recv()  # read, never answered
        flag.acted(extra["seq"], 8)

    th = threading.Thread(target=act)
    th.start()
    reply = _send(
        stop_socket_path(control), b'{"id": 3, "cmd": "stop", "args": {"mode": "halt"}}\n'
    )
    th.join(5)
    assert reply["id"] == 3 and reply["ok"]
    res = reply["result"]
    assert res["stopped"] == "halt" and res["acted_cycle"] == 8 and res["cycles_waited"] == 1
    assert "did not answer" in res["note"]
    assert store[StopFlag.REACTION] == int(Reaction.HALT)


def test_slow_oversized_and_other_requests_hold_nothing_up(line):
    sl, rig, store, control = line
    path = stop_socket_path(control)
    # Slow clients: more than the connections allowed, none ever ending its line.
    slow = []
    for _ in range(stopline.MAX_CONNECTIONS + 5):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.connect(str(path))
        s.send(b'{"cmd": "st')
        slow.append(s)
    wrong = _send(path, b'{"id": 1, "cmd": "status"}\n')["error"]
    assert wrong == "cmd: only stop on the stop socket, not 'status'"
    too_long = _send(path, b"x" * (stopline.MAX_STOP_LINE_BYTES + 10))
    assert "too long" in too_long["error"]
    assert store[StopFlag.REQUESTED] == 0  # none of these raised the flag
    t0 = time.monotonic()
    threading.Thread(
        target=lambda: rig.send((rig.recv()[0], ("ok", {"stopped": "quick_stop"})))
    ).start()
    assert _send(path, b'{"id": 2, "cmd": "stop"}\n')["result"] == {"stopped": "quick_stop"}
    assert time.monotonic() - t0 < 2.0
    assert store[StopFlag.REQUESTED] == 1
    # The slow ones were dropped (the oldest for new ones, the rest after LINE_TIMEOUT_S).
    time.sleep(0.8)
    assert not sl.conns
    for s in slow:
        s.close()
