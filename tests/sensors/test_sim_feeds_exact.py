"""The simulated sensors' feeds computed on Python floats and noise drawn in blocks, bit for bit
against the numpy formulas and per-call draws they replace: the load cells' tension noise
(``TensionFeed``), the transmitter's cached-request entry, the tracker's body pose
(``TruthSampler.sample_floats``)."""

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


def _pose(k: int):
    R = rotation_from_rotvec([0.1 + 0.01 * k, -0.2, 0.05 * k])
    if k % 5 == 2:
        R[1, 0] = 0.0  # a zero entry: the numpy path
    return R, np.array([10.0 + k, -3.0 * k + 0.5, 88.0])


def _numpy_sample(s: TruthSampler, R, p):
    if s.truth_frame == "base":
        tf = s.transform
        R_tb = tf.R_base_tracker.T @ R @ tf.R_body_tip.T
        p_tr = tf.R_base_tracker.T @ (p - tf.t_base_tracker_mm)
        p_units = (p_tr - R_tb @ tf.t_body_tip_mm) / tf.mm_per_unit
    else:
        p_units, R_tb = p / s.transform.mm_per_unit, R
    if s.noise_mm > 0:
        p_units = p_units + s.rng.normal(0.0, s.noise_mm, 3) / s.transform.mm_per_unit
    return p_units, R_tb


@pytest.mark.parametrize("frame", ["base", "tracker"])
@pytest.mark.parametrize(
    "tf",
    [
        TrackerTransform.identity(1000.0),
        TrackerTransform(
            rotation_from_rotvec([0.0, 0.3, 0.1]),
            np.array([5.0, 0.0, -2.0]),
            rotation_from_rotvec([0.2, 0.0, 0.0]),
            np.array([0.0, 0.0, 12.0]),
            1000.0,
        ),
    ],
)
def test_sample_floats_is_the_numpy_formula(frame, tf) -> None:
    poses = iter(range(1000))
    a = TruthSampler(lambda: _pose(next(poses)), tf, frame, 0.05, np.random.default_rng(2))
    b = TruthSampler(lambda: None, tf, frame, 0.05, np.random.default_rng(2))
    for k in range(60):
        p, rows = a.sample_floats()
        R, pm = _pose(k)
        p_ref, R_ref = _numpy_sample(b, R, pm)
        assert _bits(p) == _bits(p_ref.tolist())
        assert _bits([v for r in rows for v in r]) == _bits(np.asarray(R_ref).ravel().tolist())
