"""Improved capstan (Qi et al. 2023 eq. 25-32): check value, limits, tables, paying out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdcr_ctl.model.shared import capstan as cap


def test_ratio_is_one_at_zero_wrap():
    for rho, alpha, n in [(10, 0.6, 1.0), (1, 0.15, 0.67), (20, 0.3, 0.8)]:
        assert cap.improved_ratio(rho, alpha, n, 0.0) == 1.0
        prof = cap.solve_profile(rho, alpha, n, np.linspace(0, 1, 5), T1=2.0)
        assert prof.kappa[0] == pytest.approx(1.0, abs=1e-12)


def test_notes_check_value():
    # NOTES: rho = 10, alpha = 0.6, n = 1 -> kappa(pi) ~ 5.15 vs classical exp(0.6 pi) ~ 6.59
    assert cap.improved_ratio(10.0, 0.6, 1.0, math.pi) == pytest.approx(5.1507, abs=5e-4)
    assert cap.classical_ratio(0.6, math.pi) == pytest.approx(6.5861, abs=5e-4)


def test_ode_path_matches_exact_linear_solution():
    phi = np.linspace(0, math.pi, 7)
    exact = cap.solve_profile(10.0, 0.6, 1.0, phi)
    ode = cap.solve_profile(10.0, 0.6, 1.0 - 1e-9, phi)  # forces the numerical path
    np.testing.assert_allclose(ode.kappa, exact.kappa, rtol=1e-6)
    np.testing.assert_allclose(ode.int_T, exact.int_T, rtol=1e-6)


def test_limit_rigidity_free_linear_friction_is_classical():
    target = math.exp(0.6 * math.pi)
    prev = 0.0
    for rho in (1e1, 1e2, 1e4, 1e6):
        k = cap.improved_ratio(rho, 0.6, 1.0, math.pi)
        assert prev < k < target  # increases towards the classical capstan
        prev = k
    assert prev == pytest.approx(target, rel=1e-5)


@pytest.mark.parametrize("rho", [1.0, 5.0, 20.0, 100.0])
@pytest.mark.parametrize("alpha", [0.15, 0.6])
def test_improved_loses_less_than_classical(rho, alpha):
    for phi in (0.5, 1.5, math.pi):
        classical = cap.classical_ratio(alpha, phi)
        assert 1.0 < cap.improved_ratio(rho, alpha, 1.0, phi) < classical
        # non-linear friction (fig. 9, output tension 1 N)
        assert 1.0 < cap.improved_ratio(rho, alpha, 0.67, phi, T1=1.0) < classical


def test_pulley_table_matches_direct_solution_off_grid():
    tr = cap.PulleyTransfer(8.0, 1.5708, 0.15, 0.67, 0.4)
    for T in (0.013, 0.57, 2.3, 10.7, 53.0):
        direct = cap.improved_ratio(20.0, 0.15, 0.67, 1.5708, T)
        assert math.exp(tr.ln_kappa(T)) - 1.0 == pytest.approx(direct - 1.0, rel=2e-3)
        prof = cap.solve_profile(20.0, 0.15, 0.67, 1.5708, T)
        assert tr.mean_ratio(T) == pytest.approx(prof.int_T[-1] / (1.5708 * T), rel=1e-4)


@pytest.mark.parametrize(
    ("rho", "wrap", "alpha", "n"), [(20.0, 1.5708, 0.15, 0.67), (10.0, math.pi, 0.6, 0.5)]
)
def test_stacked_table_is_each_grid_tensions_own_solution(rho, wrap, alpha, n):
    """The table's one stacked integration against one LSODA solve per grid tension: both at
    rtol 1e-10, so they agree to ~1e-9 (a few steps' worth of the tolerance); 1e-8 allows it."""
    lnk, mean = cap._tension_table(rho, wrap, alpha, n, 25)
    grid = np.exp(np.linspace(math.log(cap.TABLE_T_MIN_N), math.log(cap.TABLE_T_MAX_N), 25))
    for i in (0, 7, 12, 19, 24):
        prof = cap.solve_profile(rho, alpha, n, wrap, float(grid[i]))
        assert lnk[i] == pytest.approx(math.log(prof.kappa[-1]), abs=1e-8)
        assert mean[i] == pytest.approx(prof.int_T[-1] / (wrap * grid[i]), rel=1e-8)


@pytest.mark.parametrize("n", [1.0, 0.67])
def test_paying_out_inverts_the_ratio(n):
    tr = cap.PulleyTransfer(8.0, 1.5708, 0.3, n, 0.4)
    T = 3.0
    up = tr.to_actuator(T, 1.0)  # pulling in: actuator side high
    assert up == pytest.approx(T * math.exp(tr.ln_kappa(T)))
    down = tr.to_actuator(T, -1.0)  # paying out: robot side high
    assert down < T
    assert tr.to_actuator(down, 1.0) == pytest.approx(T, rel=1e-12)  # kappa(T_low) T_low = T
    for s in (-1.0, -0.4, 0.0, 0.3, 1.0):
        assert tr.to_robot(tr.to_actuator(T, s), s) == pytest.approx(T, rel=1e-12)


def test_frictionless_pulley_and_stretch_integral():
    tr = cap.PulleyTransfer(8.0, 1.0, 0.0, 1.0, 0.4)
    assert tr.to_actuator(5.0, 1.0) == 5.0
    assert tr.stretch_integral(5.0, 5.0, 1.0, 2.0) == pytest.approx(3.0 * 8.4 * 1.0)
    lin = cap.PulleyTransfer(8.0, 1.0, 0.6, 1.0, 0.4)
    prof = cap.solve_profile(lin.rho, 0.6, 1.0, 1.0, 2.0)
    full = lin.stretch_integral(lin.to_actuator(2.0, 1.0), 2.0, 1.0, 0.0)
    assert full == pytest.approx(prof.int_T[-1] * 8.4, rel=1e-12)
    # partly mobilised: between uniform and fully sliding
    part = lin.stretch_integral(lin.to_actuator(2.0, 0.5), 2.0, 0.5, 0.0)
    assert 2.0 * 8.4 < part < full


@pytest.mark.parametrize("n", [1.0, 0.67])
def test_lower_high_inverts_raise_low_across_the_table_and_beyond_its_edges(n):
    # the table spans 1e-3 .. 1e3 N: below, inside (on and between grid points) and above it
    tr = cap.PulleyTransfer(8.0, 1.5708, 0.3, n, 0.4)
    for T_high in np.geomspace(1e-5, 1e5, 157):
        for frac in (0.0, 0.2, 0.7, 1.0):
            low = tr.lower_high(float(T_high), frac)
            assert low <= T_high * (1.0 + 1e-14)  # exp(ln T) rounds
            assert tr.raise_low(low, frac) == pytest.approx(T_high, rel=1e-13)
