"""Modbus RTU reader: the register-read reply decoded with one ``struct``
(``loadcell_reply.decode_read_reply``, and ``exact_read_reply`` before the scanner) and the
words-to-integer conversion (``registers_to_int``) give what pymodbus's own framer, decoder and
``convert_from_registers`` give, for every frame a poll can see: good replies, flipped bits anywhere
(CRC or body), both function codes, int16 and int32 words. pymodbus is the reference here on
purpose: the reader used it for these frames before and must answer the same."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from pymodbus.client.mixin import ModbusClientMixin
from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU

from cdcr_ctl.sensors import loadcell_modbus
from cdcr_ctl.sensors.loadcell_modbus import _decode_exact, registers_to_int, scan_reply
from cdcr_ctl.sensors.loadcell_reply import decode_read_reply, exact_read_reply


def _frame(slave: int, fc: int, registers: list[int]) -> bytes:
    body = bytes([slave, fc, 2 * len(registers)])
    body += b"".join(r.to_bytes(2, "big") for r in registers)
    return body + FramerRTU.compute_CRC(body).to_bytes(2, "big")


def _pymodbus(frame: bytes, slave: int):
    return _decode_exact(FramerRTU(DecodePDU(is_server=False)), frame, slave)


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return (type(a), a.dev_id, list(a.registers), a.function_code) == (
        type(b),
        b.dev_id,
        list(b.registers),
        b.function_code,
    )


@settings(max_examples=400, deadline=None)
@given(
    st.integers(1, 247),
    st.sampled_from([3, 4]),
    st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=8),
    st.one_of(st.none(), st.tuples(st.integers(0, 200), st.integers(0, 7))),
)
def test_read_reply_decodes_as_pymodbus_does(slave, fc, registers, flip):
    frame = bytearray(_frame(slave, fc, registers))
    if flip is not None:  # one bit flipped past the header scan_reply checks: CRC or body
        pos = 3 + flip[0] % (len(frame) - 3)
        frame[pos] ^= 1 << flip[1]
    frame = bytes(frame)
    fast = decode_read_reply(frame, slave)
    assert _same(fast, _pymodbus(frame, slave))
    assert (fast is None) == (flip is not None)  # CRC-16 catches every single-bit error
    # and through the scanner the reader calls (which takes the fast path for these frames)
    scan = scan_reply(frame, slave, fc, len(frame))
    assert _same(scan.pdu, fast)
    # and the reader's check before the scanner: the scanner's answer, or None to ask it
    exact = exact_read_reply(bytearray(frame), slave, fc, len(frame))
    assert _same(exact, scan.pdu)
    assert exact_read_reply(bytearray(frame), slave, fc, len(frame) + 2) is None
    assert exact_read_reply(bytearray(frame), slave ^ 1, fc, len(frame)) is None


def test_the_scanner_decodes_register_replies_on_the_fast_path(monkeypatch):
    calls = []

    def fast(frame, slave):
        calls.append(frame)
        return decode_read_reply(frame, slave)

    monkeypatch.setattr(loadcell_modbus, "decode_read_reply", fast)
    frame = _frame(1, 3, [0, 4876, 2])
    scan = scan_reply(b"\x00\x17" + frame, 1, 3, len(frame))
    assert calls == [frame] and list(scan.pdu.registers) == [0, 4876, 2]
    assert scan.start == 2 and scan.end == 2 + len(frame)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=2))
def test_registers_to_int_is_pymodbus_convert(words):
    kind = "int16" if len(words) == 1 else "int32"
    dt = ModbusClientMixin.DATATYPE.INT16 if kind == "int16" else ModbusClientMixin.DATATYPE.INT32
    ref = ModbusClientMixin.convert_from_registers(list(words), dt, word_order="big")
    assert registers_to_int(words, kind) == ref


def test_registers_to_int_limits_and_wrong_length():
    assert registers_to_int([0x7FFF], "int16") == 2**15 - 1
    assert registers_to_int([0x8000], "int16") == -(2**15)
    assert registers_to_int([0x7FFF, 0xFFFF], "int32") == 2**31 - 1
    assert registers_to_int([0x8000, 0x0000], "int32") == -(2**31)
    try:
        registers_to_int([1], "int32")
    except ValueError as exc:
        assert "int32 needs 2 registers" in str(exc)
    else:
        raise AssertionError("one word accepted as an int32")
