"""Identification (Qi et al. 2023 eq. 38): mu from load-cell tensions, generic parameter fits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from cc_robots import make_robot, qi_params

from cdcr_ctl.model.cc_disk import identification as idf
from cdcr_ctl.model.cc_disk.compensation import Compensator
from cdcr_ctl.model.cc_disk.params import Effects

MU_TRUE = (0.26, 0.31, 0.28)  # Table 1


def _truth():
    p = qi_params()
    refs = [idf.ParamRef("cable", k, "mu_disk") for k in range(3)]
    return idf.with_values(p, refs, MU_TRUE), refs


def test_paper_sweep_layout():
    p, _ = _truth()
    sweep = idf.paper_sweep(p)
    # 3 directions x (11 angles up + 10 down)
    assert len(sweep) == 3 * 21
    thetas = sorted({round(math.degrees(psi[0, 0])) for psi, _ in sweep})
    assert thetas == list(range(40, 91, 5))
    up = [s for psi, s in sweep[:11]]
    down = [s for psi, s in sweep[11:21]]
    assert all(s[0] == 1.0 for s in up) and all(s[0] == -1.0 for s in down)


@pytest.mark.parametrize("location", ["actuator", "robot_base"])
def test_friction_recovered_within_5_percent_from_noisy_tensions(location):
    truth, refs = _truth()
    locs = [location] * 3
    sweep = idf.paper_sweep(truth)
    data = idf.synthetic_tensions(truth, sweep, locs, noise_rel=0.01, rng=np.random.default_rng(11))
    start = idf.with_values(truth, refs, [0.1, 0.1, 0.1])
    res = idf.fit_friction(start, data, locs)
    assert res.success
    for k in range(3):
        assert res.values[k] == pytest.approx(MU_TRUE[k], rel=0.05)
        lo, hi = res.ci95[k]
        assert lo < res.values[k] < hi and hi - lo < 0.2 * MU_TRUE[k]
        assert abs(res.values[k] - MU_TRUE[k]) < 4 * res.std[k]
    assert res.residual_rms == pytest.approx(0.01, rel=0.3)  # the noise level
    assert "cable[0].mu_disk" in res.table()


def test_exact_data_gives_exact_fit_and_tiny_intervals():
    truth, refs = _truth()
    locs = ["actuator"] * 3
    data = idf.synthetic_tensions(truth, idf.paper_sweep(truth), locs)
    res = idf.fit_friction(idf.with_values(truth, refs, [0.2] * 3), data, locs)
    np.testing.assert_allclose(res.values, MU_TRUE, rtol=1e-6)
    assert np.all(res.std < 1e-6)


def test_parameter_vector_roundtrip_including_pulleys():
    p = qi_params()
    refs = [
        idf.ParamRef("cable", 1, "EA_N"),
        idf.ParamRef("segment", 0, "EI_Nmm2"),
        idf.ParamRef("pulley", "guide_a", "alpha"),
        idf.ParamRef("cable", 2, "pretension_N"),
    ]
    vals = [2000.0, 1500.0, 0.2, 2.5]
    q = idf.with_values(p, refs, vals)
    assert [idf.get_value(q, r) for r in refs] == vals
    assert all(c.pulleys[0].alpha == 0.2 for c in q.cables)  # a shared pulley changes everywhere
    assert all(c.pulleys[1].alpha == p.cables[0].pulleys[1].alpha for c in q.cables)
    assert p.cables[1].EA_N != 2000.0  # the original is untouched (frozen)


def test_stiffness_fitted_from_tracker_tips():
    eff = Effects(disk_friction=False, pulley_friction=False)
    truth = make_robot(1)
    true_EI = truth.segments[0].EI_Nmm2
    comp = Compensator(truth, eff)
    from cdcr_ctl.model.cc_disk.forward import ForwardModel

    fwd = ForwardModel(truth, eff)
    rng = np.random.default_rng(5)
    samples = []
    for th, ph in [(0.4, 0.0), (0.8, 1.0), (1.1, -2.0), (0.6, 2.5), (0.9, 0.3)]:
        q = comp.q_geometric([[th, ph]])  # uncompensated commands: the stiffness shows
        tip = fwd.solve(q).tip_mm + 0.01 * rng.standard_normal(3)
        samples.append(idf.TipSample(q_act_mm=q, tip_mm=tip))
    ref = idf.ParamRef("segment", 0, "EI_Nmm2", lower=100.0, upper=1e5, log=True)
    start = idf.with_values(truth, [ref], [0.6 * true_EI])
    res = idf.fit(start, [ref], idf.tip_residuals(samples, eff))
    assert res.values[0] == pytest.approx(true_EI, rel=0.05)
    assert res.ci95[0, 0] < res.values[0] < res.ci95[0, 1]
