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

    def __init__(self, fault=None):
        self.fb = [
            SimpleNamespace(node=n, position_counts=p, state=_State.ENABLED, t_s=9.99, fault="")
            for n, p in ((1, 12), (2, -40000), (3, 7))
        ]
        self._fault = fault

    def feedback(self):
        return list(self.fb)

    def fault(self):
        return self._fault


def test_positions_are_the_feedbacks():
    port = DriveGroupPort(_Group())  # type: ignore[arg-type]
    assert port.positions() == [f.position_counts for f in port.feedback()] == [12, -40000, 7]


def test_a_nodes_fault_shows_on_that_drive_only():
    boot = SimpleNamespace(node=1, text="node 1: boot-up message: the drive restarted")
    port = DriveGroupPort(_Group(boot))  # type: ignore[arg-type]
    assert [d.fault for d in port.feedback()] == [boot.text, "", ""]
    bus = SimpleNamespace(node=0, text="bus: no frame received")  # the rig's, not a drive's
    assert [d.fault for d in DriveGroupPort(_Group(bus)).feedback()] == ["", "", ""]  # type: ignore[arg-type]


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
