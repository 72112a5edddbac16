"""Compensation at motion reversals (Qi et al. 2023 eq. 17-19, 36-37) against the forward truth.

The forward model (:class:`ForwardStepper`) is the simulator's truth: friction with stick at
reversals, elastic cables. Driven by the compensator's own commands (same parameters), the robot
must follow the desired pose through a reversal; with the friction sign of the paper's
sgn(q_dot) taken the wrong way round at the reversal it would not.
"""

from __future__ import annotations

import numpy as np
import pytest
from cc_robots import qi_params

from cdcr_ctl.model.cc_disk.compensation import CCDiskModel, Compensator
from cdcr_ctl.model.cc_disk.forward import ForwardStepper
from cdcr_ctl.model.cc_disk.params import Effects

EFF = Effects(geometry="chord", capstan_points=41)


def _go_and_back(n: int = 12) -> list[np.ndarray]:
    up = np.linspace(0.05, 1.0, n)
    down = np.linspace(1.0, 0.4, n)[1:]
    return [np.array([[th, 0.0]]) for th in (*up, *down)]


def test_pulling_in_needs_more_cable_than_paying_out_at_one_pose():
    """Same pose, reached pulling in (s = +1) or paying out (s = -1): the pulled-in command is
    longer (friction adds tension to be stretched), the dead zone is positive for every cable
    that carries load, and it vanishes with zero friction."""
    comp = Compensator(qi_params(), EFF)
    psi = [[0.9, 0.3]]
    pull = np.asarray(comp.compensate(psi, [1.0, 1.0, 1.0]).q)
    pay = np.asarray(comp.compensate(psi, [-1.0, -1.0, -1.0]).q)
    assert np.all(pull - pay > 0.01)
    frictionless = Compensator(
        qi_params(), Effects(geometry="chord", disk_friction=False, pulley_friction=False)
    )
    a = np.asarray(frictionless.compensate(psi, [1.0, 1.0, 1.0]).q)
    b = np.asarray(frictionless.compensate(psi, [-1.0, -1.0, -1.0]).q)
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_compensated_commands_make_the_truth_follow_through_a_reversal():
    p = qi_params()
    model = CCDiskModel(p, EFF)
    truth = ForwardStepper(p, EFF)
    st = model.new_state()
    path = _go_and_back()
    errs, s_hist = [], []
    for psi in path:
        q = model.q_command(psi, model.q_nominal(psi), st, "model", None)
        res = truth.step(q)
        errs.append(float(np.linalg.norm(res.tip_mm - model.tip(psi))))
        s_hist.append(tuple(st.s))
    # exact inverse of the truth (same parameters): the tip is where it was asked to be
    assert max(errs) < 1e-5
    # c1 is pulled in on the way up and paid out on the way down, c2 and c3 the other way
    assert s_hist[5] == (1.0, -1.0, -1.0)
    assert s_hist[-1] == (-1.0, 1.0, 1.0)
    # ... and the truth's friction agrees in sign with the compensator's
    assert tuple(np.sign(truth.state.s)) == s_hist[-1]


def test_wrong_friction_sign_at_the_reversal_leaves_the_robot_stuck():
    """Keeping the up-leg sign on the way down (no hysteresis handling) leaves the truth in its
    dead zone: the tip misses the desired pose by far more than the compensated run does."""
    p = qi_params()
    model = CCDiskModel(p, EFF)
    truth = ForwardStepper(p, EFF)
    path = _go_and_back()
    errs = []
    for j, psi in enumerate(path):
        q = np.asarray(model.compensate(psi, [1.0, -1.0, -1.0]).q)
        res = truth.step(q)
        if j >= 12:
            errs.append(float(np.linalg.norm(res.tip_mm - model.tip(psi))))
    assert max(errs) > 0.3


def test_reversal_band_bounds_the_command_step_and_keeps_the_sign():
    """With a band the flip is spread over that much cable travel: no command step larger than
    the motion plus the dead zone times (travel / 2 band), and the final sign is the same."""
    p = qi_params()
    sharp = CCDiskModel(p, EFF)
    soft = CCDiskModel(p, EFF, reversal_band_mm=0.05)
    s1, s2 = sharp.new_state(), soft.new_state()
    thetas = [*np.linspace(0.2, 1.0, 9), *np.linspace(0.995, 0.9, 20)]
    q_sharp, q_soft = [], []
    for th in thetas:
        psi = np.array([[th, 0.0]])
        q_sharp.append(sharp.q_command(psi, sharp.q_nominal(psi), s1, "model", None))
        q_soft.append(soft.q_command(psi, soft.q_nominal(psi), s2, "model", None))
    step_sharp = np.max(np.abs(np.diff(np.array(q_sharp)[8:], axis=0)))
    step_soft = np.max(np.abs(np.diff(np.array(q_soft)[8:], axis=0)))
    assert step_soft < 0.5 * step_sharp
    assert s1.s == s2.s == [-1.0, 1.0, 1.0]
    np.testing.assert_allclose(q_soft[-1], q_sharp[-1], atol=1e-9)


@pytest.mark.parametrize("bias_N", [0.3, -0.3])
def test_measured_mode_ignores_a_common_tension_offset(bias_N):
    """Load cells reading every tension high (or low) by the same amount must not pull (or pay
    out) every cable: that common mode has no moment and would feed back with gain ~1. The
    bending part of the readings is used: a cell reading more on one cable moves the command."""
    p = qi_params()
    comp = Compensator(p, EFF)
    psi = [[0.9, 0.0]]
    s = [1.0, -1.0, -1.0]
    model = comp.compensate(psi, s)
    meas = np.asarray(model.T_base)
    biased = comp.compensate(psi, s, "measured", list(meas + bias_N))
    # fed forward as measured, the offset would add about 0.3 N * 240 mm / 2493 N = 0.029 mm to
    # every cable; pinned, only its small moment-carrying part (friction differs per cable) stays
    np.testing.assert_allclose(biased.q, model.q, atol=6e-3)
    exact = comp.compensate(psi, s, "measured", list(meas))
    np.testing.assert_allclose(exact.q, model.q, atol=1e-10)
    one = meas.copy()
    one[0] += 1.0
    more = comp.compensate(psi, s, "measured", list(one))
    assert more.q[0] > model.q[0] + 0.02
