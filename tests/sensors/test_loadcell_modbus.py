"""Modbus RTU load-cell reader: frames byte by byte, recorded transcripts with faults on a pty,
the simulated transmitters, and a stock pymodbus client reading the simulator.

The recorded frames below are literal bytes; their CRCs are checked against a reference CRC-16
written here from the spec's definition (poly 0xA001 reflected, init 0xFFFF, low byte first) and
verified against the CRC catalogue check value, so the tests do not trust pymodbus to check
pymodbus.
"""

from __future__ import annotations

import math
import threading
import time

import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from modbus_ref import ref_crc16_modbus
from pymodbus.pdu import ExceptionResponse

from cdcr_ctl.config.loadcells import ModbusRegisterMap
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.loadcell import G_M_PER_S2
from cdcr_ctl.sensors.loadcell_modbus import (
    SPEC_T35_FIXED_S,
    ModbusLoadCellBus,
    ReadPlan,
    build_read_request,
    build_write_request,
    char_time_s,
    decode_reading,
    plan_read,
    registers_to_int,
    scan_reply,
    spec_silence_s,
    transaction_chars,
)
from cdcr_ctl.sensors.loadcell_sampler import LoadCellSampler
from cdcr_ctl.sim.loadcells import ModbusLoadCellSim, SensorNoise

H = bytes.fromhex
MAP = ModbusRegisterMap()  # int32 value at 0, decimals at 2, kg: one 3-register read
KG = G_M_PER_S2


def test_reference_crc_matches_catalogue_and_recorded_frames():
    # CRC RevEng catalogue: CRC-16/MODBUS check("123456789") = 0x4B37.
    assert ref_crc16_modbus(b"123456789") == bytes([0x37, 0x4B])
    for frame in [REQ1, REQ2, REQ3, RESP1, RESP2, RESP3, EXC1, H("01 03 00 00 00 02 c4 0b")]:
        assert ref_crc16_modbus(frame[:-2]) == frame[-2:], frame.hex(" ")


# Recorded transcript: requests and replies of a 3-cell bus (map above).
REQ1 = H("01 03 00 00 00 03 05 cb")
REQ2 = H("02 03 00 00 00 03 05 f8")
REQ3 = H("03 03 00 00 00 03 04 29")
RESP1 = H("01 03 06 00 00 13 0c 00 03 a5 f3")  # 4876, 3 decimals: 4.876 kg
RESP2 = H("02 03 06 ff ff fb 2e 00 03 24 b2")  # -1234, 3 decimals: -1.234 kg
RESP3 = H("03 03 06 00 00 27 10 00 03 73 65")  # 10000, 3 decimals: 10.000 kg
EXC1 = H("01 83 02 c0 f1")  # Modbus spec example: illegal data address


def test_requests_are_built_byte_for_byte():
    plan = plan_read(MAP)
    assert plan == ReadPlan(3, 0, 3, 0, 2, 2)
    assert [build_read_request(s, plan) for s in (1, 2, 3)] == [REQ1, REQ2, REQ3]
    # The canonical example of the Modbus documentation: slave 1, 2 holding registers from 0.
    fixed = ModbusRegisterMap(decimals_register=None)
    assert build_read_request(1, plan_read(fixed)) == H("01 03 00 00 00 02 c4 0b")
    assert build_write_request(1, 0x10, 1) == H("01 06 00 10 00 01 49 cf")


def test_read_plan_merges_value_and_decimals_only_when_near():
    near = ModbusRegisterMap(value_register=10, value_type="int16", decimals_register=4)
    assert plan_read(near) == ReadPlan(3, 4, 7, 6, 1, 0)
    far = ModbusRegisterMap(value_register=0, decimals_register=100)
    assert plan_read(far) == ReadPlan(3, 0, 2, 0, 2, None)
    inputs = ModbusRegisterMap(register_kind="input", value_type="int16", decimals_register=None)
    assert plan_read(inputs) == ReadPlan(4, 0, 1, 0, 1, None)
    # Per polled cell on the wire: 8 request + (5 + 2 * 3) reply + 2 * 3.5 silence characters.
    assert transaction_chars(plan_read(MAP)) == 8 + 11 + 7


def test_bus_timing_constants():
    assert char_time_s(115200) == pytest.approx(10 / 115200)
    assert char_time_s(9600, "E", 1) == pytest.approx(11 / 9600)
    assert spec_silence_s(9600) == pytest.approx(3.5 * 10 / 9600)
    assert spec_silence_s(115200) == SPEC_T35_FIXED_S


def test_register_decoding_and_saturation():
    assert registers_to_int([0x0000, 0x130C], "int32") == 4876
    assert registers_to_int([0xFFFF, 0xFB2E], "int32") == -1234
    assert registers_to_int([0xFF9C], "int16") == -100
    r = decode_reading(4876, 3, MAP)
    assert (r.value, r.unit, r.overload) == (4.876, "kg", False)
    assert r.reading_N == pytest.approx(4.876 * 9.80665)
    grams = ModbusRegisterMap(unit="g", value_type="int16")
    assert decode_reading(-100, 1, grams).reading_N == pytest.approx(-10.0 * 9.80665e-3)
    top = decode_reading(2**31 - 1, 3, MAP)
    assert top.overload and top.reading_N == math.inf
    bottom = decode_reading(-(2**15), 0, grams)
    assert bottom.overload and bottom.reading_N == -math.inf


class TestScanReply:
    def test_exact_reply(self):
        scan = scan_reply(RESP1, 1, 3, 11)
        assert scan.pdu is not None and list(scan.pdu.registers) == [0, 0x130C, 3]
        assert (scan.start, scan.end, scan.rejected) == (0, 11, 0)

    def test_noise_and_local_echo_before_the_reply_are_skipped(self):
        buf = REQ1 + H("00 ff 01 01 03") + RESP1
        scan = scan_reply(buf, 1, 3, 11)
        assert scan.pdu is not None and scan.start == len(buf) - 11

    def test_partial_reply_asks_for_exactly_the_missing_bytes(self):
        scan = scan_reply(RESP1[:4], 1, 3, 11)
        assert scan.pdu is None and scan.need == 7
        assert scan_reply(b"", 1, 3, 11).need == 11

    def test_bad_crc_is_rejected_never_returned(self):
        bad = RESP1[:-1] + bytes([RESP1[-1] ^ 0x01])
        scan = scan_reply(bad, 1, 3, 11)
        assert scan.pdu is None and scan.rejected == 1

    def test_false_start_in_noise_does_not_hide_the_reply(self):
        # noise that looks like the start of slave 1's reply, then the real reply
        buf = H("01 03 06 aa bb cc") + RESP1
        scan = scan_reply(buf, 1, 3, 11)
        assert scan.pdu is not None and list(scan.pdu.registers) == [0, 0x130C, 3]

    def test_other_slave_and_wrong_length_are_not_taken(self):
        assert scan_reply(RESP2, 1, 3, 11).pdu is None
        assert scan_reply(RESP1, 1, 3, 9).pdu is None  # asked 2 registers, got 3

    def test_exception_reply(self):
        scan = scan_reply(EXC1, 1, 3, 11)
        assert isinstance(scan.pdu, ExceptionResponse) and scan.pdu.exception_code == 2


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=64), st.integers(1, 247), st.integers(1, 4))
def test_random_bytes_never_crash_the_reply_scanner_or_yield_a_reply(data, slave, count):
    scan = scan_reply(data, slave, 3, 5 + 2 * count)
    assert scan.pdu is None
    assert scan.need >= 1


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=40), st.integers(-(2**31) + 1, 2**31 - 2), st.integers(0, 6))
def test_a_valid_reply_after_any_noise_is_found(noise, raw, decimals):
    u = raw & 0xFFFFFFFF
    body = bytes([1, 3, 6]) + bytes([u >> 24, (u >> 16) & 0xFF, (u >> 8) & 0xFF, u & 0xFF])
    frame = body + bytes([0, decimals])
    frame += ref_crc16_modbus(frame)
    scan = scan_reply(noise + frame, 1, 3, 11)
    assert scan.pdu is not None
    regs = list(scan.pdu.registers)
    assert registers_to_int(regs[:2], "int32") == raw and regs[2] == decimals


# -- a scripted device replaying a transcript on a pty -----------------------------------------


class ScriptedDevice:
    """Plays the transmitters from a transcript: per step, read the expected request, then do
    the actions: bytes are written, a float sleeps (s), ``"hangup"`` closes the pty."""

    def __init__(self, pair, steps):
        self.pair = pair
        self.steps = steps
        self.received: list[bytes] = []
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        for expected, actions in self.steps:
            self.received.append(self.pair.read(len(expected), timeout_s=5.0))
            for action in actions:
                if action == "hangup":
                    self.pair.close_master()
                    return
                if isinstance(action, float):
                    threading.Event().wait(action)
                else:
                    self.pair.write(action)


def test_recorded_transcript_with_noise_split_frames_bad_crc_and_disconnect(pty_pair, open_serial):
    steps = [
        (REQ1, [RESP1 + H("00 ff")]),  # clean reply + 2 trailing noise bytes
        (REQ2, [H("fe 02 03 99") + RESP2]),  # noise (with a false start) before the reply
        (REQ3, [RESP3[:3], 0.01, RESP3[3:7], 0.01, RESP3[7:]]),  # reply in 3 pieces
        (REQ1, [RESP1[:-1] + bytes([RESP1[-1] ^ 0x40])]),  # bad CRC
        (REQ2, [H("02 83 02") + ref_crc16_modbus(H("02 83 02"))]),  # exception reply
        (REQ3, []),  # no reply
        (REQ1, ["hangup"]),  # the cable is pulled mid-run
    ]
    device = ScriptedDevice(pty_pair, steps)
    bus = ModbusLoadCellBus(open_serial(pty_pair.path), [1, 2, 3], MAP, response_timeout_s=0.5)

    got = [bus.read(0), bus.read(1), bus.read(2)]
    assert [r.value for r in got] == [4.876, -1.234, 10.0]
    assert got[0].reading_N == pytest.approx(4.876 * KG)
    assert bus.read(0) is None  # bad CRC: counted, skipped
    assert bus.read(1) is None  # exception reply
    assert "illegal data address" in bus.last_problem[1]
    assert bus.read(2) is None  # timeout
    with pytest.raises(SensorError) as info:
        bus.read(0)
    device.thread.join(5.0)

    assert device.received == [s[0] for s in steps]  # every request, byte for byte
    assert info.value.port == pty_pair.path and pty_pair.path in str(info.value)
    assert "01 03 00 00 00 03 05 cb" in str(info.value)  # the last frames are in the message
    s = bus.stats
    assert (s.frames_ok, s.bad_frames, s.exceptions, s.timeouts) == (3, 1, 1, 1)
    # 2 trailing + 4 leading noise bytes + the 11 bytes of the bad-CRC reply
    assert s.discarded_bytes == 2 + 4 + 11


def test_decimals_register_far_from_the_value_is_read_once(pty_pair, open_serial):
    far = ModbusRegisterMap(decimals_register=100)
    steps = [
        (H("01 03 00 64 00 01 c5 d5"), [H("01 03 02 00 02 39 85")]),  # decimals = 2
        (H("01 03 00 00 00 02 c4 0b"), [H("01 03 04 00 01 e2 40 e2 a3")]),  # 123456
        (H("01 03 00 00 00 02 c4 0b"), [H("01 03 04 00 01 e2 40 e2 a3")]),
    ]
    device = ScriptedDevice(pty_pair, steps)
    bus = ModbusLoadCellBus(open_serial(pty_pair.path), [1], far, response_timeout_s=0.5)
    assert bus.read(0).value == 1234.56
    assert bus.read(0).value == 1234.56
    device.thread.join(5.0)
    assert device.received == [s[0] for s in steps]


def test_tare_writes_the_register_and_checks_the_echo(pty_pair, open_serial):
    tared = ModbusRegisterMap(tare_register=0x10, tare_value=1)
    echo = H("01 06 00 10 00 01 49 cf")
    wrong = H("01 06 00 10 00 02") + ref_crc16_modbus(H("01 06 00 10 00 02"))
    device = ScriptedDevice(pty_pair, [(echo, [echo]), (echo, [wrong])])
    bus = ModbusLoadCellBus(open_serial(pty_pair.path), [1], tared, response_timeout_s=0.5)
    bus.tare(0)
    with pytest.raises(SensorError, match="tare not acknowledged"):
        bus.tare(0)
    device.thread.join(5.0)
    assert device.received == [echo, echo]
    with pytest.raises(SensorError, match="no tare_register"):
        ModbusLoadCellBus(open_serial(pty_pair.path), [1], MAP).tare(0)


def test_bus_rejects_bad_slave_lists():
    port = serial.serial_for_url("loop://")
    with pytest.raises(ValueError):
        ModbusLoadCellBus(port, [], MAP)
    with pytest.raises(ValueError):
        ModbusLoadCellBus(port, [1, 1], MAP)
    with pytest.raises(ValueError):
        ModbusLoadCellBus(port, [0], MAP)


# -- against the simulated transmitters --------------------------------------------------------


class Truth:
    """Truth tensions (N) the test sets while the simulator runs."""

    def __init__(self, values):
        self.values = list(values)

    def __call__(self):
        return self.values


def _close(a, b):
    # 3 decimals in kg: the transmitter resolves 0.001 kg = 0.0098 N; rounding is half of that.
    return abs(a - b) <= 0.5e-3 * KG + 1e-9


def test_sampler_reads_three_simulated_cells(open_serial):
    truth = Truth([3.0, 12.5, 40.0])
    with ModbusLoadCellSim(truth, (1, 2, 3), MAP) as sim:
        bus = ModbusLoadCellBus(open_serial(sim.path), [1, 2, 3], MAP, response_timeout_s=0.5)
        with LoadCellSampler(bus, stale_after_s=5.0) as cells:
            cells.wait_for_samples(2, timeout_s=5.0)
            got = cells.latest()
            assert [s.address for s in got] == [1, 2, 3]
            assert all(_close(s.force_N, t) for s, t in zip(got, truth.values, strict=True))
            assert not any(s.stale for s in got)
            truth.values = [5.0, 6.0, -2.0]
            first = [s.seq for s in cells.latest()]
            cells.wait_for_samples(max(first) + 2, timeout_s=5.0)
            got = cells.latest()
            assert all(_close(s.force_N, t) for s, t in zip(got, truth.values, strict=True))
        assert bus.stats.bad_frames == 0 and bus.stats.timeouts == 0
        assert sim.stats.requests == bus.stats.frames_ok


def test_faults_from_the_simulator_are_counted_and_never_returned(open_serial):
    truth = Truth([7.0, 8.0])
    with ModbusLoadCellSim(truth, (4, 9), MAP, emulate_baud=False) as sim:
        bus = ModbusLoadCellBus(open_serial(sim.path), [4, 9], MAP, response_timeout_s=0.3)
        sim.corrupt_next(2)
        assert bus.read(0) is None and bus.read(1) is None
        sim.inject_garbage(H("04 03 06 00 13 88 99"))  # looks like slave 4's reply; is not
        assert _close(bus.read(0).reading_N, 7.0)
        sim.split_next(1, gap_s=0.02)
        assert _close(bus.read(1).reading_N, 8.0)
        sim.drop_next(1)
        assert bus.read(0) is None
        s = bus.stats
        assert (s.frames_ok, s.bad_frames, s.timeouts) == (2, 2, 1)
        assert s.discarded_bytes >= 2 * 11 + 7


def test_disconnect_while_sampling_fails_the_sampler_naming_the_port(open_serial):
    with ModbusLoadCellSim(Truth([1.0, 2.0, 3.0]), (1, 2, 3), MAP) as sim:
        bus = ModbusLoadCellBus(open_serial(sim.path), [1, 2, 3], MAP, port_name=sim.path)
        with LoadCellSampler(bus, stale_after_s=5.0) as cells:
            cells.wait_for_samples(1, timeout_s=5.0)
            sim.disconnect()
            with pytest.raises(SensorError) as info:
                cells.wait_for_samples(10**9, timeout_s=5.0)
            assert info.value.port == sim.path
            assert cells.failure is info.value
            assert all(s.stale for s in cells.latest())  # fresh age, but the port is gone
            # The sampler's thread ends: it published the failure (which woke this thread)
            # as its last act, and on a loaded machine it may not have returned yet.
            end = time.monotonic() + 5.0
            while cells.running and time.monotonic() < end:
                time.sleep(0.001)
            assert not cells.running


def test_noise_and_dropouts_reach_the_reader_as_noise_and_timeouts(open_serial):
    noise = SensorNoise(noise_N=0.2, dropout=0.2, seed=3)
    with ModbusLoadCellSim(Truth([20.0]), (1,), MAP, emulate_baud=False, noise=noise) as sim:
        bus = ModbusLoadCellBus(open_serial(sim.path), [1], MAP, response_timeout_s=0.1)
        values = [r.reading_N for r in (bus.read(0) for _ in range(80)) if r is not None]
    # a reply later than the timeout (machine busy) would count as a timeout too, never as data
    assert bus.stats.timeouts >= sim.stats.dropped > 0
    assert len(values) + bus.stats.timeouts + bus.stats.bad_frames == 80
    mean = sum(values) / len(values)
    sd = (sum((v - mean) ** 2 for v in values) / (len(values) - 1)) ** 0.5
    assert mean == pytest.approx(20.0, abs=0.1)
    assert 0.1 < sd < 0.3


def test_tare_through_the_sampler_zeroes_the_simulated_cell(open_serial):
    tared = ModbusRegisterMap(tare_register=0x10)
    truth = Truth([9.0, 4.0])
    with ModbusLoadCellSim(truth, (1, 2), tared) as sim:
        bus = ModbusLoadCellBus(open_serial(sim.path), [1, 2], tared, response_timeout_s=0.5)
        with LoadCellSampler(bus, stale_after_s=5.0) as cells:
            cells.wait_for_samples(1, timeout_s=5.0)
            cells.tare(1)
            seq = cells.latest()[1].seq
            cells.wait_for_samples(seq + 2, timeout_s=5.0)
            got = cells.latest()
            assert _close(got[0].force_N, 9.0) and _close(got[1].force_N, 0.0)


def test_stock_pymodbus_client_reads_the_simulated_transmitter():
    from pymodbus.client import ModbusSerialClient

    truth = Truth([4.876 * KG, -12.0, 55.5])
    tared = ModbusRegisterMap(tare_register=0x10)
    with ModbusLoadCellSim(truth, (1, 2, 3), tared) as sim:
        client = ModbusSerialClient(port=sim.path, baudrate=115200, timeout=1.0, retries=1)
        assert client.connect()
        try:
            rr = client.read_holding_registers(0, count=3, device_id=1)
            assert not rr.isError()
            assert rr.registers == [0x0000, 0x130C, 3]  # 4.876 kg, 3 decimals
            for slave, tension in ((2, -12.0), (3, 55.5)):
                rr = client.read_holding_registers(0, count=3, device_id=slave)
                raw = client.convert_from_registers(rr.registers[:2], client.DATATYPE.INT32)
                assert _close(raw / 10 ** rr.registers[2] * KG, tension)
            assert not client.write_register(0x10, 1, device_id=3).isError()  # tare
            rr = client.read_holding_registers(0, count=2, device_id=3)
            assert client.convert_from_registers(rr.registers, client.DATATYPE.INT32) == 0
            bad = client.read_holding_registers(1000, count=2, device_id=1)
            assert bad.isError() and bad.exception_code == 2
        finally:
            client.close()


# -- the simulator's request side, without a pty ---------------------------------------------


def test_simulator_answers_requests_byte_for_byte():
    sim = ModbusLoadCellSim(Truth([4.876 * KG, -1.234 * KG, 10.0 * KG]), (1, 2, 3), MAP)
    try:
        replies = [
            sim.handle_bytes(req, now_s=float(k)) for k, req in enumerate([REQ1, REQ2, REQ3])
        ]
        assert replies == [[(RESP1, 8)], [(RESP2, 8)], [(RESP3, 8)]]
        # not ours: another slave address; broadcast write: acted on, no reply
        other = H("07 03 00 00 00 03") + ref_crc16_modbus(H("07 03 00 00 00 03"))
        assert sim.handle_bytes(other, now_s=10.0) == []
        bad_fc = H("01 01 00 00 00 01") + ref_crc16_modbus(H("01 01 00 00 00 01"))
        exc = H("01 81 01") + ref_crc16_modbus(H("01 81 01"))
        assert sim.handle_bytes(bad_fc, now_s=11.0) == [(exc, 8)]
        far = H("01 03 03 e8 00 02") + ref_crc16_modbus(H("01 03 03 e8 00 02"))
        assert sim.handle_bytes(far, now_s=12.0)[0][0][:3] == H("01 83 02")
    finally:
        sim.stop()


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(max_size=40), max_size=6))
def test_random_bytes_never_crash_the_simulator_or_get_a_reply(chunks):
    sim = ModbusLoadCellSim(Truth([1.0]), (1,), MAP)
    try:
        for k, chunk in enumerate(chunks):
            # a reply needs slave 1 + a valid function + a valid CRC: not from random bytes
            replies = sim.handle_bytes(chunk, now_s=k * 1.0)
            assert all(frame[0] == 1 for frame, _ in replies)
            assert len(replies) <= 1
    finally:
        sim.stop()
