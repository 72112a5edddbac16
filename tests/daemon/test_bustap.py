"""``stop`` timed on the bus (issue #21): the tap finds the first quick-stop controlword frame
(RPDO or SDO 0x6040) after the request, byte by byte, and counts the SYNCs sent before it."""

from __future__ import annotations

import can
import pytest

from cdcr_ctl.daemon.bustap import StopBusTap, TeeListener, is_quick_stop_frame


def _tx(cob: int, data: bytes, t: float, rx: bool = False) -> can.Message:
    return can.Message(timestamp=t, arbitration_id=cob, data=data, is_extended_id=False, is_rx=rx)


@pytest.mark.parametrize(
    ("cob", "data", "expected"),
    [
        (0x301, b"\x02\x00", True),  # controlword RPDO: 0x0002 little endian
        (0x201, b"\x02\x00", True),
        (0x301, b"\x0f\x00", False),  # enable operation
        (0x301, b"\x00\x02", False),  # 0x0200, not a quick stop
        (0x201, b"\x02\x00\x00\x00", False),  # a 4-byte target, not the controlword
        (0x602, bytes.fromhex("2B40600002000000"), True),  # SDO download 0x6040:00 = 0x0002
        (0x602, bytes.fromhex("2B40600006000000"), False),  # shutdown
        (0x582, bytes.fromhex("2B40600002000000"), False),  # an SDO answer, not a request
        (0x080, b"", False),
    ],
)
def test_quick_stop_frames_are_recognised_byte_by_byte(cob, data, expected):
    assert is_quick_stop_frame(cob, data) is expected


def test_the_tap_times_the_first_quick_stop_after_the_request_and_counts_syncs():
    period = 1e-3
    tap = StopBusTap()
    tap.on_message_received(_tx(0x301, b"\x02\x00", 9.0))  # before any request: ignored
    tap.arm(10.0)
    assert tap.result(period) is None
    tap.on_message_received(_tx(0x201, b"\x00\x01\x00\x00", 10.0002))
    tap.on_message_received(_tx(0x080, b"", 10.0003))  # one bus cycle
    tap.on_message_received(_tx(0x181, b"\x02\x00", 10.0004, rx=True))  # received: ignored
    tap.on_message_received(_tx(0x301, b"\x02\x00", 10.0012))  # the quick stop
    tap.on_message_received(_tx(0x080, b"", 10.0013))
    tap.on_message_received(_tx(0x302, b"\x02\x00", 10.0014))  # a second drive: not first
    res = tap.result(period)
    assert res["syncs_before"] == 1
    assert res["cob_id"] == "0x301"
    # 1.2 ms; the float sum's rounding is far below the 1 us the result keeps.
    assert res["quick_stop_after_ms"] == pytest.approx(1.2, abs=1e-3)
    assert res["cycles"] == pytest.approx(1.2, abs=1e-3)
    tap.arm(20.0)  # a new request forgets the old frame
    assert tap.result(period) is None


def test_the_tee_hands_every_frame_to_each_listener():
    a, b = StopBusTap(), StopBusTap()
    a.arm(0.0)
    b.arm(0.0)
    tee = TeeListener(a, b)
    tee.on_message_received(_tx(0x301, b"\x02\x00", 0.002))
    tee.stop()
    assert a.result(1e-3)["cycles"] == b.result(1e-3)["cycles"] == pytest.approx(2.0, abs=1e-6)
