"""Tracker timing (sample-and-hold tracker beside the loop) against synthetic series with a known
delay pattern. Level: model (hand-made signals, no simulation)."""

from __future__ import annotations

import numpy as np
import pytest

from cdcr_ctl.discrepancy.alignment import noise_sigma, residual_noise_sigma
from cdcr_ctl.discrepancy.timing import estimate_timing, no_timing


def _path(t: np.ndarray) -> np.ndarray:
    """A smooth tip path (mm) with speeds up to ~30 mm/s and reversals."""
    return np.column_stack(
        (20 * np.sin(0.9 * t), 15 * np.sin(1.3 * t + 0.4), 90 - 2 * np.cos(0.7 * t))
    )


def _beat_delays(cycle: np.ndarray, loop_hz: float, tracker_hz: float, latency_s: float):
    """Delay of the newest frame at each row: frames exposed every 1/tracker_hz from a phase,
    delivered latency_s later; the row at t shows the newest delivered frame (s)."""
    t = cycle / loop_hz
    phase = 0.3 / tracker_hz
    k = np.floor((t - latency_s - phase) * tracker_hz)
    return t - (phase + k / tracker_hz)


@pytest.fixture
def series():
    rng = np.random.default_rng(3)
    cycle = np.arange(3000)
    t = cycle / 100.0
    delay = _beat_delays(cycle, 100.0, 120.0, 0.004)
    meas = _path(t - delay) + 0.02 * rng.standard_normal((len(t), 3))
    # the model is off by a smooth error (as a missing effect would make it)
    model = _path(t) + np.column_stack((0.3 * np.sin(0.2 * t), 0.2 * np.cos(0.3 * t), 0 * t))
    return t, cycle, delay, meas, model


def test_finds_the_beat_period_and_the_delay_pattern(series):
    t, cycle, delay, meas, model = series
    tim = estimate_timing(t, cycle, meas, model)
    # 100 Hz beside 120 Hz: the pattern repeats every 100 / gcd(100, 120) = 5 cycles
    assert tim.period_rows == 5
    true_rel = np.array([delay[cycle % 5 == c].mean() for c in range(5)])
    true_rel -= true_rel.mean()
    assert tim.delay_s == pytest.approx(true_rel, abs=3e-4)
    # the common part is left to the workflow; with the right model it is found
    fixed = tim.with_common_delay(meas, _path(t))
    assert fixed.row_delay_s == pytest.approx(delay, abs=5e-4)
    e = meas - fixed.apply(_path(t))
    assert np.sqrt(np.mean(e**2)) == pytest.approx(0.02, rel=0.1)  # down to the noise


def test_clocks_that_do_not_beat_give_one_constant_delay():
    rng = np.random.default_rng(4)
    cycle = np.arange(2000)
    t = cycle / 100.0
    meas = _path(t - 0.012) + 0.02 * rng.standard_normal((len(t), 3))
    tim = estimate_timing(t, cycle, meas, _path(t))
    assert tim.period_rows == 1 and tim.delay_s == pytest.approx([0.0])
    assert tim.with_common_delay(meas, _path(t)).delay_s == pytest.approx([0.012], abs=2e-4)


def test_no_tip_means_no_timing():
    t = np.arange(100) / 100.0
    tim = estimate_timing(t, np.arange(100), np.full((100, 3), np.nan), _path(t))
    assert tim.period_rows == 1
    tip = _path(t)
    assert no_timing(t).apply(tip) == pytest.approx(tip)


def test_noise_from_the_timed_residual_excludes_the_sampling_jitter(series):
    t, cycle, _, meas, _ = series
    # from the samples alone the jitter of the moving tip counts as noise
    assert noise_sigma(meas, 1e-3) > 0.025
    tim = estimate_timing(t, cycle, meas, _path(t)).with_common_delay(meas, _path(t))
    assert residual_noise_sigma(meas, tim.apply(_path(t)), 1e-3) == pytest.approx(0.02, rel=0.15)


def _triangle(t: np.ndarray, period_s: float, amp_mm: float) -> np.ndarray:
    u = (t / period_s) % 1.0
    return amp_mm * (2.0 * np.abs(2.0 * u - 1.0) - 1.0)


def test_beat_found_on_a_path_with_sharp_reversals():
    """Reversals every 25 rows (a triangle path at 60 mm/s, as stick and reversals make): the
    linearised delay column is wrong there, always in the same row classes mod 25. The rows near
    the kinks are left out, so the true 5-cycle beat is found, not a spurious 25-cycle one."""
    rng = np.random.default_rng(4)
    cycle = np.arange(4000)
    t = cycle / 100.0

    def path(tt):
        return np.column_stack(
            (_triangle(tt + 0.123, 0.5, 15.0), _triangle(tt + 0.1, 1.0, 10.0), 90 + 0 * tt)
        )

    delay = _beat_delays(cycle, 100.0, 120.0, 0.004)
    meas = path(t - delay) + 0.02 * rng.standard_normal((len(t), 3))
    tm = estimate_timing(t, cycle, meas, path(t)).with_common_delay(meas, path(t))
    assert tm.period_rows == 5
    assert np.allclose(tm.row_delay_s, delay, atol=3e-4)
