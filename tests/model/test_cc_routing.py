"""Cable routing: eq. 4-5 over several segments, exact chords through the disks, wrap angles."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from cc_robots import central_diff, make_robot

from cdcr_ctl.model.cc_disk import routing as ro
from cdcr_ctl.model.cc_disk.kinematics import psi_to_x


def test_eq4_single_segment_hand_values():
    p = make_robot(1)
    theta, beta = 0.8, 0.5
    q = ro.cable_displacement([[theta, beta]], p)
    # eq. 4 with l_ij = l - r theta cos(beta - gamma_j); pulled in = l - l_ij
    for k in range(3):
        gamma = 2 * math.pi * k / 3
        assert q[k] == pytest.approx(4.0 * theta * math.cos(beta - gamma), abs=1e-14)
    assert q.sum() == pytest.approx(0.0, abs=1e-13)  # 3 cables at 120 deg, same radius
    assert q[0] > 0  # bending towards the hole at 0 pulls cable 0 in


def test_distal_cables_add_proximal_shortening():
    p = make_robot(2)
    psi = np.array([[0.6, 0.2], [0.9, -1.0]])
    q = ro.cable_displacement(psi, p)
    c = p.cables[3]  # first cable of segment 2
    expected = sum(4.0 * psi[i, 0] * math.cos(psi[i, 1] - c.hole_angle_rad) for i in range(2))
    assert q[3] == pytest.approx(expected, abs=1e-14)


def test_eq5_jacobian_and_linear_x_form():
    p = make_robot(3)
    psi = np.array([[0.6, 0.2], [0.9, -1.0], [0.3, 2.0]])
    J = ro.cable_jacobian(psi, p)
    np.testing.assert_allclose(
        J, central_diff(lambda v: ro.cable_displacement(v, p), psi.ravel()), atol=1e-8
    )
    B = ro.cable_matrix_x(p)
    np.testing.assert_allclose(B @ psi_to_x(psi).ravel(), ro.cable_displacement(psi, p), atol=1e-13)
    # rank loss at theta = 0 in (theta, phi), none in x
    J0 = ro.cable_jacobian(np.zeros((3, 2)), p)
    assert np.linalg.matrix_rank(J0) == 3 and np.linalg.matrix_rank(B) == 6


def test_chord_length_tends_to_eq4_as_disks_multiply():
    psi = np.array([[1.2, 0.7]])
    errs = []
    for n in (5, 20, 80, 320):
        p = make_robot(1, n_disks=n)
        errs.append(abs(ro.chord_displacement(psi, p, 0) - ro.cable_displacement(psi, p)[0]))
    assert errs[-1] < 1e-4
    for a, b in itertools.pairwise(errs):  # second order in 1/n
        assert b == pytest.approx(a / 16, rel=0.05)


@pytest.mark.parametrize("thickness", [0.0, 2.0])
def test_chord_closed_form_equals_polyline(thickness):
    p = make_robot(2, thickness_mm=thickness)
    psi = np.array([[1.2, 0.7], [0.8, 2.5]])
    for k in range(p.n_cables):
        c = p.cables[k]
        closed = sum(
            ro.segment_chord_shortening(
                psi[i, 0], psi[i, 1], p.segments[i].length_mm, p.segments[i].n_disks,
                c.routing_radius_mm, c.hole_angle_rad, thickness,
            )
            for i in range(c.segment + 1)
        )  # fmt: skip
        assert closed == pytest.approx(ro.chord_displacement(psi, p, k), abs=1e-12)
    straight = ro.chord_displacement(np.zeros((2, 2)), p, 4)
    assert straight == pytest.approx(0.0, abs=1e-12)


def test_wrap_angles_sum_to_theta_over_one_segment():
    n = 5
    p = make_robot(1, n_disks=n)
    for theta, phi in [(1.2, 0.7), (0.3, -2.0), (1.5, 2.09)]:
        for k in range(3):
            eta = ro.wrap_angles([[theta, phi]], p, k)
            assert eta.size == n  # base hole + 4 inner holes; none at the anchor
            # exact for t = 0: theta/2n at the base, theta/n at each inner hole
            assert eta.sum() == pytest.approx(theta * (1 - 1 / (2 * n)), abs=1e-12)
            np.testing.assert_allclose(eta[1:], theta / n, atol=1e-12)


@pytest.mark.parametrize("thickness", [0.0, 2.0])
def test_wrap_angle_closed_forms_equal_general(thickness):
    p = make_robot(3, thickness_mm=thickness)
    psi = np.array([[1.2, 0.7], [0.8, 2.5], [0.4, -1.0]])
    for k in range(p.n_cables):
        np.testing.assert_allclose(
            ro.wrap_angles_closed_form(psi, p, k), ro.wrap_angles(psi, p, k), atol=1e-12
        )
    # one segment with channels: the sum is theta (1 - 1/2n) too (two edges of theta/2n)
    p1 = make_robot(1, thickness_mm=thickness)
    assert ro.wrap_angles([[1.0, 0.3]], p1, 1).sum() == pytest.approx(1.0 * (1 - 0.1), abs=1e-12)


def test_boundary_wrap_planar_and_opposite():
    # same plane: angles add; a straight distal segment: only the proximal half-step
    assert ro.boundary_wrap(1.0, 0.3, 5, 0.8, 0.3, 4, False) == pytest.approx(0.1 + 0.1)
    assert ro.boundary_wrap(1.0, 0.3, 5, 0.0, 0.0, 4, False) == pytest.approx(0.1)
    assert ro.boundary_wrap(1.0, 0.3, 5, 0.8, 0.3 + math.pi, 4, False) == pytest.approx(
        0.0, abs=1e-7
    )
