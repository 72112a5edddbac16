"""The plain-float chain (transfer.py) equals the numpy reference implementation, piece by piece."""

from __future__ import annotations

import numpy as np
import pytest
from cc_robots import central_diff, make_robot, three_params

from cdcr_ctl.model.cc_disk import elongation as el
from cdcr_ctl.model.cc_disk import statics as st
from cdcr_ctl.model.cc_disk.kinematics import psi_to_x
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.model.cc_disk.routing import chord_displacement, wrap_angles
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer

POSES = [
    np.array([[0.9, 0.3], [0.7, 2.0], [1.1, -1.0]]),
    np.array([[0.0, 0.0], [0.4, 1.0], [0.0, 0.0]]),
    np.array([[1e-7, 0.3], [1.5, -2.5], [0.2, 0.2]]),
]
EFFECTS = [Effects(), Effects(coupling=False), Effects(disk_friction=False, gravity=False)]


@pytest.mark.parametrize("psi", POSES)
@pytest.mark.parametrize("effects", EFFECTS)
def test_fast_chain_equals_reference(psi, effects):
    p = make_robot(3)
    ft = ForceTransfer(p, effects)
    rng = np.random.default_rng(7)
    s = rng.uniform(-1, 1, p.n_cables)
    s[:3] = [1.0, -1.0, 0.0]
    xs = psi_to_x(psi).ravel().tolist()
    P = ft.pose(xs)
    np.testing.assert_allclose(P.m_req, st.moment_demand(psi, p, effects), atol=1e-12)
    Fb, _ = ft.factors(P, s.tolist())
    F_ref = st.bend_factors(psi, p, s, effects)
    for k, c in enumerate(p.cables):
        np.testing.assert_allclose(Fb[k], F_ref[k, : c.segment + 1], atol=1e-13)
    T = ft.statics(P, Fb)
    np.testing.assert_allclose(T, st.solve_tensions(psi, p, effects, s), atol=1e-11)
    res = ft.evaluate(xs, s.tolist())
    for k, c in enumerate(p.cables):
        trs = ft.pulleys(k)
        mu = c.mu_disk if effects.disk_friction else 0.0
        from dataclasses import replace

        pk = replace(p, cables=tuple(replace(cc, mu_disk=mu) for cc in p.cables))
        prof = el.cable_profile(psi, pk, k, T[k], s[k], trs)
        d_in, d_out = el.split_elongation(prof, c, s[k], trs)
        assert res.T_base[k] == pytest.approx(prof.T_base_N, rel=1e-12)
        assert res.T_actuator[k] == pytest.approx(prof.T_actuator_N, rel=1e-12)
        assert res.delta_in[k] == pytest.approx(d_in, abs=1e-13)
        assert res.delta_out[k] == pytest.approx(d_out, abs=1e-13)
        # summed wrap to the base = sum of the exact chord wrap angles
        assert P.Zb[c.segment] == pytest.approx(wrap_angles(psi, p, k).sum(), abs=1e-12)


@pytest.mark.parametrize("gravity", [(0.0, 0.0, -9810.0), (6000.0, -3000.0, -7000.0)])
def test_fast_weights_equal_reference_for_any_gravity_direction(gravity):
    from dataclasses import replace

    p = replace(make_robot(3), gravity_mm_s2=gravity)
    ft = ForceTransfer(p, Effects())
    for psi in POSES:
        P = ft.pose(psi_to_x(psi).ravel().tolist())
        np.testing.assert_allclose(P.m_req, st.moment_demand(psi, p, Effects()), atol=1e-12)


@pytest.mark.parametrize("thickness", [0.0, 1.5])
def test_chord_geometry_and_its_moment_arms(thickness):
    p = make_robot(2, thickness_mm=thickness)
    ft = ForceTransfer(p, Effects(geometry="chord"))
    for psi in (np.array([[0.9, 0.3], [0.7, 2.0]]), np.array([[1e-4, 0.3], [0.5, -1.0]])):
        x0 = psi_to_x(psi).ravel()
        P = ft.pose(x0.tolist())
        for k in range(p.n_cables):
            assert P.q_geom[k] == pytest.approx(chord_displacement(psi, p, k), abs=1e-11)
            J = central_diff(lambda v, k=k: [ft.pose(v.tolist()).q_geom[k]], x0, h=1e-5)[0]
            arms = np.concatenate(P.arm[k])
            np.testing.assert_allclose(arms, J[: arms.size], atol=2e-6)


def test_straight_pretensioned_reference_has_no_elongation():
    p = three_params()
    ft = ForceTransfer(p, Effects())
    res = ft.evaluate([0.0] * 6, [0.0] * 9)
    np.testing.assert_allclose(res.T_distal, [2.0] * 9, atol=1e-12)
    np.testing.assert_allclose(res.q, 0.0, atol=1e-12)
