"""Tracker frames without numpy's small-array calls, bit for bit against the numpy formulas:
the aligned transform's shortcut in ``tip_in_base`` / ``body_in_tracker`` (identity rotations,
zero translations: only the scale applied) and the quaternion <-> matrix conversions as floats
(their norm and division)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.sensors.tracker import (
    TrackerTransform,
    quaternion_from_rotation,
    rotation_from_quaternion,
    rotation_from_rotvec,
)
from cdcr_ctl.sensors.tracker.frames import _norm

fin = st.floats(-1e4, 1e4, allow_nan=False)
val = st.one_of(fin, st.sampled_from([0.0, -0.0, math.inf, -math.inf, math.nan, 1e-300]))


def _tip_numpy(tf: TrackerTransform, p, R):
    p_tracker_mm = tf.mm_per_unit * np.asarray(p, dtype=float)
    p_tracker_mm = p_tracker_mm + R @ tf.t_body_tip_mm
    return tf.R_base_tracker @ p_tracker_mm + tf.t_base_tracker_mm, (
        tf.R_base_tracker @ R @ tf.R_body_tip
    )


def _body_numpy(tf: TrackerTransform, p, R):
    R_tb = tf.R_base_tracker.T @ np.asarray(R, dtype=float) @ tf.R_body_tip.T
    p_tracker_mm = tf.R_base_tracker.T @ (np.asarray(p, dtype=float) - tf.t_base_tracker_mm)
    return (p_tracker_mm - R_tb @ tf.t_body_tip_mm) / tf.mm_per_unit, R_tb


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


@settings(max_examples=500, deadline=None)
@given(st.lists(val, min_size=3, max_size=3), st.lists(val, min_size=9, max_size=9))
def test_aligned_transform_is_the_numpy_formula(p, r) -> None:
    R = np.array(r).reshape(3, 3)
    for tf in (TrackerTransform.identity(1000.0), TrackerTransform.identity(1.0)):
        assert tf.aligned
        with np.errstate(all="ignore"):
            want = _tip_numpy(tf, tuple(p), R)
            got = tf.tip_in_base(tuple(p), R)
            assert _same_bits(got[0], want[0]) and _same_bits(got[1], want[1])
            want = _body_numpy(tf, np.array(p), R)
            got = tf.body_in_tracker(np.array(p), R)
            assert _same_bits(got[0], want[0]) and _same_bits(got[1], want[1])


def test_a_rotated_or_offset_transform_is_not_aligned() -> None:
    eye, zero = np.eye(3), np.zeros(3)
    assert not TrackerTransform(rotation_from_rotvec([0, 0, 0.1]), zero, eye, zero, 1.0).aligned
    assert not TrackerTransform(eye, np.array([0, 1.0, 0]), eye, zero, 1.0).aligned
    assert not TrackerTransform(eye, zero, eye, np.array([0, 0, -2.0]), 1.0).aligned


def _rotation_numpy(q_xyzw):
    q = np.asarray(q_xyzw, dtype=float)
    n = float(np.linalg.norm(q))
    x, y, z, w = (q / n).tolist()
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@settings(max_examples=500, deadline=None)
@given(st.lists(st.floats(-3.2, 3.2), min_size=3, max_size=3))
def test_quaternion_conversions_are_the_numpy_ones(rotvec) -> None:
    R = rotation_from_rotvec(rotvec)
    q = quaternion_from_rotation(R)
    # the two steps that left numpy: the norm (numpy's own sqrt of v.dot(v)) and the division
    v = np.asarray(q) * 1.000001
    assert _same_bits(_norm(v), float(np.linalg.norm(v)))
    assert _same_bits([x / _norm(v) for x in v.tolist()], v / np.linalg.norm(v))
    q32 = tuple(float(np.float32(v)) for v in q)  # as a NatNet frame carries it
    assert _same_bits(rotation_from_quaternion(q32), _rotation_numpy(q32))
