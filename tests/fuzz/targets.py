"""Fuzz targets shared by the CI sample (``tests/fuzz/test_fuzz.py``) and the benchmark
(``benchmarks/fuzz.py``): for every parser of outside input, a hypothesis strategy of inputs
(random bytes/text and mutations of a valid seed, so the fuzzer gets past the first checks) and a
function that feeds one input and returns normally or raises one of the parser's documented
errors. Anything else raised is a bug; so is an input that takes more CPU time than
:data:`HANG_S`.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hypothesis import strategies as st

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.protocol import COMMANDS, ProtocolError, encode_request, parse_request
from cdcr_ctl.drives.emcy import decode_emcy, encode_emcy
from cdcr_ctl.errors import RigError
from cdcr_ctl.sensors import attitude, joystick, loadcell_ascii, natnet
from cdcr_ctl.sensors import loadcell_modbus as mb
from cdcr_ctl.sensors.tracker import format_stream_line, parse_stream_line
from cdcr_ctl.sim.slcan_device import decode_frame

ROOT = Path(__file__).resolve().parents[2]
#: An input that takes longer than this is reported as a hang (s).
HANG_S = 1.0

#: Errors every target may raise for bad input: the project's own tree (ConfigError,
#: SensorError, ProtocolError, ... all derive from RigError) and each parser's documented one.
EXPECTED: tuple[type[BaseException], ...] = (RigError, natnet.NatNetDecodeError)


def mutated(seed: bytes, max_edits: int = 6) -> st.SearchStrategy[bytes]:
    """``seed`` with a few random edits: flip a byte, insert, delete, truncate, duplicate."""

    @st.composite
    def build(draw: st.DrawFn) -> bytes:
        b = bytearray(seed)
        for _ in range(draw(st.integers(1, max_edits))):
            op = draw(st.sampled_from(["flip", "set", "insert", "delete", "truncate", "dup"]))
            i = draw(st.integers(0, max(0, len(b) - 1)))
            if op == "flip" and b:
                b[i] ^= 1 << draw(st.integers(0, 7))
            elif op == "set" and b:
                b[i] = draw(st.integers(0, 255))
            elif op == "insert":
                b[i:i] = draw(st.binary(min_size=1, max_size=8))
            elif op == "delete" and b:
                del b[i : i + draw(st.integers(1, 8))]
            elif op == "truncate":
                del b[i:]
            elif op == "dup" and b:
                j = draw(st.integers(i, len(b)))
                b[j:j] = b[i:j]
        return bytes(b)

    return build()


def inputs(seeds: list[bytes], max_size: int = 256) -> st.SearchStrategy[bytes]:
    return st.one_of(
        st.binary(max_size=max_size), *(mutated(s) for s in seeds), st.sampled_from(seeds)
    )


# ---------------------------------------------------------------- config loader
_WORK = Path(tempfile.mkdtemp(prefix="cdcr-fuzz-"))
_RIG_SEED = (ROOT / "config" / "qi2023.yaml").read_bytes()
_SIM_SEED = (ROOT / "config" / "qi2023-sim.yaml").read_bytes()
(_WORK / "qi2023.yaml").write_bytes(_RIG_SEED)


def _yaml_lines_mutated() -> st.SearchStrategy[bytes]:
    """Line-level edits of the real configs: drop, repeat or swap lines, replace a value."""
    values = st.sampled_from(
        [b"", b"-1", b"0", b"1e400", b".nan", b"null", b"[]", b"{}", b"yes", b"'x'", b"[1, 2, 3]"]
    )

    @st.composite
    def build(draw: st.DrawFn) -> bytes:
        lines = draw(st.sampled_from([_RIG_SEED, _SIM_SEED])).split(b"\n")
        for _ in range(draw(st.integers(1, 4))):
            i = draw(st.integers(0, len(lines) - 1))
            op = draw(st.sampled_from(["drop", "repeat", "value", "indent"]))
            if op == "drop":
                del lines[i]
            elif op == "repeat":
                lines.insert(i, lines[i])
            elif op == "value" and b":" in lines[i]:
                key, _, _ = lines[i].partition(b":")
                lines[i] = key + b": " + draw(values)
            elif op == "indent":
                lines[i] = b"  " + lines[i]
            if not lines:
                break
        return b"\n".join(lines)

    return build()


def config_input() -> st.SearchStrategy[bytes]:
    return st.one_of(
        _yaml_lines_mutated(),
        mutated(_RIG_SEED, 4),
        st.binary(max_size=200),
        st.recursive(
            st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=10),
            lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=8), c, max_size=4),
            max_leaves=20,
        ).map(lambda v: json.dumps(v, allow_nan=True).encode()),
    )


def run_config(data: bytes) -> None:
    path = _WORK / "rig.yaml"
    path.write_bytes(data)
    load_rig_config(path)


# ---------------------------------------------------------------- trajectory loader
_TRAJ = tj.go_and_return(theta_max_rad=0.8, rate_rad_s=0.4, phi_rad=0.3)
_CSV_SEED = _TRAJ.to_csv_text().encode()[:600]
_YAML_SEED = (
    b"name: demo\nn_segments: 1\nsamples:\n  - t_s: 0.0\n    segments: [[0.0, 0.0]]\n"
    b"  - {t_s: 2.0, segments: [[0.5, 1.0]]}\n  - {t_s: 4.0, segments: [[0.0, 1.0]]}\n"
)


def trajectory_input() -> st.SearchStrategy[tuple[str, bytes]]:
    return st.one_of(
        st.tuples(st.just(".csv"), inputs([_CSV_SEED], 300)),
        st.tuples(st.just(".yaml"), inputs([_YAML_SEED], 300)),
    )


def run_trajectory(case: tuple[str, bytes]) -> None:
    suffix, data = case
    path = _WORK / f"traj{suffix}"
    path.write_bytes(data)
    tj.load_trajectory(path, n_segments=1, bend_limit_rad=1.75, max_rate_rad_s=2.0)


# ---------------------------------------------------------------- control-socket protocol
_PROTO_SEEDS = [
    encode_request("status"),
    encode_request("jog", {"cable": 1, "delta_mm": 0.5}),
    encode_request("jog", {"segment": 1, "theta_rad": 0.3, "phi_rad": 0.0, "speed": 0.2}),
    encode_request("trajectory", {"name": "t", "samples": [[0.0, 0.0, 0.0], [1.0, 0.2, 0.0]]}),
    encode_request("stop", {"mode": "quick_stop"}),
    encode_request("reset_fault", {"confirm": True}),
    encode_request("compensation", {"mode": "model"}),
]


def protocol_input() -> st.SearchStrategy[bytes]:
    json_values = st.recursive(
        st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=12),
        lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4),
        max_leaves=25,
    )
    structured = st.fixed_dictionaries(
        {"cmd": st.sampled_from(sorted(COMMANDS)) | st.text(max_size=8)},
        optional={"id": json_values, "args": json_values},
    ).map(lambda d: json.dumps(d, allow_nan=True).encode())
    return st.one_of(inputs(_PROTO_SEEDS, 200), structured)


def run_protocol(data: bytes) -> None:
    try:
        parse_request(data)
    except ProtocolError as exc:
        str(exc)  # the message must format


# ---------------------------------------------------------------- load cells
_MAP = mb.ModbusRegisterMap(value_register=0, value_type="int32", decimals_register=2, unit="kg")
_PLAN = mb.plan_read(_MAP)


def _modbus_seeds() -> list[bytes]:
    from pymodbus.pdu.register_message import ReadHoldingRegistersResponse

    framer = mb._framer()
    seeds = []
    for slave, regs in ((1, [0, 4876, 3]), (2, [0xFFFF, 0xFFF0, 2]), (3, [0, 0, 0])):
        pdu = ReadHoldingRegistersResponse(registers=regs, dev_id=slave)
        seeds.append(framer.buildFrame(pdu))
    return seeds


_MODBUS_SEEDS = _modbus_seeds()


def modbus_input() -> st.SearchStrategy[tuple[bytes, int]]:
    return st.tuples(
        st.one_of(inputs(_MODBUS_SEEDS, 64), st.lists(inputs(_MODBUS_SEEDS, 16)).map(b"".join)),
        st.integers(1, 3),
    )


def run_modbus(case: tuple[bytes, int]) -> None:
    buf, slave = case
    scan = mb.scan_reply(buf, slave, _PLAN.function_code, _PLAN.reply_bytes)
    regs = getattr(scan.pdu, "registers", None)
    if regs and len(regs) >= 2:
        raw = mb.registers_to_int(regs[:2], "int32")
        dec = regs[2] if len(regs) > 2 else 0
        if 0 <= dec <= 6:
            mb.decode_reading(raw, dec, _MAP)


_ASCII_SEEDS = [
    b"ST,GS,+  4.876kg\r\n",
    b"US,NT,-  0.012kg\r\nOL,GS,+ 99.999kg\r\n",
    b"ST,GS,+  1.000N\r\n",
]


def run_ascii(data: bytes) -> None:
    parser = loadcell_ascii.AsciiLineParser()
    mid = len(data) // 2
    parser.feed(data[:mid])
    parser.feed(data[mid:])
    for line in data.split(b"\n"):
        loadcell_ascii.parse_line(line + b"\n")


# ---------------------------------------------------------------- tracker: NatNet, line stream
def _natnet_seeds() -> list[bytes]:
    body = natnet.RigidBodyPose(1, (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0), 0.5, True)
    frame = natnet.FrameOfData(frame_number=7, rigid_bodies=(body,), timestamp_s=2.5)
    return [natnet.pack_frame_of_data(frame, v) for v in (natnet.DEFAULT_VERSION,)]


_NATNET_SEEDS = _natnet_seeds()


def natnet_input() -> st.SearchStrategy[bytes]:
    return inputs(_NATNET_SEEDS, 300)


def run_natnet(data: bytes) -> None:
    msg_id, payload = natnet.split_message(data)
    if msg_id == natnet.MessageId.NAT_FRAMEOFDATA:
        natnet.parse_frame_of_data(payload, natnet.DEFAULT_VERSION)
    else:
        natnet.parse_frame_of_data(payload, natnet.NatNetVersion(3, 0, 0, 0))
        natnet.parse_server_info(payload)


_STREAM_SEEDS = [
    format_stream_line(1.25, (1.0, 2.0, 3.0)),
    format_stream_line(2.5, (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0)),
]


def run_stream(data: bytes) -> None:
    for line in data.split(b"\n"):
        parse_stream_line(line)


# ---------------------------------------------------------------- attitude, EMCY, slcan
_WIT_SEEDS = [
    attitude.pack_angle(10.0, -5.0, 90.0) + attitude.pack_acceleration([0.0, 0.0, 1.0]),
    attitude.pack_quaternion([1.0, 0.0, 0.0, 0.0]),
]


def run_attitude(data: bytes) -> None:
    dec = attitude.WitMotionDecoder()
    for packet in dec.feed(data[:5]) + dec.feed(data[5:]):
        assert packet is not None
    if len(data) == 11:
        attitude.decode_frame(data)


_EMCY_SEEDS = [encode_emcy(0x8611), encode_emcy(0x2310), encode_emcy(0x0000), b"\x30\x81\x11"]


def run_emcy(data: bytes) -> None:
    for family in ("epos4", "epos2"):
        e = decode_emcy(3, data, family)
        if e is not None:
            str(e)


_SLCAN_SEEDS = [b"t20140000000a", b"t0800", b"T0000070180112233", b"r1230", b"S8", b"O", b"C"]


def run_slcan(data: bytes) -> None:
    decode_frame(data.decode("latin-1"))


# ---------------------------------------------------------------- network joystick
_JOYSTICK_SEEDS = [
    joystick.pack_input_event(joystick.EV_ABS, 0, 120, 1.5)
    + joystick.pack_input_event(joystick.EV_KEY, 304, 1, 1.5)
    + joystick.pack_input_event(joystick.EV_SYN, joystick.SYN_REPORT, 0, 1.5)
]


def run_joystick_events(data: bytes) -> None:
    """The TCP joystick's record stream, split in three reads, then its end."""
    parser = joystick.InputEventParser("fuzz")
    third = max(1, len(data) // 3)
    for part in (data[:third], data[third : 2 * third], data[2 * third :]):
        for ev in parser.feed(part):
            assert 0 <= ev.usec <= 999_999 and ev.type <= joystick.EV_MAX
    parser.eof()


@dataclass(frozen=True)
class Target:
    name: str
    strategy: Callable[[], st.SearchStrategy[Any]]
    run: Callable[[Any], None]
    #: Extra errors this target documents for bad input (besides :data:`EXPECTED`).
    expected: tuple[type[BaseException], ...] = ()


TARGETS = [
    Target("config_loader", config_input, run_config),
    Target("trajectory_loader", trajectory_input, run_trajectory),
    Target("control_protocol", protocol_input, run_protocol),
    Target("modbus_loadcell", modbus_input, run_modbus),
    Target("ascii_loadcell", lambda: inputs(_ASCII_SEEDS), run_ascii),
    Target("natnet", natnet_input, run_natnet),
    Target("tracker_line_stream", lambda: inputs(_STREAM_SEEDS), run_stream),
    Target("attitude_witmotion", lambda: inputs(_WIT_SEEDS), run_attitude),
    Target("emcy_decode", lambda: inputs(_EMCY_SEEDS, 16), run_emcy),
    Target("slcan_adapter", lambda: inputs(_SLCAN_SEEDS, 40), run_slcan),
    Target("joystick_input_events", lambda: inputs(_JOYSTICK_SEEDS, 120), run_joystick_events),
]


def check(target: Target, value: Any) -> None:
    """Feed one input; documented errors are fine, anything else propagates."""
    try:
        target.run(value)
    except EXPECTED + target.expected:
        pass
