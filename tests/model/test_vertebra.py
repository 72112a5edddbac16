"""Vertebra arm (fuel-tank paper): eq. 1-9 against geometry and rotations built with scipy, the
yaw-free attitude decode, the end-following planner, truth statics; the vertebra.yaml draft."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cdcr_ctl.config.designs import (
    check_design,
    follow_params,
    sensor_mounts,
    vertebra_arm,
)
from cdcr_ctl.config.loader import cross_check, load_yaml_model
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import ModelError
from cdcr_ctl.model import vertebra as vt

CONFIG = Path(__file__).resolve().parents[2] / "config" / "vertebra.yaml"


@pytest.fixture(scope="module")
def cfg():
    return load_yaml_model(CONFIG, RigConfig)


@pytest.fixture(scope="module")
def arm(cfg):
    return vertebra_arm(cfg, str(CONFIG))


def joint_rot(theta, phi):
    """Eq. 1 with scipy: Rz(phi) Ry(theta) Rz(-phi) (intrinsic Z-Y-Z)."""
    return Rotation.from_euler("ZYZ", [phi, theta, -phi])


# --------------------------------------------------------------------------- eq. 1-2
@pytest.mark.parametrize(("theta", "phi"), [(0.0, 0.3), (0.7, -2.0), (2.5, 1.0), (1e-8, 0.5)])
def test_eq1_rotation_and_chain(arm, theta, phi):
    np.testing.assert_allclose(
        vt.joint_rotation(theta, phi), joint_rot(theta, phi).as_matrix(), atol=1e-15
    )
    j = arm.joints[0]
    T = vt.joint_transform(theta, phi, j)
    np.testing.assert_allclose(T[:3, :3], joint_rot(theta, phi).as_matrix(), atol=1e-12)
    # the vertebra polygon tends to eq. 1's arc: chord error O(1/n^2)
    fine = replace(j, n_gaps=400, gap_mm=j.length_mm / 400 - 0.0, hole_length_mm=0.0)
    arc = vt.arc_transform(theta, phi, j.length_mm)
    assert np.linalg.norm(vt.joint_transform(theta, phi, fine)[:3, 3] - arc[:3, 3]) < 1e-3
    coarse_err = np.linalg.norm(T[:3, 3] - arc[:3, 3])
    assert coarse_err < 0.02 * j.length_mm * max(theta, 1e-9) ** 2 + 1e-6


def test_straight_tip_at_660mm(arm):
    np.testing.assert_allclose(vt.tip_position(arm, np.zeros((3, 2))), [0, 0, 660.0], atol=1e-12)


# --------------------------------------------------------------------------- eq. 3-5
@pytest.mark.parametrize(("theta", "phi"), [(0.0, 0.0), (0.4, 0.3), (1.5, -2.2), (3.0, 1.7)])
def test_eq3_equals_hole_to_hole_distances_with_d_the_diameter(arm, theta, phi):
    j = arm.joints[0]
    n, l0, H, r = j.n_gaps, j.gap_mm, j.hole_length_mm, 15.0
    R_gap = joint_rot(theta / n, phi).as_matrix()  # each ball joint turns by theta/n
    for beta in np.linspace(0.0, 2 * math.pi, 7):
        h = np.array([r * math.cos(beta), r * math.sin(beta)])
        lower = np.array([*h, -l0 / 2])  # exit of the lower disk's hole, ball centre at 0
        upper = R_gap @ np.array([*h, l0 / 2])  # entry of the upper disk's hole
        gap = np.linalg.norm(upper - lower)
        expected = n * (H + gap)
        assert vt.joint_cable_length(theta, phi, beta, r, j) == pytest.approx(expected, rel=1e-13)
        # with d read as the radius eq. 3 would be wrong whenever the joint bends
        wrong = n * (
            H
            + l0 * math.cos(theta / (2 * n))
            - r * math.sin(theta / (2 * n)) * math.cos(phi - beta)
        )
        if theta > 0.1 and abs(math.cos(phi - beta)) > 0.1:
            assert abs(wrong - expected) > 1e-3


def test_eq3_paper_sign_is_clockwise_hole_numbering(arm):
    j = arm.joints[0]
    alpha, theta, phi, r = 2 * math.pi / 3, 0.9, 0.4, 15.0
    for jj in (1, 2, 3):
        paper = j.n_gaps * (
            j.hole_length_mm
            + j.gap_mm * math.cos(theta / (2 * j.n_gaps))
            - 2 * r * math.sin(theta / (2 * j.n_gaps)) * math.cos(phi + (jj - 1) * alpha)
        )
        clockwise_beta = -(jj - 1) * alpha
        assert vt.joint_cable_length(theta, phi, clockwise_beta, r, j) == pytest.approx(paper)


def test_eq4_eq5_coupling_and_round_trip(arm):
    rng = np.random.default_rng(3)
    psi = np.array([[0.5, 0.3], [0.8, -1.0], [0.3, 2.0]])
    q = vt.cable_displacements(arm, psi)
    # eq. 5: a distal cable's shortening is the sum of eq. 4 over every joint it passes
    k = 8  # c33, ends in joint 3
    beta, r = arm.betas[k], arm.radii[k]
    total = sum(vt.joint_cable_shortening(*psi[i], beta, r, arm.joints[i]) for i in range(3))
    assert q[k] == pytest.approx(float(total))
    only1 = vt.cable_displacements(arm, np.array([[0.5, 0.3], [0, 0], [0, 0]]))
    assert np.all(np.abs(only1[3:]) > 0.5)  # joint 1 moves the cables of joints 2 and 3
    cases = [np.zeros((3, 2)), np.array([[1e-9, 0.2], [0, 0], [2.0, -3.0]]), psi]
    cases += [
        np.column_stack((rng.uniform(0, 2.5, 3), rng.uniform(-math.pi, math.pi, 3)))
        for _ in range(15)
    ]
    for p in cases:
        x = vt.joints_from_displacements(arm, vt.cable_displacements(arm, p))
        np.testing.assert_allclose(x, vt.x_from_psi(p), atol=1e-10)  # acceptance 1e-6 rad


def test_cable_jacobian_matches_differences_and_is_finite_at_straight(arm):
    for x in (np.zeros(6), np.array([0.3, -0.2, 1e-9, 0.0, 1.1, 0.7])):
        J = vt.cable_jacobian_x(arm, x)
        h = 1e-6
        for j in range(6):
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            col = (
                vt.cable_path_lengths(arm, vt.psi_from_xs(xp))
                - vt.cable_path_lengths(arm, vt.psi_from_xs(xm))
            ) / (2 * h)
            np.testing.assert_allclose(J[:, j], col, atol=2e-6)
    J0 = vt.cable_jacobian_x(arm, np.zeros(6))
    own = arm.own_cables[0]
    np.testing.assert_allclose(
        J0[own][:, :2],
        -15.0 * np.column_stack((np.cos(arm.betas[own]), np.sin(arm.betas[own]))),
        atol=1e-12,
    )


# --------------------------------------------------------------------------- eq. 9
def test_eq9_pulses_and_rate(arm):
    m = vt.LinearModule(steps_per_rev=3200, lead_mm=5.0, v_max_mm_s=10.0)
    assert float(m.pulses(2.5)) == pytest.approx(1600.0)  # m = (s/c) dl
    assert float(m.pulse_rate_hz(10.0)) == pytest.approx(6400.0)  # f = (s/c) v
    assert m.max_pulse_rate_hz == pytest.approx(6400.0)


def test_cable_hessian_is_the_derivative_of_the_jacobian(arm):
    h = 1e-6
    for x in (np.zeros(6), np.array([0.3, -0.2, 1e-9, 0.0, 1.1, 0.7]), np.full(6, 0.9)):
        Hs = vt.cable_hessian_x(arm, x)
        for j in range(6):
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            fd = (vt.cable_jacobian_x(arm, xp) - vt.cable_jacobian_x(arm, xm)) / (2 * h)
            np.testing.assert_allclose(Hs[:, :, j], fd, atol=2e-7)
        np.testing.assert_allclose(Hs, Hs.transpose(0, 2, 1), atol=1e-12)
    # at the straight pose only the gap term remains: -(l0/4n) I - r d1(0) x_beta I = -(l0/4n) I
    j = arm.joints[0]
    H0 = vt.cable_hessian_x(arm, np.zeros(6))
    np.testing.assert_allclose(H0[0, :2, :2], -(j.gap_mm / (4 * j.n_gaps)) * np.eye(2), atol=1e-15)


def test_series_functions_are_continuous_at_their_switch_points():
    for f, u0 in ((vt.s1, vt.SERIES_BELOW), (vt.d1, vt.SERIES_BELOW), (vt.d2, vt.D2_SERIES_BELOW)):
        below, above = f(u0 * (1 - 1e-12)), f(u0 * (1 + 1e-12))
        assert below == pytest.approx(above, rel=1e-10, abs=1e-14)
    assert vt.d2(0.0) == pytest.approx(1.0 / 15.0)
    for u in (0.02, 0.2, 0.7):  # d2 = d1'/u
        h = 1e-5
        assert vt.d2(u) == pytest.approx((vt.d1(u + h) - vt.d1(u - h)) / (2 * h) / u, rel=1e-6)


# --------------------------------------------------------------------------- eq. 6-8
def test_eq6_is_the_sensors_zyx_euler(arm):
    rng = np.random.default_rng(11)
    for _ in range(10):
        yaw, pitch, roll = rng.uniform(-3, 3), rng.uniform(-1.5, 1.5), rng.uniform(-3, 3)
        R = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()  # intrinsic Z-Y-X
        np.testing.assert_allclose(vt.rotation_zyx(roll, pitch, yaw), R, atol=1e-14)
        np.testing.assert_allclose(vt.world_up_in_sensor(roll, pitch), R[2], atol=1e-14)


PSI_CASES = [
    (0.7, 0.4),
    (1.9, -2.8),
    (1e-7, 1.2),
    (0.0, 0.0),
    (math.pi - 1e-6, 0.9),
    (math.pi - 1e-3, -1.4),
    (0.3, math.pi),
]


@pytest.mark.parametrize(("theta", "phi"), PSI_CASES)
def test_eq7_eq8_decode_relative_rotation(theta, phi):
    R = joint_rot(theta, phi).as_matrix()
    th, ph = vt.angles_from_relative_rotation(R, prev_phi=phi if theta < 1e-6 else 0.0)
    assert th == pytest.approx(theta, abs=1e-9)
    if theta > 1e-9:
        assert math.cos(ph - phi) == pytest.approx(1.0, abs=1e-9)


def test_eq7_eq8_singular_poses():
    assert vt.angles_from_relative_rotation(np.eye(3), prev_phi=0.8) == (0.0, 0.8)
    for phi in (0.3, -1.2, 2.9):
        R = joint_rot(math.pi, phi).as_matrix()
        th, ph = vt.angles_from_relative_rotation(R, prev_phi=phi + 0.1)
        assert th == pytest.approx(math.pi)
        assert math.cos(ph - phi) == pytest.approx(1.0, abs=1e-9)  # nearest of phi, phi + pi
        th, ph = vt.angles_from_relative_rotation(R, prev_phi=phi + math.pi - 0.1)
        assert math.cos(ph - phi) == pytest.approx(-1.0, abs=1e-9)  # the same rotation
        np.testing.assert_allclose(vt.joint_rotation(th, ph), R, atol=1e-12)


def chain_sensors(psi, base=None, rng=None, mounts=None):
    """Absolute sensor orientations of a joint chain, each with a random yaw error about world z
    (the unreliable magnetometer), reported as the sensor's Z-Y-X Euler angles."""
    R = Rotation.identity() if base is None else base
    out = []
    for i, (th, ph) in enumerate(psi):
        R = R * joint_rot(th, ph)
        sensor = R if mounts is None else R * mounts[i]
        if rng is not None:
            sensor = Rotation.from_rotvec([0, 0, rng.uniform(-math.pi, math.pi)]) * sensor
        yaw, pitch, roll = sensor.as_euler("ZYX")
        out.append((roll, pitch, yaw, sensor))
    return out


def test_yaw_free_decode_recovers_every_joint(arm):
    rng = np.random.default_rng(5)
    for _ in range(20):
        psi = np.column_stack((rng.uniform(0.05, 2.5, 3), rng.uniform(-math.pi, math.pi, 3)))
        sens = chain_sensors(psi, rng=rng)  # every sensor with its own heading error
        rolls = [s[0] for s in sens]
        pitches = [s[1] for s in sens]
        dec = vt.decode_joint_attitudes(rolls, pitches)
        for i, att in enumerate(dec):
            if att.observability < 1e-3:
                continue  # bend about the vertical: invisible to tilt (tested below)
            assert att.theta == pytest.approx(psi[i, 0], abs=1e-8)
            assert math.cos(att.phi - psi[i, 1]) == pytest.approx(1.0, abs=1e-8)


def test_yaw_free_decode_with_tilted_base_and_mounts():
    rng = np.random.default_rng(9)
    base = Rotation.from_rotvec([0.3, -0.2, 0.0])
    mounts = [Rotation.from_rotvec(rng.normal(size=3) * 0.3) for _ in range(3)]
    psi = np.array([[0.6, 0.5], [1.1, -2.0], [0.4, 2.5]])
    sens = chain_sensors(psi, base=base, rng=rng, mounts=mounts)
    base_up = base.inv().apply([0, 0, 1])  # world up seen in the base frame
    dec = vt.decode_joint_attitudes(
        [s[0] for s in sens],
        [s[1] for s in sens],
        base_up=base_up,
        mounts=[m.as_matrix() for m in mounts],
    )
    np.testing.assert_allclose([a.theta for a in dec], psi[:, 0], atol=1e-9)
    np.testing.assert_allclose(np.cos([a.phi for a in dec] - psi[:, 1]), 1.0, atol=1e-9)
    # the decode from full rotations (headings shared, no yaw error) gives the same
    full = chain_sensors(psi, base=base, mounts=None)
    out = vt.decode_from_rotations([s[3].as_matrix() for s in full], base.as_matrix())
    np.testing.assert_allclose(out[:, 0], psi[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.cos(out[:, 1] - psi[:, 1]), 1.0, atol=1e-12)


@pytest.mark.parametrize("theta", [0.0, 1e-12, 1e-7, math.pi - 1e-6, math.pi])
def test_yaw_free_decode_near_0_and_pi(theta):
    phi = 0.7
    sens = chain_sensors([(theta, phi)], rng=np.random.default_rng(1))
    att = vt.decode_joint_attitudes([sens[0][0]], [sens[0][1]], prev_phi=[-2.0])[0]
    assert att.theta == pytest.approx(theta, abs=1e-8)
    if vt.SINGULAR_TOL < theta < math.pi - 1e-9:
        assert math.cos(att.phi - phi) == pytest.approx(1.0, abs=1e-6)
    else:
        # straight, or theta = pi under an upright base (every direction gives the same tilt)
        assert att.phi == -2.0  # undefined: kept
        R = vt.joint_rotation(att.theta, att.phi)
        np.testing.assert_allclose(R.T @ [0, 0, 1], sens[0][3].inv().apply([0, 0, 1]), atol=1e-9)


def test_tilt_cannot_see_a_bend_about_the_vertical():
    # joint 1 bent 90 deg about y: joint 2's bend axis is world z -> tilt unchanged
    psi = [(math.pi / 2, 0.0), (0.5, math.pi / 2)]  # k2 = (-1, 0, 0) in joint-1 end = world z
    with pytest.warns(UserWarning, match="Gimbal lock"):  # the sensors read pitch = 90 deg
        sens = chain_sensors(psi)
    dec = vt.decode_joint_attitudes([s[0] for s in sens], [s[1] for s in sens])
    assert dec[0].theta == pytest.approx(math.pi / 2)
    assert dec[1].observability == pytest.approx(0.0, abs=1e-9)
    assert dec[1].theta == pytest.approx(0.0, abs=1e-9)


# --------------------------------------------------------------------------- end following
def check_step(arm, planner, step):
    f_max = arm.max_pulse_rate_hz
    m = np.abs(step.pulses)
    assert np.all(step.pulse_rate_hz <= f_max * (1 + 1e-12))  # no axis over its limit
    if m.max() > 0:
        # the longest move (at its own limit) sets the duration; every axis ends with it
        assert step.duration_s == pytest.approx(np.max(m / f_max))
        moving = m > 0
        np.testing.assert_allclose(m[moving] / step.pulse_rate_hz[moving], step.duration_s)
        assert np.isclose(step.pulse_rate_hz / f_max, 1.0).any()
        np.testing.assert_allclose(step.velocity_mm_s * arm.pulses_per_mm, step.pulse_rate_hz)
    dx = vt.x_from_psi(step.psi_to) - vt.x_from_psi(step.psi_from)
    assert np.max(np.hypot(dx[:, 0], dx[:, 1])) <= planner.params.step_rad + 1e-12
    np.testing.assert_allclose(
        step.delta_mm,
        vt.cable_displacements(arm, step.psi_to) - vt.cable_displacements(arm, step.psi_from),
        atol=1e-12,
    )


def test_end_following_steer_then_follow(arm, cfg):
    planner = vt.EndFollowPlanner(arm, follow_params(cfg))
    start_pulses = planner.position_pulses.copy()
    # the stick fully forward and a bit to the side for 30 ticks
    for _ in range(30):
        assert planner.steer(0.4, 1.0)
    target = planner.target[-1].copy()
    assert target[0] == pytest.approx(30 * 0.02)
    assert target[1] == pytest.approx(30 * 0.4 * 0.05)
    steps = planner.run()
    assert planner.mode is vt.FollowMode.IDLE
    np.testing.assert_allclose(planner.psi[-1], target, atol=1e-12)  # the distal joint arrives
    np.testing.assert_allclose(planner.psi[:-1], 0.0)  # only the distal joint was steered
    assert len(steps) == math.ceil(target[0] / 0.05 - 1e-9)
    for s in steps:
        check_step(arm, planner, s)
    # follow: joint 2 takes joint 3's pose, joint 1 joint 2's (straight)
    distal = planner.psi[-1].copy()
    assert planner.advance()
    assert not planner.steer(1.0, 1.0)  # the stick is ignored while following
    steps = planner.run()
    np.testing.assert_allclose(planner.psi[1], distal, atol=1e-12)
    np.testing.assert_allclose(planner.psi[2], distal, atol=1e-12)
    np.testing.assert_allclose(planner.psi[0], 0.0, atol=1e-12)
    for s in steps:
        check_step(arm, planner, s)
    # steer the tip elsewhere and follow again: the shape moves one joint towards the base
    planner.set_distal_target(0.3, -1.0)
    planner.run()
    assert planner.advance()
    for s in planner.run():
        check_step(arm, planner, s)
    np.testing.assert_allclose(planner.psi, [distal, [0.3, -1.0], [0.3, -1.0]], atol=1e-12)
    # pulses were rounded on the absolute position: no drift
    total = start_pulses + sum((s.pulses for s in steps), np.zeros(arm.n_cables, dtype=np.int64))
    assert np.array_equal(
        planner.position_pulses,
        np.rint(vt.cable_displacements(arm, planner.psi) * arm.pulses_per_mm).astype(np.int64),
    )
    assert total.shape == start_pulses.shape


def test_synchronise_respects_different_axis_limits(arm):
    slow = tuple(replace(m, v_max_mm_s=2.0) if i == 4 else m for i, m in enumerate(arm.modules))
    a = replace(arm, modules=slow)
    pulses = np.array([100, -300, 50, 0, 200, 10, -5, 0, 1])
    duration, rate = vt.synchronise(pulses, a)
    f_max = a.max_pulse_rate_hz
    assert duration == pytest.approx(200 / f_max[4])  # the slow axis, not the longest move
    assert np.all(rate <= f_max * (1 + 1e-12))
    np.testing.assert_allclose(rate * duration, np.abs(pulses))
    assert vt.synchronise(np.zeros(9), a) == (0.0, pytest.approx(np.zeros(9)))


def test_planner_limits(arm):
    p = vt.EndFollowPlanner(arm, vt.FollowParams(theta_max_rad=0.5))
    for _ in range(100):
        p.steer(0.0, 1.0)
    assert p.target[-1, 0] == pytest.approx(0.5)
    for _ in range(100):
        p.steer(0.0, -1.0)
    assert p.target[-1, 0] == 0.0
    with pytest.raises(ModelError):
        vt.EndFollowPlanner(arm, vt.FollowParams(theta_max_rad=0.5), psi=np.full((3, 2), 1.0))


# --------------------------------------------------------------------------- truth
def test_truth_kinematic_without_statics_and_sag_with_gravity(arm):
    psi = np.array([[0.6, 0.0], [0.4, 0.0], [0.3, 0.0]])
    q = vt.cable_displacements(arm, psi)
    np.testing.assert_allclose(vt.truth_pose(arm, q, statics=False), psi, atol=1e-10)
    weightless = replace(arm, gravity_mm_s2=(0.0, 0.0, 0.0))
    tip_no_g = vt.tip_position(arm, vt.truth_pose(weightless, q))
    tip = vt.tip_position(arm, vt.truth_pose(arm, q))
    assert tip[2] < tip_no_g[2] - 1.0  # the bent arm droops under gravity
    assert abs(tip[1]) < 1e-6  # bent in the x-z plane, stays there
    # the upright straight arm does not sag
    np.testing.assert_allclose(vt.truth_pose(arm, np.zeros(9))[:, 0], 0.0, atol=1e-12)


def test_truth_statics_balance_rod_and_slack(arm):
    weightless = replace(arm, gravity_mm_s2=(0.0, 0.0, 0.0))
    psi = np.array([[1.2, 0.5], [0.3, -1.0], [0.0, 0.0]])
    x_kin = vt.x_from_psi(psi).ravel()
    x, T = vt.statics_x(weightless, x_kin)
    assert np.linalg.norm(x[0]) < np.linalg.norm(x_kin[:2])  # the rod unbends it
    assert np.all(T >= 0.0) and np.any(T == 0.0)  # its moment slackens a cable (10 N pretension)
    # equilibrium with the linearised cables: J^T T + K_g dx + K_rod x = Q (= 0 here)
    J = vt.cable_jacobian_x(arm, x_kin)
    T0 = np.array([c.pretension_N for c in arm.cables])
    taut = T > 0.0
    h = 1e-6
    Kg = np.zeros((6, 6))  # geometric stiffness of the taut cables' pretension
    for j in range(6):
        xp, xm = x_kin.copy(), x_kin.copy()
        xp[j] += h
        xm[j] -= h
        Kg[:, j] = (
            (T0 * taut) @ (vt.cable_jacobian_x(arm, xp) - vt.cable_jacobian_x(arm, xm)) / (2 * h)
        )
    dx = x.ravel() - x_kin
    K_rod = np.repeat([j.rod_EI_Nmm2 / j.length_mm for j in arm.joints], 2)
    residual = J.T @ T + Kg @ dx + K_rod * x.ravel()
    np.testing.assert_allclose(residual, 0.0, atol=1e-6 * np.abs(K_rod * x.ravel()).max())
    # the model's sag compensation: command x_kin so that the arm ends where wanted
    x_target = vt.x_from_psi(np.array([[0.8, 1.0], [0.5, -0.5], [0.2, 0.0]]))
    x_pre = vt.statics_inverse_x(arm, x_target)
    np.testing.assert_allclose(vt.statics_x(arm, x_pre)[0], x_target, atol=1e-9)


def test_statics_on_the_slack_threshold_of_a_cable(arm):
    """A pose where cable c32 is neither taut nor slack: taut, its tension comes out negative;
    slack (its pretension's geometric stiffness gone too), it is stretched. The equilibrium
    holds it at zero tension with part of that stiffness (the active set used to cycle here)."""
    x = np.array([0.3857, 0.2932, 0.2137, 0.1624, 0.2566, 0.195])
    xs, T = vt.statics_x(arm, x)
    edge = 7  # c32
    assert T[edge] == 0.0 and T[3] == 0.0 and np.all(np.delete(T, [3, edge]) > 5.0)
    dx = xs.ravel() - x
    J = vt.cable_jacobian_x(arm, x)
    Lh = vt.cable_hessian_x(arm, x)
    T0 = np.array([c.pretension_N for c in arm.cables])
    k = np.array([c.stiffness_N_per_mm for c in arm.cables])
    assert abs(T0[edge] + k[edge] * (J[edge] @ dx)) < 1e-8  # exactly at the threshold
    taut = T > 0.0
    K_rod = np.repeat([j.rod_EI_Nmm2 / j.length_mm for j in arm.joints], 2)
    F = (
        J[taut].T @ T[taut]
        + np.tensordot(T0[taut], Lh[taut], axes=1) @ dx
        + K_rod * xs.ravel()
        - vt.gravity_torque_x(arm, xs.ravel())
    )
    g = T0[edge] * Lh[edge] @ dx  # the edge cable's geometric force
    w = -(g @ F) / (g @ g)
    assert 0.0 <= w <= 1.0
    np.testing.assert_allclose(F + w * g, 0.0, atol=1e-6)


def test_gravity_potential_batch_matches_mass_points(arm):
    psi = np.array([[0.6, 0.3], [0.4, -1.0], [0.3, 2.0]])
    pts, ms = vt.mass_points(arm, psi)
    expected = -np.sum(ms * 1e-6 * (pts @ np.array(arm.gravity_mm_s2)))
    assert vt.gravity_potential_Nmm(arm, psi) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize(
    "psi",
    [
        np.zeros((3, 2)),
        np.array([[1e-9, 0.4], [0.0, 0.0], [0.2, -2.0]]),
        np.array([[1.2, 2.5], [0.9, -0.4], [1.5, 1.0]]),
    ],
)
def test_closed_form_potential_matches_the_disk_chain_off_axis_gravity_too(arm, psi):
    for a in (arm, replace(arm, gravity_mm_s2=(3000.0, -2000.0, -9000.0))):
        pts, ms = vt.mass_points(a, psi)
        expected = -np.sum(ms * 1e-6 * (pts @ np.array(a.gravity_mm_s2)))
        assert vt.gravity_potential_Nmm(a, psi) == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_one_batch_gravity_torque_and_hessian_match_the_separate_ones(arm):
    x = np.array([0.3, -0.2, 0.5, 0.1, -0.7, 0.4])
    Q, H = vt._gravity_torque_and_hessian(arm, x)
    np.testing.assert_allclose(Q, vt.gravity_torque_x(arm, x), rtol=1e-12, atol=1e-12)
    # the solver's Hessian: forward mixed differences, O(h) = 1e-4 relative
    H4 = vt.gravity_hessian_x(arm, x)
    np.testing.assert_allclose(H, H4, atol=1e-3 * np.abs(H4).max())
    np.testing.assert_array_equal(H, H.T)
    # the torque is minus the gradient of the potential (larger step: independent check)
    h = 1e-3
    for j in range(6):
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        dV = (
            vt.gravity_potential_Nmm(arm, vt.psi_from_xs(xp))
            - vt.gravity_potential_Nmm(arm, vt.psi_from_xs(xm))
        ) / (2 * h)
        assert Q[j] == pytest.approx(-dV, rel=1e-5, abs=1e-6)


def test_statics_warm_start_reaches_the_same_equilibrium(arm):
    x_kin = vt.x_from_psi(np.array([[0.9, 0.3], [0.6, 1.2], [1.1, -0.8]])).ravel()
    cold, t_cold = vt.statics_x(arm, x_kin)
    for guess in (cold.ravel() - x_kin, np.full(6, 0.05), -0.1 * np.ones(6)):
        warm, t_warm = vt.statics_x(arm, x_kin, guess)
        np.testing.assert_allclose(warm, cold, atol=1e-11)
        np.testing.assert_allclose(t_warm, t_cold, atol=1e-7)


def test_loop_adapter(arm):
    model = vt.VertebraModel(arm)
    psi = np.array([[0.5, 0.2], [0.3, -1.0], [0.2, 2.0]])
    q = model.q_nominal(psi)
    np.testing.assert_allclose(model.q_command(psi, q, model.new_state(), "off", None), q)
    state = model.new_state()
    for _ in range(20):  # one warm-started statics evaluation per cycle: converges over cycles
        q_cmd = model.q_command(psi, q, state, "model", None)
    np.testing.assert_allclose(vt.truth_pose(arm, q_cmd), psi, atol=1e-8)
    with pytest.raises(ModelError):
        model.q_command(psi, q, None, "measured", None)
    with pytest.raises(ModelError, match="attitude"):
        model.q_command(psi, q, model.new_state(), "measured", None)


def test_compensation_offset_is_rate_limited_and_ramps_in_from_off(arm):
    step = 0.01  # mm per cycle
    model = vt.VertebraModel(arm, vt.AttitudeLoopParams(max_offset_step_mm=step))
    free = vt.VertebraModel(arm)
    psi = np.array([[0.8, 0.3], [0.6, 1.0], [0.9, -0.5]])
    q = model.q_nominal(psi)
    state, free_state = model.new_state(), free.new_state()
    for _ in range(200):  # one fixed-point step per cycle: converged
        target = free.q_command(psi, q, free_state, "model", None)
    assert np.abs(target - q).max() > 0.5  # a sag offset worth limiting
    # from mode off (no offset) the compensation ramps in at the bound, never jumps
    prev = model.q_command(psi, q, state, "off", None)
    np.testing.assert_array_equal(prev, q)
    n = 0
    while n < 1000:
        q_cmd = model.q_command(psi, q, state, "model", None)
        assert np.abs(q_cmd - prev).max() <= step * (1 + 1e-9)
        prev, n = q_cmd, n + 1
        if np.abs(q_cmd - target).max() < 1e-9:
            break
    expected = np.abs(target - q).max() / step
    assert expected <= n <= expected + 25  # limited by the rate, then the fixed point converges
    # a moving command: plan + offset never moves faster than the plan's step + the bound
    prev_q, prev_cmd = q, q_cmd
    for k in range(1, 60):
        p = psi * (1.0 + 0.002 * k)
        qn = model.q_nominal(p)
        q_cmd = model.q_command(p, qn, state, "model", None)
        assert np.abs((q_cmd - qn) - (prev_cmd - prev_q)).max() <= step * (1 + 1e-9)
        prev_q, prev_cmd = qn, q_cmd
    # back to off: the offset is gone at once (the loop ramps mode changes out itself)
    np.testing.assert_array_equal(model.q_command(psi, q, state, "off", None), q)
    assert state.offset_mm is None
    with pytest.raises(ModelError):
        vt.AttitudeLoopParams(max_offset_step_mm=0.0)


def test_attitude_closed_loop_removes_the_sag(arm):
    """Mode measured: the sensors see the sagged truth (eq. 6 angles of the joint-end frames);
    the integral correction drives the true joint poses to the command."""

    class Sensors:
        def __init__(self):
            self.q = np.zeros(arm.n_cables)

        def latest(self):
            psi = vt.truth_pose(arm, self.q)
            T = np.eye(4)
            roll, pitch = [], []
            for i, j in enumerate(arm.joints):
                T = T @ vt.joint_transform(psi[i, 0], psi[i, 1], j)
                r = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX")  # yaw, pitch, roll
                roll.append(r[2])
                pitch.append(r[1])
            return np.array(roll), np.array(pitch), np.zeros(arm.n_joints)

    sensors = Sensors()
    model = vt.VertebraModel(arm, vt.AttitudeLoopParams(gain_per_tick=0.3))
    model.attach_attitude(sensors)
    psi = np.array([[0.6, 0.3], [0.5, 0.3], [0.4, 0.3]])
    open_loop = np.abs(vt.truth_pose(arm, model.q_nominal(psi)) - psi).max()
    state = model.new_state()
    for _ in range(60):
        sensors.q = model.q_command(psi, model.q_nominal(psi), state, "measured", None)
    closed = np.abs(vt.truth_pose(arm, sensors.q) - psi).max()
    assert open_loop > 0.02 and closed < 1e-3 * open_loop / 0.02


# --------------------------------------------------------------------------- config
def test_vertebra_config_builds_the_papers_arm(cfg, arm):
    assert cross_check(cfg) == [] and check_design(cfg) == []
    assert [j.length_mm for j in arm.joints] == [220.0] * 3  # paper
    assert arm.joints[0].gap_mm == pytest.approx(16.0)
    assert arm.n_cables == 9
    assert sensor_mounts(cfg) is None
    data = cfg.model_dump()
    bad = dict(
        data,
        sensors={
            **data["sensors"],
            "attitude": {
                **data["sensors"]["attitude"],
                "sensors": data["sensors"]["attitude"]["sensors"][:2],
            },
        },
    )
    assert check_design(RigConfig.model_validate(bad))[0][0] == (
        "sensors",
        "attitude",
        "sensors",
    )


def test_compensation_rate_fits_beside_the_planned_speed(cfg):
    from cdcr_ctl.config.designs import attitude_loop_params

    p = attitude_loop_params(cfg)
    assert p.max_offset_step_mm == pytest.approx(
        cfg.vertebra.compensation_max_rate_mm_s / cfg.control.rate_hz
    )
    data = cfg.model_dump()
    v_limit = cfg.limits.cable_velocity_mm_s
    planned = cfg.vertebra.follow.speed_fraction * cfg.vertebra.linear_module.v_max_mm_s
    headroom = v_limit - planned
    assert headroom > 0
    for rate, ok in ((headroom, True), (headroom * 1.01, False)):
        bad = dict(data, vertebra={**data["vertebra"], "compensation_max_rate_mm_s": rate})
        problems = check_design(RigConfig.model_validate(bad))
        keys = [k for k, _, _ in problems]
        assert (("vertebra", "compensation_max_rate_mm_s") not in keys) == ok, problems
