"""Shared fixtures: short logged runs of the simulated rig with one hidden effect each.

The runs are made by ``scripts/make_discrepancy_runs.py`` (the simulator's truth stepped
offline, the run-log writer, the loop's columns) from the variants in ``config/sim/effects``.
Tests may read the truth variants; the workflow under test only sees the run directories.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from scriptload import load_script

ROOT = Path(__file__).resolve().parents[2]
EFFECTS = ROOT / "config" / "sim" / "effects"


def _generator():
    return load_script("make_discrepancy_runs")


@pytest.fixture(scope="session")
def gen():
    return _generator()


@pytest.fixture(scope="session")
def short_runs(tmp_path_factory, gen):
    """name -> run dir: 12 s at 50 Hz of the 'rich' trajectory, one per hidden effect."""
    out = tmp_path_factory.mktemp("disc-runs")
    runs = {}
    for name in ("none", "backlash", "actuator_scale", "tracker_offset"):
        runs[name] = gen.make_run(
            EFFECTS / f"{name}.yaml",
            out,
            duration_s=12.0,
            rate_hz=50.0,
            trajectory="rich",
            bend_rad=1.0,
            seed=2,
            name=name,
        )
    return runs
