"""Virtual-work statics (Qi et al. 2023 eq. 7-15): hand values, coupling, gravity, pretension."""

from __future__ import annotations

import math

import numpy as np
import pytest
from cc_robots import central_diff, make_robot

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk import statics as st
from cdcr_ctl.model.cc_disk.kinematics import disk_positions, psi_to_x, x_to_psi
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.model.cc_disk.routing import cable_jacobian

PLAIN = Effects(disk_friction=False, pulley_friction=False, gravity=False)
PLAIN_G = Effects(disk_friction=False, pulley_friction=False, gravity=True)


def test_planar_bend_towards_one_cable_hand_values():
    p = make_robot(1)
    seg, r = p.segments[0], 4.0
    theta = 0.9
    T = st.solve_tensions([[theta, 0.0]], p, PLAIN)
    # tau_1 r = EI theta / l above its pretension; the others keep theirs (eq. 9-10)
    assert (T[0] - 2.0) * r == pytest.approx(seg.EI_Nmm2 * theta / seg.length_mm, rel=1e-12)
    assert T[1] == pytest.approx(2.0) and T[2] == pytest.approx(2.0)


def test_bend_between_two_cables_shares_the_moment():
    p = make_robot(1)
    seg = p.segments[0]
    theta = 0.7
    M = seg.EI_Nmm2 * theta / seg.length_mm
    T = st.solve_tensions([[theta, math.pi / 3]], p, PLAIN)  # midway between holes 0 and 120 deg
    # e_0 + e_120 = u(60 deg): both carry M/r above pretension
    assert T[0] - 2.0 == pytest.approx(M / 4.0, rel=1e-12)
    assert T[1] - 2.0 == pytest.approx(M / 4.0, rel=1e-12)
    assert T[2] == pytest.approx(2.0)


def test_straight_pose_keeps_pretension_despite_rank_loss():
    p = make_robot(3)
    T = st.solve_tensions(np.zeros((3, 2)), p, PLAIN)
    np.testing.assert_allclose(T, [c.pretension_N for c in p.cables], atol=1e-12)
    T_lp = st.solve_tensions_all_cables(np.zeros((3, 2)), p, PLAIN)
    np.testing.assert_allclose(T_lp, T, atol=1e-9)
    # unequal pretensions cannot all hold straight: the least-tensioned keeps its own
    p2 = make_robot(1, pretension_step_N=0.1)
    np.testing.assert_allclose(st.solve_tensions([[0.0, 0.0]], p2, PLAIN), [2.2] * 3, atol=1e-12)


@pytest.mark.parametrize("effects", [PLAIN, PLAIN_G])
def test_coupling_form_equals_all_cables_virtual_work_form(effects):
    p = make_robot(3)
    psi = np.array([[0.8, 0.4], [0.6, 2.2], [1.1, -0.9]])
    T = st.solve_tensions(psi, p, effects)  # back-substitution with coupling moments
    # eq. 9 for every segment at once with the full multi-segment J_qpsi
    rhs = st.elastic_gradient(psi, p)
    if effects.gravity:
        rhs = rhs - st.gravity_force(psi, p, "psi")
    np.testing.assert_allclose(cable_jacobian(psi, p).T @ T, rhs, atol=1e-10)
    # and the global linear programme picks the same tensions
    np.testing.assert_allclose(st.solve_tensions_all_cables(psi, p, effects), T, atol=1e-7)


def test_coupling_moment_is_the_distal_bend_moment_in_its_own_plane():
    p = make_robot(3)
    psi = np.array([[0.8, 0.4], [0.6, 2.2], [1.1, -0.9]])
    T = st.solve_tensions(psi, p, PLAIN)
    J = cable_jacobian(psi, p)
    for i in range(2):
        distal = [k for k, c in enumerate(p.cables) if c.segment > i]
        generalized = J[distal, 2 * i : 2 * i + 2].T @ T[distal]
        nxt = p.segments[i + 1]
        M = nxt.EI_Nmm2 * psi[i + 1, 0] / nxt.length_mm
        np.testing.assert_allclose(
            generalized, st.coupling_force(psi[i], psi[i + 1], M), atol=1e-10
        )
    # the printed [M, 0] holds only when both segments bend in one plane
    same = st.coupling_force([0.8, 0.4], [0.6, 0.4], 3.0)
    np.testing.assert_allclose(same, [3.0, 0.0], atol=1e-15)


def test_one_distal_cable_bends_a_uniform_robot_alone():
    # equal EI/l, equal curvature, one plane: the proximal cables stay at pretension
    p = make_robot(2, twist_rad=0.0)
    from dataclasses import replace

    segs = (p.segments[0], replace(p.segments[1], length_mm=90.0, EI_Nmm2=p.segments[0].EI_Nmm2))
    p = replace(p, segments=segs)
    T = st.solve_tensions([[0.7, 0.0], [0.7, 0.0]], p, PLAIN)
    np.testing.assert_allclose(T[:3], [2.0, 2.0, 2.0], atol=1e-12)
    assert T[3] > 2.0


def test_gravity_generalized_force_is_minus_potential_gradient():
    p = make_robot(2)
    lengths = p.lengths_mm
    n = [s.n_disks for s in p.segments]
    g = np.asarray(p.gravity_mm_s2) * st.G_MM_S2_TO_N
    mass = np.concatenate([[s.disk_mass_g] * s.n_disks for s in p.segments])

    def potential(psi_flat):
        pos = disk_positions(psi_flat.reshape(-1, 2), lengths, n)
        return np.array([-np.sum(mass[:, None] * pos * g)])

    for psi in (np.array([[0.8, 0.4], [0.6, 2.2]]), np.array([[0.3, 0.0], [1e-3, 1.0]])):
        Q = st.gravity_force(psi, p, "psi")
        np.testing.assert_allclose(Q, -central_diff(potential, psi.ravel())[0], atol=1e-8)
        Qx = st.gravity_force(psi, p, "x")

        def potx(v):
            return potential(x_to_psi(v.reshape(-1, 2)).ravel())

        np.testing.assert_allclose(Qx, -central_diff(potx, psi_to_x(psi).ravel())[0], atol=1e-8)


def test_gravity_switch():
    p = make_robot(1)
    psi = [[0.5, 1.0]]
    m_off = st.moment_demand(psi, p, PLAIN)
    m_on = st.moment_demand(psi, p, PLAIN_G)
    assert np.abs(m_on - m_off).max() > 1e-3
    np.testing.assert_allclose(m_off[0], p.segments[0].EI_Nmm2 / 90.0 * psi_to_x(psi)[0])


def test_pretension_rule_minimal_and_infeasible():
    A = 4.0 * np.array([[1.0, -0.5, -0.5], [0.0, math.sqrt(3) / 2, -math.sqrt(3) / 2]])
    T0 = np.array([2.0, 2.0, 2.0])
    T = st.pretension_tensions(A, [3.0, 1.0], T0)
    np.testing.assert_allclose(A @ T, [3.0, 1.0], atol=1e-12)
    assert np.all(T >= T0 - 1e-12) and np.isclose(T, T0).sum() == 1
    with pytest.raises(ModelError):
        st.pretension_tensions(A[:, :2], [-5.0, -5.0], T0[:2])


def test_moment_residual_zero_at_solution_with_friction():
    p = make_robot(2)
    psi = np.array([[0.8, 0.4], [0.6, 2.2]])
    s = np.array([1.0, -1.0, -1.0, 0.5, 1.0, -0.2])
    eff = Effects()
    T = st.solve_tensions(psi, p, eff, s)
    assert np.abs(st.moment_residual(psi, p, eff, T, s)).max() < 1e-10
    F = st.bend_factors(psi, p, s, eff)
    assert F[0, 0] > 1.0 and F[1, 0] < 1.0  # pulled: mean tension above the anchor tension
