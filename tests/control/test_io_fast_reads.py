"""The ports' list reads the loop makes every cycle give the values of their general reads:
DriveGroupPort.positions, LoadCellTension.latest_lists."""

from __future__ import annotations

import enum
import math
from types import SimpleNamespace

import numpy as np

from cdcr_ctl.control.io import DriveGroupPort, LoadCellTension


class _State(enum.Enum):
    ENABLED = "OPERATION_ENABLED"


class _Group:
    clock = staticmethod(lambda: 10.0)

    def __init__(self):
        self.fb = [
            SimpleNamespace(position_counts=p, state=_State.ENABLED, t_s=9.99)
            for p in (12, -40000, 7)
        ]

    def feedback(self):
        return list(self.fb)

    def first_fault(self):
        return None


def test_positions_are_the_feedbacks():
    port = DriveGroupPort(_Group())  # type: ignore[arg-type]
    assert port.positions() == [f.position_counts for f in port.feedback()] == [12, -40000, 7]


class _Sampler:
    def latest_forces(self):
        return [2.5, math.nan, np.float64(0.1) + 0.2], [0.004, math.inf, 0.012]


def test_tension_lists_are_latest():
    port = LoadCellTension(_Sampler(), [2, -1, 0, 1])  # type: ignore[arg-type]
    f, a = port.latest()
    fl, al = port.latest_lists()
    assert all(type(v) is float for v in fl + al)
    assert np.array(fl).tobytes() == f.tobytes() and np.array(al).tobytes() == a.tobytes()
    assert np.isnan(fl[1]) and al[1] == math.inf
