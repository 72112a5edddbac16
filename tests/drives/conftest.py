"""Fixtures: a rig's drives against simulated EPOS nodes on a python-can virtual bus."""

from __future__ import annotations

import pytest
from drivesim import close_rig, make_rig


@pytest.fixture
def rig():
    """(config, simulated drives, drive group booted and configured, frame spy bus)."""
    parts = make_rig()
    yield parts
    close_rig(*parts)
