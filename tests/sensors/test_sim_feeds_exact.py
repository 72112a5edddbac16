"""The simulated sensors' feeds computed on Python floats and noise drawn in blocks, bit for bit
against the per-call draws they replace: the load cells' tension noise (``TensionFeed``), the
transmitter's cached-request entry; the tracker's body pose (``TruthSampler``) against
hand-worked transforms."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from cdcr_ctl.config.loadcells import ModbusRegisterMap
from cdcr_ctl.sensors.loadcell_modbus import build_read_request, plan_read
from cdcr_ctl.sensors.tracker import TrackerTransform, rotation_from_rotvec
from cdcr_ctl.sim.loadcells import ModbusLoadCellSim, SensorNoise
from cdcr_ctl.sim.loadcells.feed import NOISE_BLOCK, TensionFeed
from cdcr_ctl.sim.tracker.feed import TruthSampler


def _bits(values) -> bytes:
    return struct.pack(f"<{len(values)}d", *values)


def test_tension_noise_in_blocks_is_the_per_call_stream() -> None:
    times = [0.001 * k for k in range(4 * NOISE_BLOCK)]
    clock = iter(times).__next__
    tensions = [3.25, 7.5, 1.0]
    feed = TensionFeed(lambda: tensions, 3, SensorNoise(0.02, 0.001, 0.0, 5), clock)
    ref = np.random.default_rng(5)
    for k in range(3 * NOISE_BLOCK + 7):  # across block ends
        got = feed.measure(k % 3)
        # TensionFeed.measure's formula with one rng.normal call per reading
        drift = 0.001 * (times[k + 1] - times[0])
        want = tensions[k % 3] + drift + float(ref.normal(0.0, 0.02))
        assert _bits([got]) == _bits([want]), k


def test_tension_noise_with_dropouts_draws_per_call() -> None:
    feed = TensionFeed(lambda: [1.0], 1, SensorNoise(0.02, 0.0, 0.3, 5), lambda: 0.0)
    ref = np.random.default_rng(5)
    for _ in range(500):
        got = feed.measure(0)
        want = None if ref.random() < 0.3 else 1.0 + float(ref.normal(0.0, 0.02))
        assert (got is None) == (want is None) and (got is None or _bits([got]) == _bits([want]))


def test_cached_request_entry_answers_as_the_parsing_loop() -> None:
    rm = ModbusRegisterMap()
    sims = [
        ModbusLoadCellSim(lambda: [5.0, 6.0], [1, 2], rm, noise=SensorNoise(0.05, seed=3))
        for _ in range(2)
    ]
    try:
        reqs = [build_read_request(s, plan_read(rm)) for s in (1, 2)]
        for k in range(200):
            req = reqs[k % 2]
            fast = sims[0].handle_bytes(req, 0.01 * k)  # bytes: the cached entry
            slow = sims[1].handle_bytes(bytearray(req), 0.01 * k)  # the loop
            assert fast == slow
        assert sims[0].stats == sims[1].stats
    finally:
        for s in sims:
            s.stop()


def test_sample_is_the_body_pose_of_hand_worked_transforms() -> None:
    # Tracker frame: the body pose as given, the position in tracker units (1000 mm per unit).
    R = rotation_from_rotvec([0.1, -0.2, 0.05])
    s = TruthSampler(lambda: (R, np.array([10.0, -3.0, 88.0])), TrackerTransform.identity(1000.0),
                     "tracker", 0.0, np.random.default_rng(2))  # fmt: skip
    p, rows = s.sample_floats()
    assert p == pytest.approx([0.010, -0.003, 0.088], rel=1e-15)
    assert np.asarray(rows).tobytes() == R.tobytes()
    # Base frame: tracker turned +90 deg about z, at (5, 0, -2) mm; the tip 12 mm along the
    # body's z. Tip at (10, 20, 30) mm, unrotated: the body is Rz(-90 deg) in the tracker, at
    # Rz(-90 deg) ((10, 20, 30) - (5, 0, -2)) - (0, 0, 12) = (20, -5, 32) - (0, 0, 12).
    tf = TrackerTransform(rotation_from_rotvec([0.0, 0.0, np.pi / 2]), np.array([5.0, 0.0, -2.0]),
                          np.eye(3), np.array([0.0, 0.0, 12.0]), 1.0)  # fmt: skip
    s = TruthSampler(lambda: (np.eye(3), np.array([10.0, 20.0, 30.0])), tf, "base", 0.0,
                     np.random.default_rng(2))  # fmt: skip
    p, rows = s.sample_floats()
    # cos(pi/2) is 6e-17, not 0: the entries within a few ulp of 30 mm of the exact ones
    assert p == pytest.approx([20.0, -5.0, 20.0], abs=1e-13)
    assert np.asarray(rows) == pytest.approx(
        np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]]), abs=1e-15
    )
    p_arr, R_arr = s.sample()  # the same pose as arrays
    assert p_arr.tolist() == p and R_arr.tolist() == rows


def test_sample_noise_is_the_generators_normal_in_tracker_units() -> None:
    s = TruthSampler(lambda: np.array([10.0, -3.0, 88.0]), TrackerTransform.identity(1000.0),
                     "tracker", 0.05, np.random.default_rng(2))  # fmt: skip
    ref = np.random.default_rng(2)
    for _ in range(20):
        p, rows = s.sample_floats()
        noise = ref.normal(0.0, 0.05, 3)
        assert p == pytest.approx([10.0e-3 + noise[0] / 1000.0, -3.0e-3 + noise[1] / 1000.0,
                                   88.0e-3 + noise[2] / 1000.0], rel=1e-15)  # fmt: skip
        assert rows == np.eye(3).tolist()
