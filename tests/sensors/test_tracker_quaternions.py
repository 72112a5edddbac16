"""The tracker's quaternion <-> matrix conversions, written on Python floats, against the
formulas on numpy arrays (their norm and division: the same IEEE operations, so the same bits)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cdcr_ctl.sensors.tracker import (
    quaternion_from_rotation,
    rotation_from_quaternion,
    rotation_from_rotvec,
)
from cdcr_ctl.sensors.tracker.frames import _norm

fin = st.floats(-1e4, 1e4, allow_nan=False)
val = st.one_of(fin, st.sampled_from([0.0, -0.0, math.inf, -math.inf, math.nan, 1e-300]))


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


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
