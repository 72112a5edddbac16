"""The force-transfer chain's hot paths against their equations.

``TensionChain.cable`` against the stretch of Qi et al. 2023 eq. 33-36 (the tension chain's
sums, to rounding), ``_along`` assembling ``cable``'s values, the chord geometry against the
segment shortening and its gradient written from :func:`~cdcr_ctl.model.cc_disk.kinematics.s1` and
``d1``, the pulley table's inverse against its per-piece formula. The two kept pairs, the disk
weight sums against the kinematics ratios (:func:`~cdcr_ctl.model.cc_disk.kinematics.s1`,
``c2``, ``d1``, ``d2``; to rounding) and the pulley's fused ``to_actuator_stretch`` against its
two calls (the same floats): their measurement is printed by ``benchmarks/bench_hot_paths.py``
(docs/performance/figures.md).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from cc_robots import make_robot, qi_params, three_params

from cdcr_ctl.model.cc_disk.kinematics import c2, d1, d2, s1
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer, _disk_sums
from cdcr_ctl.model.shared import capstan as cap

ROBOTS = [qi_params, three_params, lambda: make_robot(2, thickness_mm=1.5)]


def _poses(S: int, n: int, seed: int) -> list[list[float]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        th = rng.choice([0.0, 1e-4, 0.05, 0.4, 1.4], size=S) * rng.random(S)
        ph = rng.uniform(-3.0, 3.0, size=S)
        out.append(np.column_stack((th * np.cos(ph), th * np.sin(ph))).ravel().tolist())
    return out


@pytest.mark.parametrize("robot", ROBOTS)
@pytest.mark.parametrize("geometry", ["cc", "chord"])
def test_cable_and_along_equal_outside_and_inside(robot, geometry):
    p = robot()
    ft = ForceTransfer(p, Effects(geometry=geometry))
    rng = np.random.default_rng(3)
    for xs in _poses(p.n_segments, 25, 1):
        P = ft.pose(xs)
        s = rng.choice([1.0, -1.0, 0.0, 0.37, -0.6], size=p.n_cables).tolist()
        Fb, Eb = ft.factors(P, s)
        T = ft.statics(P, Fb)
        res = ft._along(P, Fb, Eb, T, s)
        for k in range(p.n_cables):
            for Tk in (T[k], 0.0, 0.5 * T[k], 3.0 * T[k]):
                tb = Tk * math.exp(Eb[k])
                ta, do = ft.outside(k, tb, s[k])
                iEA, T0 = ft._iEA[k], ft._T0[k]
                d_in = sum(ft._l[i] * (Tk * f - T0) for i, f in enumerate(Fb[k])) * iEA
                wk = P.q_geom[k] + d_in
                got = ft.cable(P, k, Tk, s[k], Fb[k], Eb[k])
                assert got[:2] == (tb, ta)
                # the same sum in the same order: equal to rounding of |q| (mm)
                assert got[2:] == pytest.approx((wk, wk + do), rel=1e-14, abs=1e-12)
            tb, ta, wk, qk = ft.cable(P, k, T[k], s[k], Fb[k], Eb[k])
            assert (res.T_base[k], res.T_actuator[k], res.w[k], res.q[k]) == (tb, ta, wk, qk)
            assert (res.delta_in[k], res.delta_out[k]) == (wk - P.q_geom[k], qk - wk)


def test_disk_sums_equal_the_kinematics_ratios():
    disks = [(m / 5, 0.8 + 0.1 * m) for m in range(1, 6)]
    factors = [
        (sig, m * sig * sig, m * sig * sig * sig, m * sig * sig * sig * sig, m * sig)
        for sig, m in disks
    ]
    # Both evaluate the same series (|t| < 0.1) or closed forms with a different grouping (a
    # product by 1/t^k against a division by t^k, Horner against powers): each ratio within a
    # few roundings (~10 operations, 2**-53 each: < 2e-15 relative). The terms of each sum have
    # one sign for |sig t| < 4.49 (c2, s1 > 0; d1, d2 < 0), so no cancellation: 1e-14 relative.
    for t in (0.0, 1e-9, 0.03, 0.0999, 0.1, 0.2, 0.49, 0.5, 0.51, 1.3, 3.0, -0.7):
        A = B = C = D = 0.0
        for sig, m in disks:
            st = sig * t
            ms2 = m * sig * sig
            A += ms2 * c2(st)
            B += ms2 * sig * sig * d2(st)
            C += ms2 * sig * d1(st)
            D += m * sig * s1(st)
        assert _disk_sums(factors, t) == pytest.approx((A, B, C, D), rel=1e-14, abs=0.0)
    # at the straight pose, the series' constant terms: sum m sig^2 / 2, -m sig^4 / 12, ...
    A, B, C, D = _disk_sums(factors, 0.0)
    assert A == pytest.approx(sum(f[1] for f in factors) / 2.0, rel=1e-15)
    assert B == pytest.approx(-sum(f[3] for f in factors) / 12.0, rel=1e-15)
    assert C == pytest.approx(-sum(f[2] for f in factors) / 3.0, rel=1e-15)
    assert D == pytest.approx(sum(f[4] for f in factors), rel=1e-15)


@pytest.mark.parametrize("thickness", [0.0, 2.0])
def test_chord_factors_equal_s1_and_d1(thickness):
    p = make_robot(2, thickness_mm=thickness)
    ft = ForceTransfer(p, Effects(geometry="chord"))
    for xs in _poses(2, 40, 7):
        P = ft.pose(xs)
        for k in range(p.n_cables):
            c = p.cables[k]
            ex = c.routing_radius_mm * math.cos(c.hole_angle_rad)
            ey = c.routing_radius_mm * math.sin(c.hole_angle_rad)
            qk = 0.0
            for i in range(c.segment + 1):
                seg = p.segments[i]
                n, L, tk = seg.n_disks, seg.length_mm, seg.disk_thickness_mm
                X, Y = xs[2 * i], xs[2 * i + 1]
                t = P.theta[i]
                ux, uy = (X / t, Y / t) if t > 0.0 else (1.0, 0.0)
                a = 0.5 * t / n
                sa = s1(a)
                h = math.sin(0.5 * a)
                base = L * (1.0 - sa) - 2.0 * n * tk * h * h
                qk += base + 2.0 * n * math.sin(a) * (ex * ux + ey * uy)
                f = d1(a) / (4.0 * n * n) * (ex * X + ey * Y - L) - tk * sa / (4.0 * n)
                assert P.arm[k][i] == (f * X + sa * ex, f * Y + sa * ey)
            assert P.q_geom[k] == qk


@pytest.mark.parametrize("n", [0.67, 0.5])
def test_table_inverse_pieces_equal_the_per_piece_formula(n):
    # lower_high's solve on piece j: y = (ln T_high - frac (a_j - m_j y_j)) / (1 + frac m_j),
    # m_j = (a_{j+1} - a_j) / dx, y_j = x0 + j dx, formed at load time: the same floats
    tr = cap.PulleyTransfer(8.0, 1.5708, 0.3, n, 0.4)
    tab, x0, dx = tr._lnk_tab, tr._x0, tr._dx
    assert len(tr._pieces) == len(tab) - 1
    for j, (m, c) in enumerate(tr._pieces):
        m_j = (tab[j + 1] - tab[j]) / dx
        assert (m, c) == (m_j, tab[j] - m_j * (x0 + j * dx))
    for T_high in np.geomspace(1e-5, 1e5, 157):
        for frac in (0.0, 0.7, 1.0):
            y = math.log(tr.lower_high(float(T_high), frac))
            assert y + frac * tr.ln_kappa(math.exp(y)) == pytest.approx(math.log(T_high), abs=1e-12)


@pytest.mark.parametrize("n", [1.0, 0.67, None])
def test_to_actuator_stretch_equals_the_two_calls_across_the_table(n):
    tr = cap.PulleyTransfer(8.0, 1.5708, 0.0 if n is None else 0.3, n or 1.0, 0.4)
    for T in np.concatenate((-np.geomspace(1e-3, 10.0, 5), [0.0], np.geomspace(1e-5, 1e5, 301))):
        T = float(T)
        for s in (-1.0, -0.7, -0.4, -0.0, 0.0, 0.3, 1.0):
            Tn = tr.to_actuator(T, s)
            assert tr.to_actuator_stretch(T, s, 2.0) == (Tn, tr.stretch_integral(Tn, T, s, 2.0))
