"""Network joystick: ``struct input_event`` records (64-bit layout, linux/input.h) packed and
parsed byte by byte, split anywhere, garbage and truncated streams named by byte offset, a
property test on random bytes; the reader over TCP against the simulated sender (axis range
from the config, disconnect), the ``tcp://`` config and the simulator's stick scripts."""

from __future__ import annotations

import contextlib
import itertools
import socket
import threading
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from cdcr_ctl.config.tracking import JoystickConfig, parse_tcp_url
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.joystick import (
    ABS_CODES,
    BUTTON_CODES,
    EV_ABS,
    EV_KEY,
    EV_SYN,
    INPUT_EVENT_SIZE,
    SYN_REPORT,
    AxisRange,
    InputEvent,
    InputEventError,
    InputEventParser,
    open_joystick,
    open_tcp_joystick,
    pack_input_event,
)
from cdcr_ctl.sim.joystick import (
    JoystickFrame,
    NetworkJoystickServer,
    ScriptedJoystick,
    load_stick_script,
)

X, Y = ABS_CODES["ABS_X"], ABS_CODES["ABS_Y"]
SOUTH = BUTTON_CODES["BTN_SOUTH"]
WAIT_S = 5.0

# EV_ABS ABS_Y -32768 at t = 12.5 s, written out field by field (little endian):
# tv_sec = 12 (8 bytes), tv_usec = 500000 = 0x0007A120 (8 bytes), type 3, code 1, value -32768.
HAND_RECORD = bytes.fromhex("0c00000000000000" + "20a1070000000000" + "0300" + "0100" + "0080ffff")


def _records(events, t0: float = 100.0) -> bytes:
    return b"".join(pack_input_event(*e, t_s=t0 + 0.001 * i) for i, e in enumerate(events))


STREAM = [(EV_ABS, X, 1000), (EV_ABS, Y, -2000), (EV_SYN, SYN_REPORT, 0), (EV_KEY, SOUTH, 1)]


def test_record_layout_by_hand():
    assert INPUT_EVENT_SIZE == 24
    assert pack_input_event(EV_ABS, Y, -32768, t_s=12.5) == HAND_RECORD
    (ev,) = InputEventParser().feed(HAND_RECORD)
    assert ev == InputEvent(12, 500_000, EV_ABS, Y, -32768)
    assert ev.event == (EV_ABS, Y, -32768)


def test_byte_by_byte_completes_each_record_at_its_last_byte():
    data = _records(STREAM)
    p = InputEventParser()
    got = []
    for i, b in enumerate(data):
        out = p.feed(bytes([b]))
        # A record comes out exactly when its 24th byte arrives, never earlier.
        assert len(out) == (1 if (i + 1) % INPUT_EVENT_SIZE == 0 else 0)
        got += [e.event for e in out]
        assert p.pending == (i + 1) % INPUT_EVENT_SIZE
    assert got == STREAM
    assert p.records == len(STREAM) and p.offset == len(data)
    p.eof()  # ended on a boundary


@pytest.mark.parametrize("cut", [1, 7, 23, 24, 25, 47, 50, 95])
def test_split_anywhere_gives_the_same_events(cut):
    data = _records(STREAM)
    p = InputEventParser()
    got = [e.event for e in p.feed(data[:cut])] + [e.event for e in p.feed(data[cut:])]
    assert got == STREAM


def test_garbage_record_is_named_by_its_byte_offset_and_the_parser_stays_failed():
    good = _records(STREAM[:2])  # bytes 0..47
    bad = bytearray(_records([(EV_ABS, X, 5)]))
    bad[16:18] = (0x1234).to_bytes(2, "little")  # type 0x1234: no such event type
    p = InputEventParser("tcp://127.0.0.1:1")
    # The good records before it come out first; the error is raised by the next call.
    assert [e.event for e in p.feed(good + bytes(bad))] == STREAM[:2]
    with pytest.raises(InputEventError) as info:
        p.check()
    assert info.value.offset == 48
    assert "byte 48" in str(info.value) and "0x1234" in str(info.value)
    assert info.value.port == "tcp://127.0.0.1:1"
    with pytest.raises(InputEventError):  # no resync on an unframed stream
        p.feed(_records(STREAM))


def test_bad_microseconds_and_negative_seconds_are_refused():
    import struct

    usec = struct.pack("<qqHHi", 1, 1_000_000, EV_SYN, 0, 0)
    with pytest.raises(InputEventError, match="tv_usec 1000000"):
        InputEventParser().feed(usec)
    neg = struct.pack("<qqHHi", -5, 0, EV_SYN, 0, 0)
    p = InputEventParser()
    assert len(p.feed(_records([(EV_SYN, 0, 0)]) + neg)) == 1
    with pytest.raises(InputEventError, match=r"byte 24: .*tv_sec -5"):
        p.eof()


def test_stream_ending_inside_a_record_names_where():
    p = InputEventParser()
    p.feed(_records(STREAM[:2]) + b"\x00" * 10)
    with pytest.raises(InputEventError, match="byte 48: stream ended 10 byte"):
        p.eof()


@settings(max_examples=300, deadline=None)
@given(data=st.binary(max_size=400), cuts=st.lists(st.integers(0, 400), max_size=6))
def test_random_bytes_never_crash_and_chunking_does_not_matter(data, cuts):
    """Any bytes in any chunks: the same events, or InputEventError at the same offset."""

    def run(chunks):
        p = InputEventParser()
        events = []
        try:
            for c in chunks:
                events += p.feed(c)
            p.eof()
        except InputEventError as exc:
            return events, exc.offset
        return events, None

    bounds = sorted({0, len(data), *(c for c in cuts if c <= len(data))})
    chunks = [data[a:b] for a, b in itertools.pairwise(bounds)]
    whole, chunked = run([data]), run(chunks)
    assert whole == chunked
    events, offset = whole
    if offset is not None:
        assert 0 <= offset <= len(data) and offset % INPUT_EVENT_SIZE == 0
        assert len(events) <= offset // INPUT_EVENT_SIZE  # only records before the bad one


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 0x1F), st.integers(0, 0xFFFF), st.integers(-(2**31), 2**31 - 1)),
        max_size=20,
    )
)
def test_pack_parse_round_trip(events):
    assert [e.event for e in InputEventParser().feed(_records(events))] == events


# -- config ---------------------------------------------------------------------------------


def test_tcp_url_is_validated():
    assert parse_tcp_url("tcp://127.0.0.1:5555") == ("127.0.0.1", 5555)
    assert parse_tcp_url("tcp://[::1]:5555") == ("::1", 5555)
    assert JoystickConfig(device="tcp://localhost:7").tcp_address == ("localhost", 7)
    assert JoystickConfig(device="/dev/input/event3").tcp_address is None
    for bad, why in [
        ("tcp://127.0.0.1:0", "1..65535"),
        ("tcp://127.0.0.1:70000", "1..65535"),
        ("tcp://127.0.0.1", "host and a port"),
        ("tcp://:5", "host and a port"),
        ("tcp://h:5/path", "no user, path"),
        ("udp://h:5", "tcp://HOST:PORT"),
        ("event3", "absolute path"),
        ("tcp://::1:5", "brackets"),
    ]:
        with pytest.raises(ValidationError, match=why) as info:
            JoystickConfig(device=bad)
        assert info.value.errors()[0]["loc"] == ("device",)
    with pytest.raises(ValidationError, match="above min"):
        JoystickConfig(axis_range={"min": 5, "max": 5})


# -- over TCP -------------------------------------------------------------------------------


def _wait(pred, timeout_s: float = WAIT_S) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


def test_reader_over_tcp_uses_the_configured_axis_range_and_sees_the_disconnect():
    rng = AxisRange(0, 1023)  # a 10-bit stick: only the config can say so over the wire
    frames = [
        JoystickFrame(0.0, 0.5, -1.0),
        JoystickFrame(0.05, 0.5, -1.0, frozenset({"BTN_SOUTH"})),
        JoystickFrame(0.4, 0.5, -1.0, frozenset({"BTN_SOUTH"})),
    ]
    server = NetworkJoystickServer(
        lambda: ScriptedJoystick(frames, axis_range=rng, disconnect_at_end=True)
    ).start()
    cfg = JoystickConfig(device=server.url, axis_range={"min": 0, "max": 1023}, deadband=0.0)
    try:
        with open_joystick(cfg) as stick:
            assert _wait(lambda: "BTN_SOUTH" in stick.latest().buttons)
            s = stick.latest()
            assert s.connected
            assert s.x == pytest.approx(0.5, abs=2 / 1023) and s.y == -1.0
            assert _wait(lambda: stick.failure is not None)
            assert "joystick disconnected" in str(stick.failure)
            assert "closed the connection at byte" in str(stick.failure)
            assert not stick.latest().connected
        assert server.clients == 1
    finally:
        server.stop()


@contextlib.contextmanager
def raw_sender(payload: bytes):
    """A TCP server on loopback that sends ``payload`` to its first client, then hangs up."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)

    def serve():
        conn, _ = srv.accept()
        with conn:
            conn.sendall(payload)
            time.sleep(0.1)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        t.join(2)
        srv.close()


@pytest.mark.parametrize(
    ("payload", "expect"),
    [
        (_records(STREAM[:1]) + b"\x01" * 30, "byte 24: not a struct input_event"),
        (_records(STREAM[:3]) + b"\x00" * 5, "byte 72: stream ended 5 byte"),
    ],
)
def test_reader_fails_naming_the_byte_offset_of_a_bad_stream(payload, expect):
    with raw_sender(payload) as url, open_tcp_joystick(JoystickConfig(device=url)) as stick:
        assert _wait(lambda: stick.failure is not None)
        assert expect in str(stick.failure) and url in str(stick.failure)
        assert stick.stats.events >= 1


def test_nobody_listening_is_a_sensor_error_naming_the_address():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nobody listens there now
    url = f"tcp://127.0.0.1:{port}"
    with pytest.raises(SensorError, match=f"{url}: cannot connect"):
        open_joystick(JoystickConfig(device=url, connect_timeout_s=1.0))


# -- simulator scripts ----------------------------------------------------------------------


def test_stick_script_file(tmp_path):
    p = tmp_path / "stick.yaml"
    p.write_text("- {t_s: 0.0, y: 1.0}\n- {t_s: 1.5, buttons: [BTN_SOUTH]}\n")
    assert load_stick_script(p) == [
        JoystickFrame(0.0, 0.0, 1.0),
        JoystickFrame(1.5, 0.0, 0.0, frozenset({"BTN_SOUTH"})),
    ]
    for text, why in [
        ("[]", "non-empty list"),
        ("- {t_s: 0, z: 1}\n", r"\[0\]: keys"),
        ("- {t_s: 0, x: 2}\n", r"\[0\]: axes"),
        ("- {t_s: 0, buttons: [BTN_NOPE]}\n", "unknown button"),
        ("- {t_s: 1}\n- {t_s: 0}\n", "time order"),
    ]:
        p.write_text(text)
        with pytest.raises(ValueError, match=why):
            load_stick_script(p)


def test_simulated_rig_joystick_plays_the_paper_session_inverted_as_configured(tmp_path):
    import yaml

    from cdcr_ctl.cli.demo import ROOT_CONFIG, make_session
    from cdcr_ctl.sim.rig import network_joystick, stick_script
    from cdcr_ctl.sim.simconfig import load_sim_config

    work = tmp_path / "w"
    work.mkdir()
    _, sim = make_session(ROOT_CONFIG / "sim" / "vertebra-truth.yaml", work, tmp_path)
    doc = yaml.safe_load(sim.read_text())
    doc["joystick"] = {"script": "paper", "scale": 0.5, "disconnect_after_s": 0.3}
    sim.write_text(yaml.safe_dump(doc))
    loaded = load_sim_config(sim)
    js = loaded.rig.sensors.joystick
    assert js.device.startswith("tcp://127.0.0.1:") and js.device != "tcp://127.0.0.1:15512"
    frames = stick_script(loaded)
    assert frames[0] == JoystickFrame(0.0, 1.0, 1.0) and frames[-1].t_s == 0.3
    server = network_joystick(loaded).start()
    try:
        with open_joystick(js) as stick:
            assert _wait(lambda: stick.latest().seq >= 1)
            s = stick.latest()
            # The script's "forward" (+1) is sent as the stick reports it (negative) and the
            # config's invert_y brings it back.
            assert (s.x, s.y) == (1.0, 1.0)
            assert _wait(lambda: stick.failure is not None)  # unplugged at 0.3 s
    finally:
        server.stop()
