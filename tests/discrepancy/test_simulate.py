"""Forward simulation of a logged run: the kinematic shape and the interpolation between
simulated rows. Level: model (hand-made poses) and system (a short generated run)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import robot_params
from cdcr_ctl.discrepancy.alignment import align_run, kinematic_tip
from cdcr_ctl.discrepancy.simulate import _interp, _step_path, path_weights, simulate
from cdcr_ctl.model.cc_disk.kinematics import psi_to_x, tip_position
from cdcr_ctl.model.cc_disk.routing import cable_matrix_x

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("rig", ["qi2023.yaml", "three_segment_example.yaml"])
def test_kinematic_tip_inverts_the_constant_curvature_cable_map(rig):
    p = robot_params(load_rig_config(ROOT / "config" / rig).robot)
    rng = np.random.default_rng(1)
    S = p.n_segments
    psi = np.stack((rng.uniform(0, 1.2, (5, S)), rng.uniform(-math.pi, math.pi, (5, S))), -1)
    B = cable_matrix_x(p)
    q = np.array([B @ psi_to_x(ps).ravel() for ps in psi])  # eq. 4: q = B x
    L = np.array([s.length_mm for s in p.segments])
    expected = np.array([tip_position(ps, L) for ps in psi])
    assert np.allclose(kinematic_tip(p, q), expected, atol=1e-9)


def test_tip_between_simulated_rows_follows_the_kinematic_shape(gen, tmp_path):
    """Few simulated rows on a short run: the tip interpolated as kinematic shape + interpolated
    model correction is closer to the every-row simulation than the chord between rows."""
    run = gen.make_run(
        ROOT / "config" / "sim" / "effects" / "none.yaml",
        tmp_path,
        duration_s=8.0,
        rate_hz=50.0,
        seed=5,
        name="interp",
    )
    dense = align_run(run, max_points=100000)
    ref = simulate(dense.spec, dense).tip_mm
    sparse = align_run(run, max_points=60)
    assert len(sparse.sim_idx) < len(dense.sim_idx) / 4
    new = simulate(sparse.spec, sparse).tip_mm
    tip, _, _, _ = _step_path(sparse.spec, sparse)
    seg, u = path_weights(sparse.q_in_mm, sparse.t_s, sparse.sim_idx)
    chord = _interp(seg, u, tip)
    err_new = np.sqrt(np.mean(np.sum((new - ref) ** 2, axis=1)))
    err_chord = np.sqrt(np.mean(np.sum((chord - ref) ** 2, axis=1)))
    assert err_new < 0.75 * err_chord  # measured: about half
