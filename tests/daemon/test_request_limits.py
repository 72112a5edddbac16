"""Bounded requests (issue #21): every refusal names its limit, on the daemon's side and before
sending on the client's; an oversized line is read to its end and answered, not cut off; big
lines are parsed by the spooler (the intake process), not in the server's process."""

from __future__ import annotations

import json
import socket

import pytest
from test_server import handler

from cdcr_ctl.daemon import protocol
from cdcr_ctl.daemon.client import ControlClient, DaemonError
from cdcr_ctl.daemon.protocol import (
    INLINE_PARSE_BYTES,
    MAX_ID_DIGITS,
    ProtocolError,
    check_jog_speed,
    jog_speed_bounds,
    parse_request,
)
from cdcr_ctl.daemon.server import ControlServer


def test_a_5000_digit_id_is_refused_naming_the_limit():
    with pytest.raises(ProtocolError) as info:
        parse_request('{"cmd": "status", "id": ' + "9" * 5000 + "}")
    assert f"at most {MAX_ID_DIGITS} digits" in str(info.value)


@pytest.mark.parametrize("speed", [1e-300, 1e-4, 11.0])
def test_jog_speed_outside_the_config_bounds_names_the_limit(speed):
    with pytest.raises(ProtocolError) as info:
        check_jog_speed(speed, bend_rad=1.75)
    assert info.value.field == "args.speed" and "limits.bend_rad" in str(info.value)


def test_the_slowest_jog_has_a_bounded_number_of_samples():
    lo, _ = jog_speed_bounds(1.75)
    # The longest move (2 bend_rad in bending vectors) at the slowest speed, in samples:
    samples = (3.1416 * 2 * 1.75 / (2 * lo)) / protocol.JOG_DT_S
    assert samples <= protocol.MAX_JOG_DURATION_S / protocol.JOG_DT_S * 1.001


def test_client_refuses_an_oversized_request_before_sending(monkeypatch, tmp_path):
    monkeypatch.setattr(protocol, "MAX_LINE_BYTES", 1000)
    srv = ControlServer(tmp_path / "ctl.sock", handler).start()
    try:
        with ControlClient(srv.path) as c, pytest.raises(DaemonError) as info:
            c.call("trajectory", name="t", samples=[[float(i), 0.1, 0.0] for i in range(200)])
        assert "MAX_LINE_BYTES" in str(info.value)
    finally:
        srv.close()


def test_oversized_line_is_answered_with_the_limit(monkeypatch, tmp_path):
    from cdcr_ctl.daemon import server as server_mod

    monkeypatch.setattr(server_mod, "MAX_LINE_BYTES", 100_000)
    srv = ControlServer(tmp_path / "ctl.sock", handler).start()
    try:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(30)
        s.connect(str(srv.path))
        s.sendall(b'{"cmd": "status", "pad": "' + b"x" * 300_000 + b'"}\n')
        reply = json.loads(s.makefile("rb").readline())
        assert not reply["ok"] and "MAX_LINE_BYTES = 100000" in reply["error"]
        # The connection still serves the next request.
        s.sendall(b'{"cmd": "status", "id": 2}\n')
        assert json.loads(s.makefile("rb").readline())["id"] == 2
        s.close()
    finally:
        srv.close()


def test_big_lines_go_to_the_spooler(tmp_path):
    seen: list[int] = []

    def spooler(path):
        data = path.read_bytes()
        seen.append(len(data))
        return parse_request(data)

    srv = ControlServer(tmp_path / "ctl.sock", handler, spooler=spooler, spool_dir=tmp_path).start()
    try:
        rows = [[0.01 * i, 0.1, 0.0] for i in range(INLINE_PARSE_BYTES // 10)]
        with ControlClient(srv.path) as c:
            assert c.call("trajectory", name="t", samples=rows) == {"cmd": "trajectory"}
            assert c.call("status")["state"] == "idle"  # small: parsed in place
        assert len(seen) == 1 and seen[0] > INLINE_PARSE_BYTES
        assert not list(tmp_path.glob("line*.json"))  # the spool is removed after parsing
    finally:
        srv.close()


@pytest.mark.parametrize(
    ("args", "field", "says"),
    [
        (dict(segment=3, theta_rad=0.1, phi_rad=0.0), "args.segment", "segment 3 outside [1, 2]"),
        (dict(segment=1, theta_rad=2.0, phi_rad=0), "args.theta_rad", "2 rad outside [0, 1.75]"),
        ({"cable": 7, "delta_mm": 1.0}, "args.cable", "cable 7 outside [1, 6]"),
        ({"cable": 1, "delta_mm": 40.0}, "args.delta_mm", "40 mm outside [-30, 30] mm"),
    ],
)  # fmt: skip
def test_jog_refusals_state_the_allowed_range_and_unit(args, field, says):
    """Refused on the request's own limits, before the rig's state is looked at."""
    from types import SimpleNamespace

    from cdcr_ctl.daemon.commands_run import RunCommands

    limits = SimpleNamespace(bend_rad=1.75, cable_displacement_mm=(-10.0, 20.0))
    daemon = SimpleNamespace(
        model=SimpleNamespace(n_segments=2, n_cables=6), cfg=SimpleNamespace(limits=limits)
    )
    with pytest.raises(ProtocolError) as info:
        RunCommands._cmd_jog(daemon, protocol.COMMANDS["jog"](**args))  # type: ignore[arg-type]
    assert info.value.field == field and says in str(info.value), str(info.value)
