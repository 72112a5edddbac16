"""DriveGroupPort.positions (the loop's read every cycle) is the positions of its feedback."""

from __future__ import annotations

import enum
from types import SimpleNamespace

from cdcr_ctl.control.io import DriveGroupPort


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
