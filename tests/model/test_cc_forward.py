"""Forward static model: it inverts the compensation, freezes in stick, slides, goes slack."""

from __future__ import annotations

import numpy as np
import pytest
from cc_robots import make_robot, qi_params, three_params

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.compensation import Compensator
from cdcr_ctl.model.cc_disk.forward import ForwardModel, ForwardStepper
from cdcr_ctl.model.cc_disk.kinematics import psi_to_x
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.model.shared.friction import FrictionState

ELASTIC_ONLY = Effects(disk_friction=False, pulley_friction=False)


def _poses(S, n, seed):
    rng = np.random.default_rng(seed)
    return [np.column_stack((rng.uniform(0, 1.5, S), rng.uniform(-3, 3, S))) for _ in range(n)]


@pytest.mark.parametrize("geometry", ["cc", "chord"])
def test_everything_off_inverts_the_inverse_model(geometry):
    for p in (qi_params(), three_params()):
        eff = Effects(
            disk_friction=False, pulley_friction=False, elongation=False, coupling=False,
            gravity=False, geometry=geometry,
        )  # fmt: skip
        comp, fwd = Compensator(p, eff), ForwardModel(p, eff)
        for psi in _poses(p.n_segments, 5, 1):
            q = np.asarray(comp.compensate(psi, [1.0] * p.n_cables).q)
            res = fwd.solve(q)
            np.testing.assert_allclose(res.x, psi_to_x(psi).ravel(), atol=1e-9)
            assert np.max(np.abs(res.q_geom_mm - q)) < 1e-6  # mm
            assert np.all(res.delta_mm == 0.0)


def test_elastic_forward_recovers_pose_and_tensions():
    p = three_params()
    comp, fwd = Compensator(p, ELASTIC_ONLY), ForwardModel(p, ELASTIC_ONLY)
    for psi in _poses(3, 4, 2):
        target = comp.compensate(psi, [0.0] * 9)
        res = fwd.solve(np.asarray(target.q))
        np.testing.assert_allclose(res.x, psi_to_x(psi).ravel(), atol=1e-9)
        np.testing.assert_allclose(res.tension_distal_N, target.T_distal, atol=1e-6)


def _track(p, effects, path, substeps=1):
    comp, stepper = Compensator(p, effects), ForwardStepper(p, effects)
    st = comp.new_state()
    q_prev = np.zeros(p.n_cables)
    errs, results = [], []
    for psi in path:
        q = np.asarray(comp.step(psi, st).q)
        for m in range(1, substeps + 1):
            res = stepper.step(q_prev + (q - q_prev) * m / substeps)
        q_prev = q
        errs.append(np.max(np.abs(res.x - psi_to_x(psi).ravel())))
        results.append(res)
    return np.array(errs), results


def test_all_effects_single_segment_tracks_through_reversals():
    p = qi_params()
    th = np.concatenate((np.linspace(0.05, 1.2, 12), np.linspace(1.1, 0.3, 9), [0.6, 0.9]))
    path = [np.array([[t, 0.4]]) for t in th]
    errs, results = _track(p, Effects(), path)
    assert errs.max() < 1e-8
    assert results[11].state.s == pytest.approx((1.0, -1.0, -1.0))
    assert results[13].state.s == pytest.approx((-1.0, 1.0, 1.0))


def test_all_effects_three_segments_track_monotone_path():
    p = three_params()
    path = [
        np.array([[0.6 * u, 0.5], [0.5 * u, 1.5], [0.8 * u, -1.0]]) for u in np.linspace(0.05, 1, 8)
    ]
    errs, _ = _track(p, Effects(), path)
    assert errs.max() < 1e-8


def test_stick_freezes_the_robot_across_the_dead_zone():
    p = qi_params()
    eff = Effects()
    comp = Compensator(p, eff)
    stepper = ForwardStepper(p, eff)
    st = comp.new_state()
    for t in np.linspace(0.05, 1.0, 10):
        q_pull = np.asarray(comp.step([[t, 0.0]], st).q)
        end = stepper.step(q_pull)
    x_end = end.x.copy()
    # the inverse model's dead zone at this pose: the command for arriving from above
    q_back = np.asarray(comp.compensate([[1.0, 0.0]], [-1.0, 1.0, 1.0]).q)
    assert q_back[0] < q_pull[0] - 0.05
    frozen = 0
    for lam in np.linspace(0.05, 0.95, 10):
        res = stepper.step(q_pull + lam * (q_back - q_pull))
        if all(m == "stick" for m in res.modes):
            frozen += 1
            np.testing.assert_allclose(res.x, x_end, atol=1e-10)  # no motion in stick
            assert all(-1.0 < v < 1.0 for v in res.state.s[:1])
    assert frozen >= 5  # most of the dead zone is pure stick: the actuators move, the robot not
    res = stepper.step(q_back)
    np.testing.assert_allclose(res.x, x_end, atol=1e-8)  # across the whole dead zone: same pose
    assert res.state.s[0] == pytest.approx(-1.0, abs=1e-9)


def test_stepping_is_rate_independent():
    p = qi_params()
    path = [np.array([[t, 0.3]]) for t in np.linspace(0.1, 1.0, 6)]
    _, coarse = _track(p, Effects(), path, substeps=1)
    _, fine = _track(p, Effects(), path, substeps=5)
    np.testing.assert_allclose(coarse[-1].x, fine[-1].x, atol=1e-9)
    np.testing.assert_allclose(coarse[-1].state.s, fine[-1].state.s, atol=1e-9)


def test_uncompensated_commands_bend_less():
    p = qi_params()
    comp, fwd = Compensator(p, Effects()), ForwardModel(p, Effects())
    psi = np.array([[1.0, 0.0]])
    q_nom = comp.q_geometric(psi)
    res = fwd.solve(q_nom, FrictionState.initial(3))
    assert res.psi[0, 0] < 1.0 - 0.02


def test_paid_out_cable_goes_slack():
    p = make_robot(1)
    fwd = ForwardModel(p, ELASTIC_ONLY)
    res = fwd.solve(np.array([0.0, -3.0, 0.0]))
    assert res.modes[1] == "slack" and res.tension_distal_N[1] == 0.0
    assert np.all(res.tension_distal_N >= 0.0)


def test_mixed_rigid_and_elastic_cables_rejected():
    from dataclasses import replace

    p = make_robot(1)
    p2 = replace(p, cables=(replace(p.cables[0], EA_N=float("inf")), *p.cables[1:]))
    with pytest.raises(ModelError):
        ForwardModel(p2, Effects())


class _Scale:
    """A test actuator effect: the cable moves (1 + e) times the actuator."""

    def __init__(self, e: float) -> None:
        self.e = e

    def new_state(self, n_cables: int) -> None:
        return None

    def to_cable(self, q_act_mm, state):
        return np.asarray(q_act_mm) * (1.0 + self.e)

    def to_actuator(self, q_cable_mm, state):
        return np.asarray(q_cable_mm) / (1.0 + self.e)


def test_actuator_effects_hook_in_simulator_and_compensation():
    p = qi_params()
    eff = Effects(actuator=(_Scale(0.05),))
    comp, stepper = Compensator(p, eff), ForwardStepper(p, eff)
    st = comp.new_state()
    for t in (0.3, 0.6):
        q_cable = np.asarray(comp.step([[t, 0.2]], st).q)
        res = stepper.step(comp.actuator_command(q_cable, st))
    np.testing.assert_allclose(res.x, psi_to_x(np.array([[0.6, 0.2]])).ravel(), atol=1e-8)


def test_infinitely_stiff_cables_are_rigid():
    p = make_robot(1, EA_N=float("inf"))
    res = Compensator(p, Effects()).compensate([[0.7, 0.3]], [1.0, -1.0, -1.0])
    assert res.q == res.q_geom
    out = ForwardModel(p, Effects()).solve(np.asarray(res.q))
    np.testing.assert_allclose(out.x, psi_to_x(np.array([[0.7, 0.3]])).ravel(), atol=1e-12)


def test_three_segment_reversal_transient_then_exact_again():
    # Distal cables load proximal segments through their friction-dependent mean tension there,
    # so while they cross their dead zones (stick) a proximal segment creeps: a bounded transient
    # at the reversal, exact tracking again once every cable slides.
    p = three_params()
    u = np.concatenate((np.linspace(0.05, 1.0, 12), np.linspace(0.95, 0.2, 16)))
    path = [np.array([[0.6 * v, 0.5], [0.5 * v, 1.5], [0.8 * v, -1.0]]) for v in u]
    errs, results = _track(p, Effects(), path, substeps=4)
    assert errs[:12].max() < 1e-8
    assert errs.max() < 0.05
    assert errs[-3:].max() < 1e-8
    assert all(m == "slide" for m in results[-1].modes)
