"""Units and calibration of load-cell readings, against hand-derived values."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.sensors.loadcell import (
    G_M_PER_S2,
    Calibration,
    TrafficLog,
    from_newtons,
    to_newtons,
)


def test_units_to_newtons():
    assert G_M_PER_S2 == 9.80665  # standard gravity, exact by definition
    assert to_newtons(1.0, "kg") == 9.80665
    assert to_newtons(250.0, "g") == pytest.approx(2.4516625)
    assert to_newtons(1.0, "lb") == pytest.approx(4.4482216152605)  # 1 lbf, exact by definition
    assert to_newtons(-3.5, "N") == -3.5
    assert to_newtons(math.inf, "kg") == math.inf
    with pytest.raises(ValueError, match="unknown load-cell unit"):
        to_newtons(1.0, "oz")


@given(st.floats(-1e6, 1e6), st.sampled_from(["kg", "g", "N", "lb"]))
def test_from_newtons_inverts_to_newtons(value, unit):
    assert from_newtons(to_newtons(value, unit), unit) == pytest.approx(value, abs=1e-9)


def test_calibration_apply_zero_and_span():
    cal = Calibration(zero_N=0.5, span=2.0)
    assert cal.apply(3.0) == 5.0  # 2 * (3 - 0.5)
    assert cal.apply(0.5) == 0.0
    assert cal.apply(math.inf) == math.inf  # overload stays an overload
    assert cal.with_zero(1.5) == Calibration(1.5, 2.0)
    assert Calibration().apply(7.25) == 7.25


def test_two_point_calibration_with_a_reference_mass():
    # unloaded the transmitter reads 0.2 N; with 1 kg hung on it, 10.0 N
    cal = Calibration.from_two_points(0.2, 0.0, 10.0, 1.0 * G_M_PER_S2)
    assert cal.zero_N == pytest.approx(0.2)
    assert cal.span == pytest.approx(9.80665 / 9.8)
    assert cal.apply(10.0) == pytest.approx(9.80665)
    assert cal.apply(0.2) == pytest.approx(0.0)


@settings(max_examples=200)
@given(
    st.floats(-50, 50),
    st.floats(-50, 50),
    st.floats(0.1, 100),
    st.floats(0.5, 2.0),
)
def test_two_point_calibration_reproduces_both_points(reading_a, known_a, d_known, span):
    reading_b = reading_a + d_known / span
    known_b = known_a + d_known
    cal = Calibration.from_two_points(reading_a, known_a, reading_b, known_b)
    assert cal.apply(reading_a) == pytest.approx(known_a, abs=1e-6)
    assert cal.apply(reading_b) == pytest.approx(known_b, abs=1e-6)


@pytest.mark.parametrize("zero,span", [(0.0, 0.0), (0.0, -1.0), (math.nan, 1.0), (0.0, math.inf)])
def test_invalid_calibration_is_rejected(zero, span):
    with pytest.raises(ValueError):
        Calibration(zero, span)
    with pytest.raises(ValueError):
        Calibration.from_two_points(1.0, 0.0, 1.0, 5.0)


def test_traffic_log_keeps_the_last_frames():
    log = TrafficLog(size=3)
    for k in range(5):
        log.add("tx", bytes([k, 0xAB]), t_s=float(k))
    assert [t for t, _, _ in log.frames] == [2.0, 3.0, 4.0]
    assert log.dump(last=2) == "  tx 03 ab\n  tx 04 ab"
