"""Joystick end-following as the loop's setpoint source: synchronised steps within the speed
limits, every joint following, the stick read between steps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.designs import follow_params, vertebra_arm
from cdcr_ctl.model.vertebra import EndFollowPlanner, cable_displacements
from cdcr_ctl.model.vertebra.follow import (
    SPEED_FRACTION,
    StickFrame,
    paper_session,
    plan_session,
)

CONFIG = Path(__file__).resolve().parents[2] / "config" / "vertebra.yaml"


@pytest.fixture(scope="module")
def session():
    cfg = load_rig_config(CONFIG)
    arm = vertebra_arm(cfg)
    planner = EndFollowPlanner(arm, follow_params(cfg))
    dt = 0.01
    t, psi, source = plan_session(planner, paper_session(scale=0.3), dt)
    q = np.array([cable_displacements(arm, p) for p in psi])
    return arm, t, psi, q, source, dt


def test_session_ends_at_the_commanded_distal_pose_with_every_joint_following(session):
    _, _, psi, _, source, _ = session
    target = source.planner.target
    np.testing.assert_allclose(psi[-1], target, atol=1e-9)
    # two "forward" presses: the steered distal poses moved down the arm
    modes = [r.mode for r in source.log]
    assert "follow" in modes and "steer" in modes
    assert target[0, 0] > target[-1, 0] > 0.0  # first steer (bent further) reached joint 1
    np.testing.assert_allclose(target[1], target[2], atol=1e-12)


def test_every_axis_within_its_speed_limit_and_steps_synchronised(session):
    arm, t, _, q, source, dt = session
    v_max = np.array([m.v_max_mm_s for m in arm.modules])
    speed = np.abs(np.diff(q, axis=0)) / dt
    assert np.all(speed <= SPEED_FRACTION * v_max * (1 + 1e-3))
    for rec in source.log:
        moving = np.abs(rec.q_to_mm - rec.q_from_mm) > 1e-6
        idx = np.nonzero((t >= rec.t_start_s) & (t <= rec.t_start_s + rec.duration_s + dt))[0]
        reached = [idx[np.abs(q[idx, k] - rec.q_to_mm[k]) < 1e-6][0] for k in np.nonzero(moving)[0]]
        assert max(reached) - min(reached) <= 1  # within one cycle of each other
        # the longest move runs at the (fractional) speed limit
        assert rec.duration_s == pytest.approx(
            np.max(np.abs(rec.q_to_mm - rec.q_from_mm) / (SPEED_FRACTION * v_max))
        )


def test_stick_is_ignored_while_following():
    cfg = load_rig_config(CONFIG)
    arm = vertebra_arm(cfg)
    b = frozenset({"BTN_SOUTH"})
    steer = [StickFrame(0.0, 0.0, 1.0), StickFrame(0.5), StickFrame(1.0, buttons=b)]
    _, _, plain = plan_session(EndFollowPlanner(arm, follow_params(cfg)), steer, 0.01)
    # the stick pushed again while the follow move runs (it starts at 1.0 s) changes nothing
    script = [*steer, StickFrame(1.01, 0.0, 1.0, buttons=b), StickFrame(1.04)]
    _, _, source = plan_session(EndFollowPlanner(arm, follow_params(cfg)), script, 0.01)
    follow = [r for r in source.log if r.mode == "follow"]
    assert follow and follow[-1].t_start_s + follow[-1].duration_s > 1.04
    np.testing.assert_allclose(source.planner.target, plain.planner.target, atol=1e-12)


def test_planned_return_to_straight_within_the_planned_speed(session):
    arm, _, psi, _, source, dt = session
    planner = EndFollowPlanner(arm, source.planner.params, psi=psi[-1])
    assert np.abs(psi[-1][:, 0]).max() > 0.3
    fraction = 0.6
    assert planner.set_targets(np.zeros_like(psi[-1]))
    _, back, ret = plan_session(planner, [], dt, speed_fraction=fraction)
    np.testing.assert_allclose(back[0], psi[-1], atol=1e-12)
    np.testing.assert_allclose(back[-1][:, 0], 0.0, atol=1e-12)
    q = np.array([cable_displacements(arm, p) for p in back])
    v_max = np.array([m.v_max_mm_s for m in arm.modules])
    speed = np.abs(np.diff(q, axis=0)) / dt
    assert np.all(speed <= fraction * v_max * (1 + 1e-3))
    assert speed.max() > 0.95 * fraction * v_max.max()  # at the planned speed, not slower
    assert all(r.mode == "steer" for r in ret.log)
