"""Universal-joint arm: the per-cycle path (vectorised eq. 4-5, analytic second derivatives,
normal-equation Newton steps, cached statics matrices, warm starts) against the plain
formulations it replaced: the literal eq. 4 per sub-joint, central differences of the Jacobian,
the pseudo-inverse Newton iteration and a cold-started truth. Results agree to the solvers'
tolerances, so the speed-up changes no number the controller or the simulator produce."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config.designs import ujoint_arm
from cdcr_ctl.config.loader import load_yaml_model
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.model import ujoint as uj

CONFIG = Path(__file__).resolve().parents[2] / "config" / "yang2022.yaml"
#: Central-difference step of the replaced geometric-stiffness formulation (rad).
FD_STEP_RAD = 1e-6


@pytest.fixture(scope="module")
def arm():
    return ujoint_arm(load_yaml_model(CONFIG, RigConfig), str(CONFIG))


def uneven(arm, gravity=(-9810.0, 0.0, 0.0)):
    """Light links under gravity and unequal pretensions: the statics has work to do."""
    return replace(
        arm,
        segments=tuple(replace(s, link_mass_g=15.0) for s in arm.segments),
        cables=tuple(replace(c, pretension_N=90.0 + 5.0 * k) for k, c in enumerate(arm.cables)),
        tip_mass_g=20.0,
        gravity_mm_s2=gravity,
    )


def poses(n, seed, scale=0.15):
    return np.random.default_rng(seed).uniform(-scale, scale, (n, 2, 2))


# --------------------------------------------------------------------------- eq. 4-5, 9
def test_hole_terms_equal_literal_eq4_and_its_gradient():
    rng = np.random.default_rng(1)
    beta, rho, d, m = rng.uniform(0, 2 * math.pi, 5), rng.uniform(20, 45, 5), 17.0, 4
    holes = uj.HoleSet.from_holes(np.arange(5), beta, rho, d, m)
    for a, b in rng.uniform(-0.8, 0.8, (12, 2)):
        f, g, _ = uj._hole_terms(holes, a, b, second=True)
        f_ref, ga, gb = uj.subjoint_cable_length_grad(a, b, beta, rho, d)
        np.testing.assert_allclose(f, m * uj.subjoint_cable_length(a, b, beta, rho, d), rtol=1e-13)
        np.testing.assert_allclose(f, m * f_ref, rtol=1e-13)
        np.testing.assert_allclose(g, m * np.array([ga, gb]), rtol=1e-9, atol=1e-11)
        # without the second derivatives: the same values (to the round-off of another product)
        np.testing.assert_allclose(uj._hole_lengths(holes, a, b), f, rtol=1e-13)
        np.testing.assert_allclose(uj._hole_terms(holes, a, b)[1], g, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("seed", [0, 1])
def test_cable_hessian_matches_central_differences_of_the_jacobian(arm, seed):
    h = 1e-5
    for theta in poses(4, seed):
        J, H = uj.cable_jacobian_hessian(arm, theta)
        # Two evaluation paths of the same closed form (eq. 4's derivative, a few tens of flops a
        # term, condition ~1): numpy may order or fuse the flops differently (SIMD, FMA), so they
        # agree to a few ulps of the largest entry, not bit for bit. 64 eps bounds that generously.
        J_ref = uj.cable_jacobian(arm, theta)
        np.testing.assert_allclose(
            J, J_ref, rtol=0, atol=64 * np.finfo(float).eps * np.abs(J_ref).max()
        )
        t = theta.ravel()
        H_fd = np.zeros_like(H)
        for j in range(t.size):
            tp, tm = t.copy(), t.copy()
            tp[j] += h
            tm[j] -= h
            H_fd[:, :, j] = (
                uj.cable_jacobian(arm, tp.reshape(2, 2)) - uj.cable_jacobian(arm, tm.reshape(2, 2))
            ) / (2 * h)
        np.testing.assert_allclose(H, H_fd, atol=1e-6 * np.abs(H).max())
        np.testing.assert_array_equal(H, H.transpose(0, 2, 1))
        # block diagonal: the cables of segment 1 do not see segment 2's angles
        assert not H[arm.own_cables[0]][:, 2:, :].any()


def test_cable_path_lengths_sum_literal_eq4_over_passed_subjoints(arm):
    for theta in poses(5, 2):
        expected = np.zeros(arm.n_cables)
        for k, c in enumerate(arm.cables):
            for i in range(c.segment + 1):
                seg = arm.segments[i]
                expected[k] += seg.n_subjoints * float(
                    uj.subjoint_cable_length(
                        theta[i, 0],
                        theta[i, 1],
                        c.hole_angle_rad,
                        c.hole_radius_mm,
                        seg.half_gap_mm,
                    )
                )
        np.testing.assert_allclose(uj.cable_path_lengths(arm, theta), expected, rtol=1e-13)


# --------------------------------------------------------------------------- eq. 10
def pinv_newton(lengths, beta, rho, d, m, guess):
    """Eq. 10 as first written: theta += pinv(J_d) (l_d - f) until the step is below tolerance."""
    th = np.array(guess, dtype=float)
    for _ in range(uj.NEWTON_MAX_ITER):
        f, J = uj.segment_cable_jacobian(th[0], th[1], beta, rho, d, m)
        step = np.linalg.pinv(J) @ (lengths - f)
        big = float(np.max(np.abs(step)))
        if big > 0.3:
            step *= 0.3 / big
        th = th + step
        if float(np.max(np.abs(step))) < uj.NEWTON_STEP_TOL_RAD:
            return th
    raise AssertionError("reference did not converge")


def test_normal_equation_newton_equals_pseudo_inverse_newton(arm):
    own = arm.own_cables[1]
    seg = arm.segments[1]
    args = (arm.betas[own], arm.rhos[own], seg.half_gap_mm, seg.n_subjoints)
    rng = np.random.default_rng(4)
    for theta in poses(6, 3, scale=0.3):
        exact = uj.segment_cable_lengths(theta[1, 0], theta[1, 1], *args)
        stretched = exact + rng.normal(0.0, 0.05, exact.shape)  # inconsistent: least squares
        for lengths in (exact, stretched):
            for guess in (np.zeros(2), theta[1] + 0.01):
                got = uj.solve_segment_angles(lengths, *args, guess)
                np.testing.assert_allclose(
                    got, pinv_newton(lengths, *args, guess), rtol=0, atol=1e-12
                )
        np.testing.assert_allclose(
            uj.solve_segment_angles(exact, *args), theta[1], rtol=0, atol=1e-12
        )


# --------------------------------------------------------------------------- statics
def fd_statics(arm, theta_pre):
    """The statics with the pretension's geometric stiffness from central differences of the
    Jacobian (the formulation the analytic Hessian replaced)."""
    t0 = theta_pre.ravel()
    n = t0.size
    J = uj.cable_jacobian(arm, theta_pre)
    L_hess = np.zeros((arm.n_cables, n, n))
    for j in range(n):
        tp, tm = t0.copy(), t0.copy()
        tp[j] += FD_STEP_RAD
        tm[j] -= FD_STEP_RAD
        dJ = uj.cable_jacobian(arm, tp.reshape(-1, 2)) - uj.cable_jacobian(arm, tm.reshape(-1, 2))
        L_hess[:, :, j] = dJ / (2.0 * FD_STEP_RAD)
    L_hess = 0.5 * (L_hess + L_hess.transpose(0, 2, 1))
    x, T = uj.small_deflection(
        t0,
        J,
        arm.cable_stiffness_N_per_mm,
        arm.pretension_N,
        L_hess,
        np.zeros((n, n)),
        np.zeros(n),
        lambda x: uj.gravity_torque(arm, x.reshape(-1, 2)),
        uj.gravity_hessian(arm, theta_pre),
    )
    return x.reshape(-1, 2), T


@pytest.mark.parametrize("gravity", [(-9810.0, 0.0, 0.0), (0.0, 0.0, 0.0)])
def test_statics_equals_finite_difference_formulation(arm, gravity):
    a = uneven(arm, gravity)
    for theta in poses(4, 5, scale=0.1):
        th, T = uj.statics_angles(a, theta)
        th_ref, T_ref = fd_statics(a, theta)
        np.testing.assert_allclose(th, th_ref, rtol=0, atol=1e-11)
        np.testing.assert_allclose(T, T_ref, rtol=0, atol=1e-6)
        assert np.abs(th - theta).max() > 1e-6  # the statics moved the pose


def test_statics_with_slack_cables_equals_finite_difference_formulation(arm):
    # a fourth, lightly pretensioned cable in segment 1 on the lower side of a horizontal arm:
    # its weight-induced stretch releases it (the active set changes), the other three hold
    heavy = replace(arm, gravity_mm_s2=(-9810.0, 0.0, 0.0))
    extra = replace(arm.cables[0], name="c14", hole_angle_rad=math.pi, pretension_N=10.0)
    loose = replace(heavy, cables=(*arm.cables[:3], extra, *arm.cables[3:]))
    th, T = uj.statics_angles(loose, np.zeros((2, 2)))
    th_ref, T_ref = fd_statics(loose, np.zeros((2, 2)))
    assert T[3] == 0.0 and (T[np.arange(7) != 3] > 0.0).all()
    np.testing.assert_allclose(th, th_ref, rtol=0, atol=1e-11)
    np.testing.assert_allclose(T, T_ref, rtol=0, atol=1e-6)


# --------------------------------------------------------------------------- truth
def test_truth_warm_start_changes_nothing(arm):
    a = uneven(arm, (0.0, 0.0, 0.0))
    eff = uj.UJointEffects(friction_driven_deformation=True)
    s = np.concatenate((np.linspace(0, 1, 25), np.linspace(1, 0, 25)[1:]))
    state = None
    for v in s:
        q = uj.cable_displacements(a, np.array([[0.02 * v, 0.1 * v], [-0.01 * v, 0.1 * v]]))
        warm, new_state = uj.truth_angles(a, q, state, eff)
        if state is not None:
            assert new_state.theta_coupled is not None
            cold, _ = uj.truth_angles(a, q, replace(state, theta_coupled=None), eff)
            np.testing.assert_allclose(warm, cold, rtol=0, atol=1e-12)
        state = new_state


def test_segment_transform_is_the_mth_power_of_the_subjoint(arm):
    seg = arm.segments[0]
    for a, b in poses(3, 6).reshape(-1, 2)[:4]:
        np.testing.assert_allclose(
            uj.segment_transform(a, b, seg),
            np.linalg.matrix_power(uj.subjoint_transform(a, b, seg), seg.n_subjoints),
            rtol=0,
            atol=1e-12,
        )
