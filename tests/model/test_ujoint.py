"""Universal-joint arm (Yang et al. 2022): eq. 3-17 against geometry built with scipy, limits and
the paper's numbers; truth and compensation round trips; the yang2022.yaml draft config."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cdcr_ctl.config.designs import check_design, ujoint_arm
from cdcr_ctl.config.loader import cross_check, load_yaml_model
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import ConfigError, ModelError
from cdcr_ctl.model import ujoint as uj

CONFIG = Path(__file__).resolve().parents[2] / "config" / "yang2022.yaml"
STEEL_1_2_EA = 70000.0 * math.pi * 1.2**2 / 4.0  # N, the config's effective modulus


@pytest.fixture(scope="module")
def cfg():
    return load_yaml_model(CONFIG, RigConfig)


@pytest.fixture(scope="module")
def arm(cfg):
    return ujoint_arm(cfg, str(CONFIG))


def light_arm(arm, gravity=(-9810.0, 0.0, 0.0), n_seg=2):
    """The paper's arm with light links under gravity, so the pretension holds it (statics)."""
    segs = tuple(replace(s, link_mass_g=15.0) for s in arm.segments)
    cables = arm.cables
    if n_seg == 3:
        segs = (*segs, replace(segs[0], name="seg3", n_subjoints=4))
        extra = tuple(
            uj.UJointCable(
                f"c3{j}", 2, 0.5 + j * 2 * math.pi / 3, 38.0, STEEL_1_2_EA, 1700.0, 100.0
            )
            for j in range(3)
        )
        cables = (*cables, *extra)
    return replace(arm, segments=segs, cables=cables, tip_mass_g=20.0, gravity_mm_s2=gravity)


def rot(axis, angle):
    return Rotation.from_rotvec(np.asarray(axis, dtype=float) * angle)


# --------------------------------------------------------------------------- eq. 4-6
ANGLES = [(0.0, 0.0), (0.1, 0.0), (0.0, -0.2), (0.3, 0.25), (-0.4, 0.7), (1.2, -0.9), (1e-8, 2e-8)]


@pytest.mark.parametrize(("psi_I", "psi_J"), ANGLES)
def test_eq4_equals_hole_to_hole_distance(psi_I, psi_J):
    d, rho = 20.0, 38.0
    betas = np.linspace(0.0, 2 * math.pi, 13)
    R = (rot([1, 0, 0], psi_I) * rot([0, 1, 0], psi_J)).as_matrix()  # Rx then Ry (intrinsic)
    for beta in betas:
        h = np.array([rho * math.cos(beta), rho * math.sin(beta)])
        lower = np.array([*h, -d])  # disk D1, joint centre at the origin
        upper = R @ np.array([*h, d])  # disk D2 after the two rotations
        expected = np.linalg.norm(upper - lower)
        assert uj.subjoint_cable_length(psi_I, psi_J, beta, rho, d) == pytest.approx(
            expected, rel=1e-14, abs=1e-12
        )
    assert uj.subjoint_cable_length(0.0, 0.0, betas, rho, d) == pytest.approx(2 * d)


@pytest.mark.parametrize(("psi_I", "psi_J"), ANGLES)
def test_eq4_gradient_matches_central_differences(psi_I, psi_J):
    d, rho, beta = 20.0, 38.0, np.array([0.3, 2.0, 4.4])
    f, ga, gb = uj.subjoint_cable_length_grad(psi_I, psi_J, beta, rho, d)
    h = 1e-6
    fa = (
        uj.subjoint_cable_length(psi_I + h, psi_J, beta, rho, d)
        - uj.subjoint_cable_length(psi_I - h, psi_J, beta, rho, d)
    ) / (2 * h)
    fb = (
        uj.subjoint_cable_length(psi_I, psi_J + h, beta, rho, d)
        - uj.subjoint_cable_length(psi_I, psi_J - h, beta, rho, d)
    ) / (2 * h)
    np.testing.assert_allclose(ga, fa, atol=1e-7)
    np.testing.assert_allclose(gb, fb, atol=1e-7)
    np.testing.assert_allclose(f, uj.subjoint_cable_length(psi_I, psi_J, beta, rho, d))


def test_eq9_jacobian_at_straight_pose_is_hole_moment_arm():
    beta = np.array([0.0, 2 * math.pi / 3, 4 * math.pi / 3])
    _, J = uj.segment_cable_jacobian(0.0, 0.0, beta, 38.0, 20.0, 6)
    np.testing.assert_allclose(
        J, 6 * 38.0 * np.column_stack((np.sin(beta), -np.cos(beta))), atol=1e-12
    )


def test_eq6_alternates_first_axis_and_eq5_sums_a_uniform_bend():
    psi = uj.subjoint_angles(0.1, -0.2, 5)
    np.testing.assert_allclose(psi[:, 0], [0.1, -0.1, 0.1, -0.1, 0.1])
    np.testing.assert_allclose(psi[:, 1], -0.2)
    # eq. 6 inverted: theta_{2n-1} = (-1)^(i+1) psi_I for every i
    np.testing.assert_allclose(uj.first_axis_signs(5) * psi[:, 0], 0.1)
    # the physical chain: sub-joint i turns by psi_I about its first axis xi_I = (-1)^(i+1) x
    d, rho, m = 20.0, 38.0, 4
    beta = np.array([0.2, 2.3, 4.1])
    psi = uj.subjoint_angles(0.15, -0.1, m)
    total = np.zeros(3)
    for i in range(m):
        xi_I = np.array([uj.first_axis_signs(m)[i], 0.0, 0.0])
        R = (rot(xi_I, psi[i, 0]) * rot([0, 1, 0], psi[i, 1])).as_matrix()
        for k, b in enumerate(beta):
            h = np.array([rho * math.cos(b), rho * math.sin(b)])
            total[k] += np.linalg.norm(R @ np.array([*h, d]) - np.array([*h, -d]))
    np.testing.assert_allclose(
        uj.segment_cable_lengths(0.15, -0.1, beta, rho, d, m), total, rtol=1e-14
    )


def test_literal_alternation_would_leave_first_axis_unsteerable():
    """Why eq. 6 is a frame convention: eq. 4 fed the alternating psi_I directly (same hole frames)
    gives cable lengths with zero slope in theta_{2n-1} at the straight pose for even M."""
    beta, rho, d, m, h = np.array([0.0, 2.1, 4.2]), 38.0, 20.0, 6, 1e-6

    def literal(t):
        return sum(
            uj.subjoint_cable_length(s * t, 0.0, beta, rho, d) for s in uj.first_axis_signs(m)
        )

    slope = (literal(h) - literal(-h)) / (2 * h)
    np.testing.assert_allclose(slope, 0.0, atol=1e-6)
    _, J = uj.segment_cable_jacobian(0.0, 0.0, beta, rho, d, m)
    assert np.abs(J[:, 0]).max() > 100.0  # the physical reading: full first-order sensitivity


# --------------------------------------------------------------------------- eq. 1-2
def test_segment_transform_is_chain_of_subjoints(arm):
    seg = arm.segments[0]
    a, b = 0.12, -0.07
    R_sub = (rot([1, 0, 0], a) * rot([0, 1, 0], b)).as_matrix()
    T = np.eye(4)
    for _ in range(seg.n_subjoints):
        step = np.eye(4)
        step[:3, :3] = R_sub
        step[:3, 3] = [0, 0, seg.half_gap_mm] + R_sub @ [0, 0, seg.half_gap_mm + seg.link_mm]
        T = T @ step
    np.testing.assert_allclose(uj.segment_transform(a, b, seg), T, atol=1e-12)
    straight = uj.tip_transform(arm, np.zeros((2, 2)))
    np.testing.assert_allclose(straight[:3, 3], [0, 0, 1110.0])  # paper: 1110 mm arm


def test_planar_bend_tip_follows_polygon(arm):
    # theta_2n only: every sub-joint turns by b about y; joint centres lie on a polygon
    b = math.radians(6.0)  # the paper's simulation angle
    theta = np.array([[0.0, b], [0.0, b]])
    T = uj.tip_transform(arm, theta)
    n_total = sum(s.n_subjoints for s in arm.segments)
    np.testing.assert_allclose(T[:3, :3], rot([0, 1, 0], n_total * b).as_matrix(), atol=1e-12)
    assert T[1, 3] == pytest.approx(0.0, abs=1e-9)
    # whole-arm bend 12 x 6 deg = 72 deg (paper section 4.3)
    assert math.degrees(math.atan2(T[0, 2], T[2, 2])) == pytest.approx(72.0)


# --------------------------------------------------------------------------- eq. 7-12
def random_angles(rng, n_seg, scale=0.15):
    return rng.uniform(-scale, scale, size=(n_seg, 2))


@pytest.mark.parametrize("n_seg", [2, 3])
def test_forward_inverse_round_trip(arm, n_seg):
    a = light_arm(arm, n_seg=n_seg)
    rng = np.random.default_rng(7)
    cases = [np.zeros((n_seg, 2)), np.full((n_seg, 2), 1e-9)]
    cases += [random_angles(rng, n_seg) for _ in range(20)]
    for theta in cases:
        q = uj.cable_displacements(a, theta)
        back = uj.angles_from_displacements(a, q)
        np.testing.assert_allclose(back, theta, atol=1e-10)  # acceptance: 1e-6 rad


def test_eq11_distal_cables_pass_proximal_segment(arm):
    theta = np.array([[0.1, -0.05], [0.0, 0.0]])
    q = uj.cable_displacements(arm, theta)
    distal = arm.anchor == 1
    assert np.all(np.abs(q[distal]) > 1.0)  # segment 2's cables change though it is straight
    # eq. 11: the distal cable's change is its length change inside segment 1
    seg = arm.segments[0]
    inside = uj.segment_cable_lengths(
        0.1, -0.05, arm.betas[distal], arm.rhos[distal], seg.half_gap_mm, seg.n_subjoints
    )
    np.testing.assert_allclose(q[distal], seg.straight_gap_length_mm - inside, rtol=1e-14)
    np.testing.assert_allclose(uj.angles_from_displacements(arm, q), theta, atol=1e-12)


def test_eq10_least_squares_for_inconsistent_lengths(arm):
    seg = arm.segments[0]
    own = arm.own_cables[0]
    beta, rho = arm.betas[own], arm.rhos[own]
    theta = np.array([0.08, -0.03])
    L = uj.segment_cable_lengths(*theta, beta, rho, seg.half_gap_mm, seg.n_subjoints)
    L_bad = L + np.array([0.2, -0.1, 0.05])
    sol = uj.solve_segment_angles(L_bad, beta, rho, seg.half_gap_mm, seg.n_subjoints)
    f, J = uj.segment_cable_jacobian(*sol, beta, rho, seg.half_gap_mm, seg.n_subjoints)
    np.testing.assert_allclose(J.T @ (L_bad - f), 0.0, atol=1e-9)  # normal equations
    with pytest.raises(ModelError):
        uj.solve_segment_angles(L + 500.0, beta, rho, seg.half_gap_mm, seg.n_subjoints)


def test_cable_jacobian_matches_differences(arm):
    theta = np.array([[0.05, -0.1], [0.12, 0.02]])
    J = uj.cable_jacobian(arm, theta)
    h = 1e-6
    for j in range(4):
        tp, tm = theta.ravel().copy(), theta.ravel().copy()
        tp[j] += h
        tm[j] -= h
        col = (
            uj.cable_path_lengths(arm, tp.reshape(2, 2))
            - uj.cable_path_lengths(arm, tm.reshape(2, 2))
        ) / (2 * h)
        np.testing.assert_allclose(J[:, j], col, atol=1e-6)
    assert np.all(J[arm.anchor == 0][:, 2:] == 0.0)  # proximal cables do not see segment 2


# --------------------------------------------------------------------------- eq. 3
def test_eq3_lead_screw_with_moving_pulley():
    one_turn = 2 * math.pi
    red = uj.LeadScrewDrive(lead_mm=4.0, gear_ratio=14.0, gear_ratio_kind="reduction")
    mul = uj.LeadScrewDrive(lead_mm=4.0, gear_ratio=14.0, gear_ratio_kind="multiplier")
    unit = uj.LeadScrewDrive(lead_mm=4.0)
    assert float(red.cable_from_motor(one_turn)) == pytest.approx(2 * 4.0 / 14.0)
    assert float(mul.cable_from_motor(one_turn)) == pytest.approx(2 * 4.0 * 14.0)
    assert unit.cable_mm_per_motor_rad == pytest.approx(4.0 / math.pi)  # eq. 3: S / pi
    assert float(red.motor_from_cable(red.cable_from_motor(1.234))) == pytest.approx(1.234)
    assert red.counts_per_mm(4096) == pytest.approx(7168.0)
    with pytest.raises(ModelError):
        uj.LeadScrewDrive(lead_mm=4.0, gear_ratio_kind="divide")


# --------------------------------------------------------------------------- dead zone
def test_dead_zone_reproduces_paper_3_4mm_at_100N_and_is_linear(arm):
    kappa = arm.friction_exponent_per_mm  # fitted at load time from the config's calibration
    w100 = uj.dead_zone_width_mm(100.0, 2877.0, STEEL_1_2_EA, kappa)
    assert w100 == pytest.approx(3.4, rel=1e-9)
    for T0 in (20.0, 50.0, 0.0, 137.5):
        assert uj.dead_zone_width_mm(T0, 2877.0, STEEL_1_2_EA, kappa) == pytest.approx(
            3.4 * T0 / 100.0, rel=1e-12, abs=1e-15
        )
    assert uj.calibrate_friction_exponent(3.4, 100.0, 2877.0, STEEL_1_2_EA) == pytest.approx(kappa)


def test_dead_zone_is_the_stretch_difference_of_the_friction_profiles():
    T0, L, EA, kappa = 80.0, 1500.0, 5.0e4, 4e-4
    s = np.linspace(0.0, L, 200001)
    pull = np.trapezoid(T0 * np.exp(kappa * (L - s)) - T0, s) / EA
    release = np.trapezoid(T0 - T0 * np.exp(-kappa * (L - s)), s) / EA
    p, r = uj.dead_zone_mm(T0, L, EA, kappa)
    assert p == pytest.approx(pull, rel=1e-9)
    assert r == pytest.approx(release, rel=1e-9)
    # limits: no friction or a rigid cable -> no dead zone; small kappa -> T0 kappa L^2 / EA
    assert uj.dead_zone_width_mm(T0, L, EA, 0.0) == 0.0
    assert uj.dead_zone_width_mm(T0, L, 1e18, kappa) == pytest.approx(0.0, abs=1e-12)
    small = 1e-9
    assert uj.dead_zone_width_mm(T0, L, EA, small) == pytest.approx(
        T0 * small * L * L / EA, rel=1e-6
    )
    # the series branch joins the closed form
    x_edge = 1e-5 / L
    a = uj.dead_zone_mm(T0, L, EA, x_edge * (1 - 1e-9))
    b = uj.dead_zone_mm(T0, L, EA, x_edge * (1 + 1e-9))
    np.testing.assert_allclose(a, b, rtol=1e-6)


def test_play_operator_sticks_for_the_dead_zone_at_reversal():
    pull, release = np.array([0.3]), np.array([0.2])
    q_out = np.zeros(1)
    outs = []
    path = np.concatenate((np.linspace(0.0, 2.0, 201), np.linspace(2.0, 0.0, 201)[1:]))
    for q in path:
        q_out = uj.play_update(q_out, np.array([q]), pull, release)
        outs.append(q_out[0])
    outs = np.array(outs)
    # start from the centred state: the output moves after e_p; then trails by e_p
    assert outs[20] == pytest.approx(0.0) and outs[40] == pytest.approx(0.1)
    assert outs[200] == pytest.approx(2.0 - 0.3)
    # after the reversal it stands still until the input has come back by w = 0.5 mm
    back = path[200:] - 2.0
    stuck = outs[200:][back > -0.5 + 1e-9]
    np.testing.assert_allclose(stuck, 1.7)
    assert outs[-1] == pytest.approx(0.0 + 0.2)
    # the inverse: commanding q_out + e_p / - e_r moving gives exactly q_out
    q_out = np.zeros(1)
    desired = np.concatenate((np.linspace(0, 1, 11), np.linspace(1, -1, 21)[1:]))
    last = np.zeros(1)
    prev = None
    for qd in desired:
        direction = uj.motion_direction(np.array([qd]), prev, last, True, 1e-12)
        q_out = uj.play_update(
            q_out, uj.play_inverse(np.array([qd]), direction, pull, release), pull, release
        )
        assert q_out[0] == pytest.approx(qd, abs=1e-12)
        prev, last = np.array([qd]), direction


def test_truth_dead_zone_holds_the_pose_at_reversal(arm):
    eff = uj.UJointEffects(dead_zone=True, deformation=False, statics=False)
    state = None
    # pull segment 1's first cable in and release it again, others fixed (least squares pose)
    up = np.linspace(0.0, 3.0, 61)
    down = np.linspace(3.0, 2.0, 41)[1:]
    thetas = []
    for v in np.concatenate((up, down)):
        q = np.zeros(arm.n_cables)
        q[0] = v
        th, state = uj.truth_angles(arm, q, state, eff)
        thetas.append(th.copy())
    thetas = np.array(thetas)
    w = sum(x[0] for x in arm.dead_zones_mm)
    at_top = thetas[60]
    back = 3.0 - down
    hold = thetas[61:][back < w - 1e-9]
    assert len(hold) > 0
    np.testing.assert_allclose(hold, np.broadcast_to(at_top, hold.shape), atol=1e-12)
    assert not np.allclose(thetas[-1], at_top)  # released beyond the dead zone: it moves


# --------------------------------------------------------------------------- eq. 14-17
def test_deformation_sign_follows_eq14_to_17(arm):
    theta = np.array([[0.05, -0.08], [0.0, 0.0]])
    eta = arm.deformation.eta
    moving = np.array([[0.0, 0.0], [1.0, 1.0]])
    d = uj.deformation_rad(arm, theta, moving)
    # theta_1 > 0 with theta_dot_3 > 0: eq. 14 and 16-17 agree, +eta theta_1
    assert d[0, 0] == pytest.approx(eta * 0.05)
    # theta_2 < 0: eq. 16 literally, eta theta_2 with eta < 0 (theta_dot_4 theta_2 < 0),
    # = +eta |theta_2|: the deformation follows the distal motion
    assert d[0, 1] == pytest.approx(eta * 0.08)
    np.testing.assert_allclose(d[1], 0.0)  # nothing drives through the distal segment
    # mirror symmetry: flip every angle and velocity, the deformation flips
    np.testing.assert_allclose(uj.deformation_rad(arm, -theta, -moving), -d)
    np.testing.assert_allclose(uj.deformation_rad(arm, theta, np.zeros((2, 2))), 0.0)  # stopped
    np.testing.assert_allclose(uj.deformation_rad(arm, np.zeros((2, 2)), moving), 0.0)
    # eq. 14 (torque form): tau_f,m / k_n with the same signs
    tq = replace(
        arm,
        deformation=uj.DeformationParams(
            kind="torque", friction_torque_Nmm=(0.0, 500.0), stiffness_Nmm_per_rad=(1e5, 1e5)
        ),
    )
    d = uj.deformation_rad(tq, theta, np.array([[0.0, 0.0], [1.0, -1.0]]))
    np.testing.assert_allclose(d[0], [500.0 / 1e5, -500.0 / 1e5])
    for model in (arm, tq):
        for dirs in ([1.0, -1.0], [-1.0, 1.0], [1.0, 1.0]):
            direction = np.array([[0.0, 0.0], dirs])
            back = uj.undeform(
                model, theta + uj.deformation_rad(model, theta, direction), direction
            )
            np.testing.assert_allclose(back, theta, atol=1e-15)


def test_truth_deformation_makes_go_and_return_differ(arm):
    eff = uj.UJointEffects(dead_zone=False, deformation=True, statics=False)
    b = np.linspace(0.0, math.radians(6.0), 31)
    path = np.concatenate((b, b[::-1][1:]))
    state, out = None, []
    for v in path:
        th_d = np.array([[0.0, v], [0.0, v]])
        th, state = uj.truth_angles(arm, uj.cable_displacements(arm, th_d), state, eff)
        out.append(th)
    out = np.array(out)
    go, ret = out[15], out[-16]  # the same desired pose (3 deg) on the way out and back
    eta = arm.deformation.eta
    assert go[0, 1] == pytest.approx((1 + eta) * path[15], rel=1e-9)  # theta_dot_2 * theta_1 > 0
    assert ret[0, 1] == pytest.approx((1 - eta) * path[15], rel=1e-9)
    # the distal segment runs through the deformed proximal one: its angle changes too
    assert abs(go[1, 1] - path[15]) > 1e-4 and abs(ret[1, 1] - path[15]) > 1e-4
    assert np.linalg.norm(uj.tip_position(arm, go) - uj.tip_position(arm, ret)) > 10.0
    hold = replace(arm, deformation=replace(arm.deformation, hold_when_stopped=True))
    th_stop = np.array([[0.0, 0.05], [0.0, 0.05]])
    q = uj.cable_displacements(arm, th_stop)
    s_paper, s_hold = None, None
    for qq in (0.5 * q, q, q):  # moving, then standing still
        th_p, s_paper = uj.truth_angles(arm, qq, s_paper, eff)
        th_h, s_hold = uj.truth_angles(hold, qq, s_hold, eff)
    assert th_p[0, 1] == pytest.approx(0.05, rel=1e-9)  # eq. 17: eta = 0 when stopped
    assert th_h[0, 1] == pytest.approx(0.05 * (1 + eta), rel=1e-9)


def test_linearised_errors_eq13_eq15_predict_truth(arm):
    theta = np.array([[0.03, 0.06], [-0.02, 0.05]])
    q = uj.cable_displacements(arm, theta)
    dq = np.array([0.004, -0.002, 0.003, -0.001, 0.002, 0.0005])  # small output errors (mm)
    truth = uj.angles_from_displacements(arm, q + dq)
    pred = uj.linearised_angle_error(arm, theta, dq)
    np.testing.assert_allclose(truth - theta, pred, atol=1e-8, rtol=1e-3)


# --------------------------------------------------------------------------- statics
def test_statics_sags_along_gravity_and_balances(arm):
    a = light_arm(arm)  # horizontal arm, gravity along -x
    theta0 = np.zeros((2, 2))
    theta, T = uj.statics_angles(a, theta0)
    tip0, tip = uj.tip_position(a, theta0), uj.tip_position(a, theta)
    assert tip[0] < tip0[0] - 1.0  # sags down
    assert abs(tip[1]) < 1e-9  # gravity in the x-z plane: no sideways motion
    assert np.all(T >= 0.0)
    # equilibrium (linearised cables): J^T T + K_g dtheta = Q at the sagged pose
    J = uj.cable_jacobian(a, theta0)
    Q = uj.gravity_torque(a, theta)
    dtheta = (theta - theta0).ravel()
    Kg = np.zeros((4, 4))
    h = 1e-6
    for j in range(4):
        tp, tm = theta0.ravel().copy(), theta0.ravel().copy()
        tp[j] += h
        tm[j] -= h
        Kg[:, j] = (
            a.pretension_N
            @ (uj.cable_jacobian(a, tp.reshape(2, 2)) - uj.cable_jacobian(a, tm.reshape(2, 2)))
            / (2 * h)
        )
    np.testing.assert_allclose(J.T @ T + Kg @ dtheta, Q, atol=1e-5 * np.abs(Q).max())
    # no gravity, no pretension: the kinematic pose stands
    bare = replace(
        a,
        gravity_mm_s2=(0.0, 0.0, 0.0),
        cables=tuple(replace(c, pretension_N=0.0) for c in a.cables),
    )
    np.testing.assert_allclose(
        uj.statics_angles(bare, np.array([[0.1, 0.0], [0.0, -0.1]]))[0],
        [[0.1, 0.0], [0.0, -0.1]],
        atol=1e-15,
    )


def test_gravity_potential_batch_matches_mass_points(arm):
    a = light_arm(arm)
    theta = np.array([[0.1, -0.2], [0.05, 0.3]])
    pts, ms = uj.mass_points(a, theta)
    V = -np.sum(ms * 1e-6 * (pts @ np.array(a.gravity_mm_s2)))
    assert uj.gravity_potential_Nmm(a, theta) == pytest.approx(V, rel=1e-12)


def test_statics_heavy_cantilever_and_an_arm_it_cannot_hold(arm):
    heavy = replace(arm, gravity_mm_s2=(-9810.0, 0.0, 0.0))  # the config's links, horizontal
    theta, T = uj.statics_angles(heavy, np.zeros((2, 2)))
    assert uj.tip_position(heavy, theta)[0] < -10.0  # sags by centimetres
    assert T.max() > 150.0 and np.all(T >= 0.0)  # the upper cables carry the weight
    # without pretension the lower cables go slack and one cable cannot hold two axes
    loose = replace(heavy, cables=tuple(replace(c, pretension_N=0.0) for c in arm.cables))
    with pytest.raises(ModelError, match="no stable equilibrium"):
        uj.statics_angles(loose, np.zeros((2, 2)))


# --------------------------------------------------------------------------- compensation
def trajectory(n_seg):
    """Out to 6 deg on theta_2n and back, with a sideways excursion on theta_2n-1."""
    s = np.concatenate((np.linspace(0, 1, 21), np.linspace(1, 0, 21)[1:]))
    th = np.zeros((s.size, n_seg, 2))
    th[:, :, 1] = math.radians(6.0) * s[:, None]
    th[:, :, 0] = 0.02 * np.sin(math.pi * s)[:, None]
    return th


@pytest.mark.parametrize("n_seg", [2, 3])
def test_compensation_inverts_truth(arm, n_seg):
    a = light_arm(arm, n_seg=n_seg)
    eff = uj.UJointEffects()
    th_d = trajectory(n_seg)
    t_state = c_state = None
    raw_state = None
    errs, raw_errs = [], []
    for td in th_d:
        q_in, c_state = uj.compensate(a, td, c_state, eff)
        th, t_state = uj.truth_angles(a, q_in, t_state, eff)
        raw, raw_state = uj.truth_angles(a, uj.cable_displacements(a, td), raw_state, eff)
        errs.append(np.abs(th - td).max())
        raw_errs.append(np.abs(raw - td).max())
    # exact along the whole out-and-back path, reversals of theta_2n-1 and theta_2n included
    assert max(errs) < 1e-8
    assert max(raw_errs) > 1e-3  # the uncompensated arm is off by milliradians


def test_compensation_without_effects_is_ideal_inverse_kinematics(arm):
    eff = uj.UJointEffects(dead_zone=False, deformation=False, statics=False)
    td = np.array([[0.02, 0.08], [-0.04, 0.01]])
    q, _ = uj.compensate(arm, td, None, eff)
    np.testing.assert_allclose(q, uj.cable_displacements(arm, td), atol=1e-13)


def test_loop_psi_is_subjoint_tilt_and_direction():
    # the loop's rows (tilt, phi) <-> Rx(a) Ry(b): the tilted axis is Rx(a) Ry(b) e_z
    rng = np.random.default_rng(3)
    psi = np.column_stack((rng.uniform(0.0, 1.2, 20), rng.uniform(-math.pi, math.pi, 20)))
    ab = uj.joint_angles_from_psi(psi)
    for (t, phi), (a, b) in zip(psi, ab, strict=True):
        z = (rot([1, 0, 0], a) * rot([0, 1, 0], b)).apply([0.0, 0.0, 1.0])
        np.testing.assert_allclose(
            z, [math.sin(t) * math.cos(phi), math.sin(t) * math.sin(phi), math.cos(t)], atol=1e-12
        )
    np.testing.assert_allclose(uj.psi_from_joint_angles(ab), psi, atol=1e-12)
    # Yang's [0, 6 deg] is a 6 deg tilt towards x
    np.testing.assert_allclose(
        uj.joint_angles_from_psi(np.array([[math.radians(6), 0.0]])),
        [[0.0, math.radians(6)]],
        atol=1e-15,
    )


def test_loop_adapter_modes(arm):
    model = uj.UJointModel(arm)
    state = model.new_state()
    psi = uj.psi_from_joint_angles(np.array([[0.0, 0.01], [0.0, 0.02]]))
    q_nom = model.q_nominal(psi)
    np.testing.assert_allclose(model.q_command(psi, q_nom, state, "off", None), q_nom)
    psi2 = psi * [2.0, 1.0]
    q_cmd = model.q_command(psi2, model.q_nominal(psi2), state, "model", None)
    pull, _ = arm.dead_zones_mm
    moved = np.abs(model.q_nominal(psi2) - q_nom) > 1e-9
    assert np.all(np.abs(q_cmd - model.q_nominal(psi2))[moved] >= pull.min() * 0.5)
    np.testing.assert_allclose(model.tip(np.zeros((2, 2))), [0, 0, 1110.0])
    with pytest.raises(ModelError):
        model.q_command(psi, q_nom, state, "measured", None)


def test_loop_adapter_one_statics_evaluation_per_tick_tracks_truth(arm):
    a = light_arm(arm)  # horizontal, with gravity: the statics compensation matters
    model = uj.UJointModel(a)
    state = model.new_state()
    t_state = None
    s = np.linspace(0.0, 1.0, 151)  # 1 ms ticks of a 0.15 s move
    errs = []
    for v in s:
        theta = np.array([[0.01 * v, 0.05 * v], [-0.02 * v, 0.08 * v]])
        psi = uj.psi_from_joint_angles(theta)
        q = model.q_command(psi, model.q_nominal(psi), state, "model", None)
        th, t_state = uj.truth_angles(a, q, t_state)
        errs.append(np.abs(th - theta).max())
    assert max(errs) < 1e-7  # one warm-started statics evaluation per tick suffices


# --------------------------------------------------------------------------- config
def test_yang2022_config_builds_the_papers_arm(cfg, arm):
    assert cross_check(cfg) == [] and check_design(cfg) == []
    assert [s.n_subjoints for s in arm.segments] == [6, 6]
    assert [c.total_length_mm for c in arm.cables] == [780.0] * 3 + [1290.0] * 3  # paper
    assert arm.segments[0].link_mm == pytest.approx(45.0)
    assert arm.drive.counts_per_mm(cfg.ujoint.drive.encoder_counts_per_rev) == pytest.approx(
        cfg.drives[0].counts_per_mm
    )


def test_design_sections_are_checked(cfg):
    data = cfg.model_dump()
    with pytest.raises(ValueError, match="needs a 'ujoint:' section"):
        RigConfig.model_validate({**data, "ujoint": None})
    with pytest.raises(ValueError, match="only for design ujoint"):
        RigConfig.model_validate({**data, "design": "cc_disk"})
    bad = RigConfig.model_validate(
        {**data, "drives": [{**d, "counts_per_mm": 1000.0} for d in data["drives"]]}
    )
    problems = check_design(bad)
    assert len(problems) == 6 and problems[0][0] == ("drives", 0, "counts_per_mm")
    with pytest.raises(ConfigError, match="counts_per_mm"):
        ujoint_arm(bad)
    short = {**data, "ujoint": {**data["ujoint"], "half_gap_mm": 50.0}}
    assert check_design(RigConfig.model_validate(short))[0][0] == (
        "robot",
        "segments",
        0,
        "length_mm",
    )
