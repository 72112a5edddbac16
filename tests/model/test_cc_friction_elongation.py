"""Disk-hole capstan (eq. 16-24) and elongation (eq. 33-36): hand values and limits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from cc_robots import make_robot

from cdcr_ctl.model.cc_disk import elongation as el
from cdcr_ctl.model.cc_disk.routing import wrap_angles
from cdcr_ctl.model.shared import friction as fr


def test_hole_by_hole_propagation_eq23():
    wraps = np.array([0.1, 0.2, 0.2, 0.2])
    spans, Tb = fr.propagate(3.0, wraps, 0.3, 1.0)
    assert spans[-1] == 3.0
    assert spans[0] == pytest.approx(3.0 * math.exp(0.3 * 0.6))
    assert Tb == pytest.approx(3.0 * math.exp(0.3 * 0.7))  # pulled in: higher towards the base
    _, Tb_out = fr.propagate(3.0, wraps, 0.3, -1.0)
    assert Tb_out == pytest.approx(3.0 * math.exp(-0.3 * 0.7))  # paid out: lower
    spans0, Tb0 = fr.propagate(3.0, wraps, 0.3, 0.0)
    assert Tb0 == 3.0 and np.all(spans0 == 3.0)


def test_mean_geometric_closed_form():
    for y, n in [(0.05, 5), (-0.2, 7), (1e-12, 4), (0.0, 3)]:
        explicit = np.mean([math.exp(p * y) for p in range(n)])
        assert fr.mean_geometric(y, n) == pytest.approx(explicit, rel=1e-12)


def test_direction_rule_keeps_state_when_still():
    assert fr.direction_update(-1.0, 0.0) == -1.0  # hysteresis: no motion, no change
    assert fr.direction_update(-1.0, 1e-6) == 1.0
    assert fr.direction_update(1.0, -1e-6) == -1.0
    assert fr.band_update(1.0, -0.1, 0.4) == pytest.approx(0.75)
    assert fr.band_update(-0.9, 1.0, 0.4) == 1.0


def test_friction_state_validation():
    st = fr.FrictionState.initial(3)
    assert st.s == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        fr.FrictionState(s=(1.5,), w_mm=(0.0,))
    with pytest.raises(ValueError):
        fr.FrictionState(s=(1.0, 1.0), w_mm=(0.0,))


def test_rigid_cable_does_not_stretch():
    assert el.piecewise([5.0, 9.0], [10.0, 20.0], 2.0, math.inf) == 0.0
    assert el.continuous_disk(5.0, 0.3, 1.0, 1.0, 90.0, 2.0, math.inf) == 0.0
    assert el.piecewise([5.0, 9.0], [10.0, 20.0], 2.0, 1000.0) == pytest.approx(
        (3.0 * 10 + 7.0 * 20) / 1000.0
    )


def test_discrete_disk_stretch_tends_to_eq36():
    theta, mu, Td, T0, EA = 1.2, 0.3, 6.0, 2.0, 2500.0
    cont = el.continuous_disk(Td, mu, 1.0, theta, 90.0, T0, EA)
    errs = []
    for n in (5, 50, 500):
        p = make_robot(1, n_disks=n)
        wraps = wrap_angles([[theta, 0.0]], p, 0)
        spans, _ = fr.propagate(Td, wraps, mu, 1.0)
        errs.append(abs(el.piecewise(spans, [90.0 / n] * n, T0, EA) - cont))
    assert errs[-1] < 1e-3 * cont
    assert errs[1] == pytest.approx(errs[0] / 10, rel=0.1)  # first order in 1/n (span sums)
    assert errs[2] == pytest.approx(errs[1] / 10, rel=0.1)
    # eq. 36 without friction: uniform tension
    assert el.continuous_disk(Td, 0.0, 1.0, theta, 90.0, T0, EA) == pytest.approx(
        (Td - T0) * 90.0 / EA
    )


def test_cable_profile_pulleys_and_split():
    p = make_robot(1)
    c = p.cables[0]
    trs = el.transfers_for(c)
    prof = el.cable_profile([[0.8, 0.0]], p, 0, 5.0, 1.0, trs)
    assert prof.T_distal_N == 5.0
    assert prof.T_base_N > 5.0 and prof.T_actuator_N > prof.T_base_N
    d_in, d_out = el.split_elongation(prof, c, 1.0, trs)
    assert d_in > 0 and d_out > 0
    assert len(prof.runs_N) == 3 and prof.run_length_mm == pytest.approx(50.0)
