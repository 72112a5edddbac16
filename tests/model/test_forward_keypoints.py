"""The forward solve answers on every keypoint row.

The lab case: a 3-segment, 9-cable robot with ``free_length_mm: 0`` and disk friction on, fed
the measured actuator positions of quasi-static keypoints far apart. Before the fix the active
set over the cable modes cycled ("friction/slack modes did not settle") on about 1 row in 10 of
such a path (4 of its first 30 rows with the path below). The tests count the failures over a
120-row random walk and over a 2000-row keypoint log of out-and-back sweeps to 1.2 rad (the
poses the simulated lab logs use; ``benchmarks/bench_keypoint_identify.py forward`` times it).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.forward import ForwardStepper, replay
from cdcr_ctl.model.cc_disk.routing import cable_displacement
from cdcr_ctl.sim.keypoint_log import sweep_poses

CONFIG = Path(__file__).resolve().parents[2] / "config" / "three_segment_example.yaml"


def lab_model():
    m = build_model(load_rig_config(CONFIG))
    p = m.params
    cab = tuple(dataclasses.replace(c, free_length_mm=0.0) for c in p.cables)
    return dataclasses.replace(p, cables=cab), m.effects


def keypoint_path(params, n: int, seed: int, step: float = 0.15, bend_max: float = 1.0):
    """Random walk of keypoint poses -> nominal cable displacements (mm), (n, K)."""
    rng = np.random.default_rng(seed)
    psi = np.zeros((params.n_segments, 2))
    out = []
    for _ in range(n):
        th = np.clip(psi[:, 0] + rng.normal(0, step, params.n_segments), 0, bend_max)
        ph = psi[:, 1] + rng.normal(0, 0.5, params.n_segments)
        psi = np.column_stack([th, ph])
        out.append(cable_displacement(psi, params))
    return np.asarray(out)


def test_every_keypoint_row_settles_without_free_length_friction_on():
    params, effects = lab_model()
    assert all(c.free_length_mm == 0.0 for c in params.cables)
    assert effects.disk_friction and effects.elongation
    q = keypoint_path(params, 120, seed=0)
    rep = replay(ForwardStepper(params, effects), q)
    assert rep.failed == []
    assert np.all(np.isfinite(rep.tip_mm))
    # every answer is a static solution: the tip is at the FK of the solved bending vectors
    # and the rows actually bend the robot (not a degenerate straight answer)
    assert np.max(np.hypot(rep.tip_mm[:, 0], rep.tip_mm[:, 1])) > 50.0
    # slack cables carry no tension; no tension is negative
    assert np.nanmin(rep.tension_base_N) >= -1e-9


def test_a_row_without_solution_is_named_and_the_replay_goes_on(monkeypatch):
    params, effects = lab_model()
    q = keypoint_path(params, 6, seed=3)
    st = ForwardStepper(params, effects)
    real = st.model.solve
    bad = q[2].copy()

    def solve(qq, *a, **k):
        if np.allclose(qq, bad, atol=1e-3):  # the row and its sub-steps' last one
            raise ModelError("no static solution (injected)")
        return real(qq, *a, **k)

    monkeypatch.setattr(st.model, "solve", solve)
    rep = replay(st, q)
    assert [i for i, _ in rep.failed] == [2]
    assert "no static solution" in rep.failed[0][1]
    assert np.all(np.isnan(rep.tip_mm[2]))
    assert np.all(np.isfinite(rep.tip_mm[[0, 1, 3, 4, 5]]))


@pytest.mark.parametrize("seed", [1])
def test_large_keypoint_steps_settle(seed):
    """Steps of up to 0.25 rad per segment and bends to 1.4 rad (the solver used to fail to
    converge from the last pose on such steps; now: straight-start retry and sub-steps)."""
    params, effects = lab_model()
    q = keypoint_path(params, 90, seed=seed, step=0.25, bend_max=1.4)
    rep = replay(ForwardStepper(params, effects), q)
    assert rep.failed == []


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_every_row_of_a_2000_row_keypoint_log_settles():
    """Issue 18 acceptance 4, counted: 0 of 2000 rows without a static solution (about 11 s)."""
    params, effects = lab_model()
    psi = sweep_poses(params.n_segments, 2000, np.random.default_rng(1), bend_max_rad=1.2)
    q = np.array([cable_displacement(x, params) for x in psi])
    rep = replay(ForwardStepper(params, effects), q)
    assert len(q) == 2000
    assert rep.failed == []
    assert np.all(np.isfinite(rep.tip_mm))
    assert np.max(np.hypot(rep.tip_mm[:, 0], rep.tip_mm[:, 1])) > 50.0
