"""Fixtures: simulated EPOS nodes and a DriveGroup on a python-can virtual bus (one process)."""

from __future__ import annotations

import pytest
from drivesim import Rig, make_rig


@pytest.fixture
def rig():
    """Three simulated EPOS4 in CSP and a group booted and configured (nothing enabled)."""
    r: Rig = make_rig()
    yield r
    r.close()
