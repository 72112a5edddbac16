"""Compensation q~ = q + delta (Qi et al. 2023 eq. 37) and the loop's model port."""

from __future__ import annotations

import math

import numpy as np
import pytest
from cc_robots import make_robot, qi_params, three_params

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.compensation import CCDiskModel, Compensator
from cdcr_ctl.model.cc_disk.kinematics import tip_position
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.model.cc_disk.routing import cable_displacement

PSI3 = np.array([[0.8, 0.4], [0.6, 2.2], [1.1, -0.9]])
RIGID_NO_FRICTION = Effects(disk_friction=False, pulley_friction=False, elongation=False)


@pytest.mark.parametrize("gravity", [False, True])
def test_zero_friction_and_rigid_cables_give_zero_delta_exactly(gravity):
    p = three_params()
    comp = Compensator(p, Effects(disk_friction=False, pulley_friction=False, elongation=False,
                                  gravity=gravity))  # fmt: skip
    for s in ([1.0] * 9, [-1.0] * 9, [0.3] * 9):
        res = comp.compensate(PSI3, s)
        assert res.q == res.q_geom  # bit for bit
        assert all(d == 0.0 for d in res.delta_in + res.delta_out)
    np.testing.assert_allclose(res.q_geom, cable_displacement(PSI3, p), atol=1e-13)


def test_rigid_cables_with_friction_still_give_zero_delta_but_tension_loss():
    p = qi_params()
    comp = Compensator(p, Effects(elongation=False))
    psi = [[1.0, 0.0]]
    pull = comp.compensate(psi, [1.0, -1.0, -1.0])
    assert pull.q == pull.q_geom
    assert pull.T_actuator[0] > pull.T_base[0] > pull.T_distal[0]  # pulled: friction adds
    assert pull.T_actuator[1] < pull.T_base[1] < pull.T_distal[1]  # paid out: friction subtracts


def test_compensation_sign_pulling_in_vs_paying_out():
    p = qi_params()
    comp = Compensator(p, Effects())
    psi = [[1.0, 0.0]]  # bend towards cable c1
    pull = comp.compensate(psi, [1.0, -1.0, -1.0])
    d = np.asarray(pull.q) - np.asarray(pull.q_geom)
    assert d[0] > 0  # the stretched pulling cable must be pulled in further
    assert d[1] < 0 and d[2] < 0  # the others run below pretension at the base: pay out more
    back = comp.compensate(psi, [-1.0, 1.0, 1.0])  # same pose reached while unbending
    # dead zone: at one pose the command differs by direction; pulling needs more cable
    assert np.all(np.asarray(pull.q) - np.asarray(back.q) > np.array([0.0, -np.inf, -np.inf]))
    assert pull.q[0] - back.q[0] > 0.05
    assert back.q[1] > pull.q[1] and back.q[2] > pull.q[2]


def test_measured_tensions_replace_modelled_ones():
    p = three_params()
    locs = ["actuator"] * 3 + ["robot_base"] * 6
    comp = Compensator(p, Effects(), locations=locs)
    s = [1.0, -1.0, -1.0] * 3
    model = comp.compensate(PSI3, s)
    meas = [model.T_at(k, loc) for k, loc in enumerate(locs)]
    same = comp.compensate(PSI3, s, "measured", meas)
    np.testing.assert_allclose(same.q, model.q, atol=1e-10)
    np.testing.assert_allclose(same.T_distal, model.T_distal, rtol=1e-9)
    meas2 = list(meas)
    meas2[0] = float("nan")  # a missing cell falls back to the model
    meas2[4] *= 1.5  # a higher tension stretches the cable more
    mixed = comp.compensate(PSI3, s, "measured", meas2)
    assert mixed.q[0] == pytest.approx(model.q[0], abs=1e-10)
    assert mixed.q[4] > model.q[4]
    with pytest.raises(ModelError):
        comp.compensate(PSI3, s, "measured")


def test_stateful_step_keeps_friction_when_holding_and_flips_on_reversal():
    p = qi_params()
    comp = Compensator(p, Effects())
    st = comp.new_state()
    for th in np.linspace(0.1, 1.0, 10):
        res = comp.step([[th, 0.0]], st)
    assert st.s == [1.0, -1.0, -1.0]
    q_hold = list(res.q)
    for _ in range(3):  # holding: same state, same command (stick memory)
        res = comp.step([[1.0, 0.0]], st)
    assert st.s == [1.0, -1.0, -1.0] and res.q == q_hold
    res = comp.step(
        [[0.99, 0.0]], st
    )  # reversal: friction flips, the command crosses the dead zone
    assert st.s == [-1.0, 1.0, 1.0]
    assert res.q[0] < q_hold[0] - 0.05


def test_reversal_band_spreads_the_flip():
    p = qi_params()
    comp = Compensator(p, Effects(), reversal_band_mm=0.5)
    st = comp.new_state()
    comp.step([[0.5, 0.0]], st)
    comp.step([[0.6, 0.0]], st)
    assert st.s[0] == 1.0
    comp.step([[0.59, 0.0]], st)
    assert -1.0 < st.s[0] < 1.0


class _Scale:
    """A test actuator effect: the actuator drives (1 + e) times the cable displacement."""

    def __init__(self, e: float) -> None:
        self.e = e

    def new_state(self, n_cables: int) -> None:
        return None

    def to_cable(self, q_act_mm, state):
        return np.asarray(q_act_mm) * (1.0 + self.e)

    def to_actuator(self, q_cable_mm, state):
        return np.asarray(q_cable_mm) / (1.0 + self.e)


def test_loop_port_calls():
    p = three_params()
    model = CCDiskModel(p, Effects(actuator=(_Scale(0.02),)))
    assert model.n_segments == 3 and model.n_cables == 9
    st = model.new_state()
    q_nom = model.q_nominal(PSI3)
    np.testing.assert_allclose(q_nom, cable_displacement(PSI3, p), atol=1e-13)
    # "off" sends the bare geometry: no transmission effect either (issue #17: the dead zone's
    # pre-travel is compensation; the memories are still tracked)
    q_off = model.q_command(PSI3, q_nom, st, "off", None)
    np.testing.assert_array_equal(q_off, q_nom)
    q_mod = model.q_command(PSI3, q_nom, st, "model", None)
    last = st.last
    np.testing.assert_allclose(q_mod * 1.02, q_nom + np.asarray(last.q) - last.q_geom, atol=1e-12)
    np.testing.assert_allclose(model.tip(PSI3), tip_position(PSI3, p.lengths_mm), atol=1e-12)
    with pytest.raises(ModelError):
        model.q_command(PSI3, q_nom, object(), "model", None)
    with pytest.raises(ModelError):
        model.q_command(PSI3, q_nom, st, "bogus", None)


def test_unreachable_moment_raises_model_error():
    # two cables only in one segment: they cannot bend it away from both holes
    from dataclasses import replace

    p = make_robot(1)
    p2 = replace(p, cables=p.cables[:2])
    comp = Compensator(p2, RIGID_NO_FRICTION)
    with pytest.raises(ModelError):
        comp.compensate([[0.5, math.radians(240.0)]], [1.0, 1.0])
