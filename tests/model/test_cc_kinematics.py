"""Constant-curvature kinematics (Qi et al. 2023 eq. 1-3, 6) against scipy, geometry and FD."""

from __future__ import annotations

import math

import numpy as np
import pytest
from cc_robots import central_diff
from scipy.spatial.transform import Rotation

from cdcr_ctl.model.cc_disk import kinematics as kin

ANGLES = [(1.0, 0.3), (0.4, -2.0), (2.5, 3.0), (1e-7, 1.1), (0.0, 0.7), (-0.6, 0.2), (0.1, 1.3)]


@pytest.mark.parametrize(("theta", "phi"), ANGLES)
def test_eq1_rotation_equals_scipy_composition(theta, phi):
    R_ref = Rotation.from_euler("ZYZ", [phi, theta, -phi]).as_matrix()  # intrinsic z, y, z
    R_ref2 = (
        Rotation.from_rotvec([0, 0, phi])
        * Rotation.from_rotvec([0, theta, 0])
        * Rotation.from_rotvec([0, 0, -phi])
    ).as_matrix()
    R = kin.rotation(theta, phi)
    np.testing.assert_allclose(R, R_ref, atol=1e-15)
    np.testing.assert_allclose(R, R_ref2, atol=1e-15)
    # the corrected (2,1) element: the xy block is symmetric (NOTES, eq. 1 typo)
    assert R[1, 0] == pytest.approx(math.cos(phi) * math.sin(phi) * (math.cos(theta) - 1.0))
    np.testing.assert_allclose(
        kin.segment_pose_x(kin.bend_vector(theta, phi), 1.0)[0], R, atol=1e-15
    )


def test_eq2_position_straight_and_arc():
    assert kin.position(0.0, 0.4, 90.0) == pytest.approx([0.0, 0.0, 90.0], abs=0)
    # a quarter circle of length L has radius 2l/pi: tip at (R, 0, R) in the bending plane
    L = 90.0
    R = 2 * L / math.pi
    for phi in (0.0, 1.0, -2.5):
        p = kin.position(math.pi / 2, phi, L)
        np.testing.assert_allclose(p, [R * math.cos(phi), R * math.sin(phi), R], atol=1e-12)


def test_series_join_smoothly_at_threshold():
    for f in (kin.s1, kin.c2, kin.d1, kin.d2, kin.e2, kin.g1):
        below = f(kin.SERIES_BELOW * (1 - 1e-12))
        above = f(kin.SERIES_BELOW * (1 + 1e-12))
        assert below == pytest.approx(above, rel=1e-12, abs=1e-14)
    assert kin.s1(0.0) == 1.0 and kin.c2(0.0) == 0.5 and kin.d1(0.0) == pytest.approx(-1 / 3)


def _omega_fd(Rfun, q, h=1e-6):
    """Angular-velocity Jacobian (3, n) by central differences: skew(w) = dR R^T."""
    q = np.asarray(q, dtype=float)
    R0 = Rfun(q)
    cols = []
    for j in range(q.size):
        e = np.zeros_like(q)
        e[j] = h
        W = (Rfun(q + e) - Rfun(q - e)) / (2 * h) @ R0.T
        cols.append([W[2, 1], W[0, 2], W[1, 0]])
    return np.array(cols).T


@pytest.mark.parametrize(("theta", "phi"), ANGLES)
def test_eq6_segment_jacobian_vs_finite_differences(theta, phi):
    L = 90.0
    Jv, Jw = kin.segment_jacobian(theta, phi, L)
    assert np.all(np.isfinite(Jv)) and np.all(np.isfinite(Jw))
    q = np.array([theta, phi])
    Jv_fd = central_diff(lambda v: kin.position(v[0], v[1], L), q)
    Jw_fd = _omega_fd(lambda v: kin.rotation(v[0], v[1]), q)
    np.testing.assert_allclose(Jv, Jv_fd, atol=2e-7)
    np.testing.assert_allclose(Jw, Jw_fd, atol=2e-9)


@pytest.mark.parametrize("x", [(0.7, -0.4), (1e-7, 0.0), (0.0, 0.0), (-1e-7, 2e-7), (1.5, 1.0)])
def test_bending_vector_jacobian_smooth_through_zero(x):
    L = 80.0
    x = np.array(x)
    Jv, Jw = kin.segment_jacobian_x(x, L)
    Jv_fd = central_diff(lambda v: kin.segment_pose_x(v, L)[1], x)
    Jw_fd = _omega_fd(lambda v: kin.segment_pose_x(v, L)[0], x)
    np.testing.assert_allclose(Jv, Jv_fd, atol=2e-7)
    np.testing.assert_allclose(Jw, Jw_fd, atol=2e-9)


def test_jacobians_continuous_through_theta_zero():
    L = 80.0
    J0 = np.hstack(kin.segment_jacobian_x(np.zeros(2), L))
    for x in ([1e-7, 0.0], [-1e-7, 0.0], [0.0, 1e-7], [7e-8, -7e-8]):
        J = np.hstack(kin.segment_jacobian_x(np.array(x), L))
        np.testing.assert_allclose(J, J0, atol=1e-5)
    # (theta, phi) form at theta -> 0 from both sides of the straight pose
    Jp = np.hstack(kin.segment_jacobian(1e-9, 0.4, L))
    Jm = np.hstack(kin.segment_jacobian(-1e-9, 0.4, L))
    np.testing.assert_allclose(Jp, Jm, atol=1e-6)


def test_eq3_chain_of_equal_curvature_is_one_arc():
    # two segments in one plane with equal curvature form one arc of the summed length/angle
    psi = np.array([[0.9, 0.5], [0.8, 0.5]])
    lengths = np.array([90.0, 80.0])
    np.testing.assert_allclose(
        kin.tip_position(psi, lengths), kin.position(1.7, 0.5, 170.0), atol=1e-12
    )
    R = kin.chain(psi, lengths)[-1][0]
    np.testing.assert_allclose(R, kin.rotation(1.7, 0.5), atol=1e-14)


@pytest.mark.parametrize("coords", ["psi", "x"])
@pytest.mark.parametrize(
    "psi", [[[0.9, 0.3], [0.5, 2.0], [1.2, -1.0]], [[0.0, 0.0], [1e-7, 0.5], [0.0, 0.0]]]
)
def test_robot_jacobian_vs_finite_differences(psi, coords):
    psi = np.array(psi)
    lengths = np.array([90.0, 80.0, 70.0])
    J = kin.robot_jacobian(psi, lengths, coords)
    assert np.all(np.isfinite(J))
    if coords == "psi":
        q0 = psi.ravel()

        def to_psi(v):
            return v.reshape(-1, 2)
    else:
        q0 = kin.psi_to_x(psi).ravel()

        def to_psi(v):
            return kin.x_to_psi(v.reshape(-1, 2))

    Jv_fd = central_diff(lambda v: kin.tip_position(to_psi(v), lengths), q0)
    Jw_fd = _omega_fd(lambda v: kin.chain(to_psi(v), lengths)[-1][0], q0)
    np.testing.assert_allclose(J[:3], Jv_fd, atol=3e-7)
    np.testing.assert_allclose(J[3:], Jw_fd, atol=3e-9)


def test_disk_point_jacobian_vs_finite_differences():
    psi = np.array([[0.9, 0.3], [0.5, 2.0]])
    lengths = np.array([90.0, 80.0])
    x0 = kin.psi_to_x(psi).ravel()
    for seg, frac in [(0, 0.4), (1, 0.6), (1, 1.0)]:

        def pt(v, seg=seg, frac=frac):
            return kin.point_jacobian(kin.x_to_psi(v.reshape(-1, 2)), lengths, seg, frac, "x")[0]

        _, Jv, _ = kin.point_jacobian(psi, lengths, seg, frac, "x")
        np.testing.assert_allclose(Jv, central_diff(pt, x0), atol=3e-7)
    pos = kin.disk_positions(psi, lengths, [3, 2])
    assert pos.shape == (5, 3)
    np.testing.assert_allclose(pos[2], kin.chain(psi, lengths)[0][1], atol=1e-12)


def test_fast_tip_frame_equals_the_chain():
    # rotation and position of the last tip frame, including straight and nearly straight
    # segments (the series branch of the ratios) and one theta = 0 exactly
    rng = np.random.default_rng(7)
    lengths = [90.0, 80.0, 70.0]
    for trial in range(30):
        theta = rng.uniform(0, 2, 3) * (1e-3 if trial % 3 == 0 else 1.0)
        if trial == 1:
            theta[1] = 0.0
        psi = np.column_stack((theta, rng.uniform(-3, 3, 3)))
        xs = kin.psi_to_x(psi).ravel().tolist()
        R, p = kin.tip_frame_fast(xs, lengths)
        R_ref, p_ref = kin.chain(psi, np.array(lengths))[-1]
        np.testing.assert_allclose(np.array(R), R_ref, atol=1e-14)
        np.testing.assert_allclose(p, p_ref, atol=1e-12)
        assert kin.tip_position_fast(xs, lengths) == p


def test_bend_angles_roundtrip():
    for theta, phi in [(0.7, 1.0), (0.0, 0.0), (2.0, -3.0)]:
        th, ph = kin.bend_angles(kin.bend_vector(theta, phi))
        assert th == pytest.approx(theta) and (theta == 0 or ph == pytest.approx(phi))
