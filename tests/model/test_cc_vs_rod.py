"""scripts/cc_vs_rod.py, the comparison the tip-load docs quote: its two models meet the
cantilever limits of beam theory, and agree with each other without load."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scriptload import load_script

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rod():
    return load_script("cc_vs_rod")


def test_small_tip_force_on_a_straight_rod_and_arc(rod):
    """F at the tip of a straight cantilever: the rod deflects F L^3 / (3 EI) (Euler-Bernoulli),
    the single arc F L^3 / (4 EI) (energy EI th^2 / 2L - F L th / 2 at its minimum). F is small
    (deflection 0.2 % of L): the large-deflection terms are below 1e-3 relative."""
    L, EI, F = 90.0, 1206.0, 0.001
    pr, _ = rod.rod_tip([L], EI, [0.0], np.array([F, 0.0]))
    pc = rod.cc_tip([L], EI, [0.0], np.array([F, 0.0]))
    assert pr[0] == pytest.approx(F * L**3 / (3 * EI), rel=1e-3)
    assert pc[0] == pytest.approx(F * L**3 / (4 * EI), rel=1e-3)


def test_unloaded_rod_is_the_arcs(rod):
    """No tip load: the tendon moments are constant along each segment, so the rod's shape is
    the constant-curvature arcs (midpoint rule, 2000 steps: 1e-3 mm)."""
    lengths, EI = [200.0, 200.0], 2945.0
    M_seg = [5.0, 6.0]
    pr, _ = rod.rod_tip(lengths, EI, M_seg, np.zeros(2))
    pc = rod.cc_tip(lengths, EI, M_seg, np.zeros(2))
    assert np.linalg.norm(pr - pc) < 1e-3
