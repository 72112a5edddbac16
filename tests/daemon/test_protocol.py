"""Control-socket protocol: requests are validated field by field; replies are JSON lines."""

from __future__ import annotations

import contextlib
import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.daemon.protocol import (
    COMMANDS,
    MAX_LINE_BYTES,
    ProtocolError,
    encode_reply,
    encode_request,
    parse_request,
)


def test_valid_jog_request_round_trips():
    line = encode_request("jog", {"segment": 1, "theta_rad": 0.5, "phi_rad": 1.0}, rid=7)
    req = parse_request(line)
    assert (req.id, req.cmd, req.args.segment, req.args.theta_rad) == (7, "jog", 1, 0.5)


@pytest.mark.parametrize(
    "obj,field",
    [
        ({"cmd": "jog", "args": {"segment": 1, "theta_rad": "x", "phi_rad": 0}}, "args.theta_rad"),
        ({"cmd": "jog", "args": {"segment": 0, "theta_rad": 0.1, "phi_rad": 0}}, "args.segment"),
        ({"cmd": "jog", "args": {"cable": 1}}, "args"),
        ({"cmd": "jog", "args": {"segment": 1, "theta_rad": 0.1, "phi_rad": 0, "x": 1}}, "args.x"),
        ({"cmd": "fly"}, "cmd"),
        ({"cmd": 3}, "cmd"),
        ({"cmd": "status", "id": "a"}, "id"),
        ({"cmd": "status", "args": []}, "args"),
        ({"cmd": "status", "extra": 1}, "extra"),
        ({"cmd": "stop", "args": {"mode": "brake"}}, "args.mode"),
        ({"cmd": "trajectory", "args": {"name": "t", "samples": [[0.0, 1.0]]}}, "args.samples[0]"),
        ({"cmd": "jog", "args": {"segment": True, "theta_rad": 0.1, "phi_rad": 0}}, "args.segment"),
    ],
)
def test_invalid_requests_name_the_field(obj, field):
    with pytest.raises(ProtocolError) as info:
        parse_request(json.dumps(obj))
    assert info.value.field == field


def test_nan_in_trajectory_is_refused_with_its_position():
    line = '{"cmd": "trajectory", "args": {"name": "t", "samples": [[0, 0.1, 0], [1, NaN, 0]]}}'
    with pytest.raises(ProtocolError) as info:
        parse_request(line)
    assert info.value.field == "args.samples[1][1]"


def test_oversized_and_non_utf8_lines_are_refused():
    with pytest.raises(ProtocolError, match="longer"):
        parse_request(b"x" * (MAX_LINE_BYTES + 1))
    with pytest.raises(ProtocolError, match="byte 9"):
        parse_request(b'{"cmd": "\xff"}')


def test_reply_encoding_replaces_nan_and_carries_field():
    ok = json.loads(encode_reply(3, {"a": float("nan"), "b": [1.0, float("inf")]}))
    assert ok == {"id": 3, "ok": True, "result": {"a": None, "b": [1.0, None]}}
    err = json.loads(encode_reply(4, error=ProtocolError("bad", field="args.x")))
    assert err == {"id": 4, "ok": False, "error": "args.x: bad", "field": "args.x"}


@pytest.mark.parametrize(
    "name",
    [
        "status",
        "enable",
        "disable",
        "home",
        "stop",
        "log_start",
        "log_stop",
        "reset_fault",
        "shutdown",
    ],
)
def test_commands_without_required_args_parse_bare(name):
    assert name in COMMANDS
    assert parse_request(json.dumps({"cmd": name})).cmd == name


@pytest.mark.parametrize("name", ["jog", "trajectory", "compensation"])
def test_commands_with_required_args_refuse_bare(name):
    with pytest.raises(ProtocolError) as info:
        parse_request(json.dumps({"cmd": name}))
    assert info.value.field.startswith("args")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_never_crash_the_parser(data):
    with contextlib.suppress(ProtocolError):
        parse_request(data)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=20,
)


@settings(max_examples=300, deadline=None)
@given(
    cmd=st.sampled_from([*COMMANDS, "bogus"]),
    args=st.dictionaries(
        st.sampled_from(
            ["segment", "theta_rad", "phi_rad", "cable", "delta_mm", "name", "samples", "mode"]
        ),
        json_values,
        max_size=5,
    ),
)
def test_random_structured_requests_are_accepted_or_refused_cleanly(cmd, args):
    try:
        line = json.dumps({"cmd": cmd, "args": args})
    except ValueError:
        return
    try:
        parse_request(line)
    except ProtocolError as exc:
        assert str(exc)
