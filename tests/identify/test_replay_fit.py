"""The output-error fit of keypoint logs (:mod:`cdcr_ctl.identify.replay_fit`), model level.

Small simulated keypoint logs of ``config/three_segment_example.yaml``; the world is the forward
replay with known parameters (``cdcr_ctl.sim.keypoint_log``), so the replay with the world's
parameters must explain the log to the tracker noise, and a fit from the config's values must
come back to the world's within its own interval.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.identify.keypoints import _load, _run_rows, candidates
from cdcr_ctl.identify.logkind import split_by_time
from cdcr_ctl.identify.replay_fit import Evaluator, ReplayProblem, fit
from cdcr_ctl.sim.keypoint_log import TIP_NOISE_MM, Truth, make_keypoint_log

CONFIG = Path(__file__).resolve().parents[2] / "config" / "three_segment_example.yaml"
# ~8 s CPU for the three tests (measured); the limit guards a hang, not speed
pytestmark = pytest.mark.timeout(400)


@pytest.fixture(scope="module")
def model():
    return build_model(load_rig_config(CONFIG))


def _problem(model, run_dir, max_rows=60):
    runs, _, _ = _load([run_dir], None, model.params.n_segments)
    pts = [p for r in runs for p in r.points]
    fit_pts, _ = split_by_time(pts, 0.3)
    keys = {(p.run, p.index) for p in fit_pts}
    rr = tuple(_run_rows(r, keys, max_rows) for r in runs)
    return ReplayProblem(model.params, model.effects, rr, (), TIP_NOISE_MM, 0.02)


def test_replay_with_the_worlds_parameters_explains_the_log_to_the_noise(model, tmp_path):
    """The cause of the old fit's 7.7x: with the world's parameters the replay reproduces the
    simulator's tips row by row; its reduced chi^2 is 1 within the spread of a chi^2 with m
    degrees of freedom (sd sqrt(2/m)); with the config's values it is far above."""
    run, truth = make_keypoint_log(model.params, model.effects, tmp_path, n_rows=60, seed=3)
    prob = _problem(model, run)
    r_true, is_tip, failed = prob.residuals_of(truth.apply(model.params))
    m = r_true.size
    assert failed == 0 and is_tip.all() and m == 3 * len(prob.runs[0].rows)
    chi2 = float(r_true @ r_true) / m
    assert abs(chi2 - 1.0) < 5 * math.sqrt(2.0 / m)
    r_nom, _, _ = prob.residuals_of(model.params)
    assert float(r_nom @ r_nom) / m > 100 * chi2


def test_fit_from_the_config_recovers_the_world_within_its_interval(model, tmp_path):
    """Two parameters off nominal (seg1 EI +35 %, seg2 hole offset 2.5 deg), the rest at the
    config: the fit of those two from the config's values lands within 4 standard errors of
    the world's and reaches the noise (reduced chi^2 within 5 sd of 1)."""
    off = math.radians(2.5)
    truth = Truth((1.35, 1.0, 1.0), 1.0, 1.0, (0.0, off, 0.0))
    run, _ = make_keypoint_log(
        model.params, model.effects, tmp_path, n_rows=50, seed=4, truth=truth
    )
    prob = _problem(model, run)
    fps = [
        f for f in candidates(model.params) if f.name in ("seg1.EI_Nmm2", "seg2.hole_offset_rad")
    ]
    with Evaluator(prob, jobs=1) as ev:
        sol = fit(ev, fps, [0.25, math.radians(1.0)], max_nfev=15)
    ei, ho = sol.estimates
    ei_true = model.params.segments[0].EI_Nmm2 * 1.35
    assert abs(ei.value - ei_true) < 4 * ei.std
    assert abs(ho.value - off) < 4 * ho.std
    assert ei.ci95[0] < ei.value < ei.ci95[1]
    assert abs(sol.chi2_reduced - 1.0) < 5 * math.sqrt(2.0 / sol.n_residuals)


def test_a_hidden_transmission_play_is_fitted_as_backlash(model, tmp_path):
    """A world with 0.4 mm of lost motion on every cable: the candidate cables.backlash_mm
    (added to the config's play) is fitted near 0.4 mm, and its interval excludes 0."""
    world = dataclasses.replace(
        model.params,
        cables=tuple(
            dataclasses.replace(c, backlash_mm=c.backlash_mm + 0.4) for c in model.params.cables
        ),
    )
    ident = Truth((1.0, 1.0, 1.0), 1.0, 1.0, (0.0, 0.0, 0.0))
    run, _ = make_keypoint_log(world, model.effects, tmp_path, n_rows=50, seed=6, truth=ident)
    prob = _problem(model, run)
    fps = [f for f in candidates(model.params, backlash=True) if f.kind == "backlash"]
    with Evaluator(prob, jobs=1) as ev:
        sol = fit(ev, fps, [0.05], max_nfev=15)
    (b,) = sol.estimates
    assert abs(b.value - 0.4) < max(4 * b.std, 0.02)
    assert b.ci95[0] > 0.0
    assert np.isfinite(sol.chi2_reduced)


def test_sensitivity_replay_matches_central_differences_of_the_replay(model, tmp_path):
    """The Jacobian of the fit from one replay carrying implicit-differentiation sensitivities
    (:mod:`cdcr_ctl.model.cc_disk.forward.sensitivity`, friction memory handed on row to row)
    against central differences of whole replays (h = 1e-4 in the fit variables) for every
    candidate, on a 40-row log with disk friction. Central differences err by O(h^2) ~ 1e-8
    relative plus the solver's tolerance over 2h (~1e-5 mm); the sensitivities by their own
    differences (1e-6, 1e-7: ~1e-6 relative). Rows where a +-h replay changes a cable's mode
    (stick/slide) differ by a jump that is not a derivative: they are left out and counted."""
    from cdcr_ctl.identify.replay_fit import effects_of
    from cdcr_ctl.model.cc_disk.forward import ForwardStepper
    from cdcr_ctl.model.cc_disk.forward.sensitivity import replay_sensitivity

    run, _ = make_keypoint_log(model.params, model.effects, tmp_path, n_rows=40, seed=5)
    prob = _problem(model, run)
    q = prob.runs[0].q_path
    fps = candidates(model.params)
    x0 = np.array([fp.to_var(fp.nominal) for fp in fps])

    def rep(x):
        p = prob.params_of(fps, x)
        st = ForwardStepper(p, effects_of(p, model.effects))
        out = [st.step(qi) for qi in q]
        return np.array([r.tip_mm for r in out]), [r.modes for r in out]

    eye = np.eye(len(fps))
    variants = [prob.params_of(fps, x0 + 1e-6 * e) for e in eye]
    p0 = prob.params_of(fps, x0)
    tip, dtip = replay_sensitivity(p0, effects_of(p0, model.effects), variants, [1e-6] * 10, q)
    tip0, modes0 = rep(x0)
    assert np.array_equal(tip, tip0)
    skipped = 0
    for j, e in enumerate(eye):
        (tp, mp), (tm, mm) = rep(x0 + 1e-4 * e), rep(x0 - 1e-4 * e)
        same = np.array([a == b == c for a, b, c in zip(mp, mm, modes0, strict=True)])
        same = np.logical_and.accumulate(same)  # a changed mode carries on in the memory
        skipped += int((~same).sum())
        fd = (tp - tm) / 2e-4
        scale = np.max(np.abs(fd))
        assert scale > 0
        assert np.max(np.abs(fd - dtip[:, :, j])[same]) < 1e-4 * scale + 1e-4, fps[j].name
    assert skipped < 0.1 * len(q) * len(fps)


def test_the_replay_follows_the_configs_friction_law(tmp_path):
    """A config whose ``robot.friction_law`` has a breakaway b = 1 (m(v) = 1 + b at rest, p = 1):
    a keypoint row is settled, so the law's replay (:func:`replay_fit.stepper`, the fit's
    residuals and the held-out check) is the capstan replay with every ``mu_disk`` doubled, to
    the solver's tolerance (1e-11 scaled residual: tips agree to ~1e-6 mm; 1e-4 asserted), and
    differs from the capstan replay of the same config (by up to 0.95 mm on this path; > 0.05 mm
    asserted)."""
    import types

    import yaml

    from cdcr_ctl.config.build_model import friction_law
    from cdcr_ctl.identify.heldout import heldout_errors
    from cdcr_ctl.identify.replay_fit import RunRows, stepper
    from cdcr_ctl.model.cc_disk.forward import replay

    rig = tmp_path / "law.yaml"
    rig.write_text(
        yaml.safe_dump({"extends": str(CONFIG), "robot": {"friction_law": {"breakaway": 1.0}}})
    )
    cfg = load_rig_config(rig)
    m, law = build_model(cfg), friction_law(cfg.robot)
    p = m.params
    assert law is not None and not law.capstan
    doubled = dataclasses.replace(
        p, cables=tuple(dataclasses.replace(c, mu_disk=2 * c.mu_disk) for c in p.cables)
    )
    # the first tendons of segments 1 and 3 pulled to 3 mm and back
    up = np.linspace(0.0, 3.0, 5)
    rows = []
    for k in (0, 6):
        for v in np.concatenate([up, up[::-1]]):
            q = np.zeros(p.n_cables)
            q[k] = v
            rows.append(q)
    q = np.array(rows)
    t_law = replay(stepper(p, m.effects, law), q).tip_mm
    t_mu2 = replay(stepper(doubled, m.effects), q).tip_mm
    t_cap = replay(stepper(p, m.effects), q).tip_mm
    assert np.all(np.isfinite(t_law)) and np.max(np.abs(t_law - t_mu2)) < 1e-4
    assert np.max(np.linalg.norm(t_law - t_cap, axis=1)) > 0.05
    idx = np.arange(len(q))
    rr = RunRows("r", q, idx, np.zeros((len(q), 3)), np.full((len(q), p.n_cables), np.nan))
    # the fit's residuals (tips against 0, noise 1 mm) and the held-out check replay the law
    r_law = ReplayProblem(p, m.effects, (rr,), (), 1.0, 0.02, law).residuals_of(p)[0]
    assert np.max(np.abs(r_law - t_law.ravel())) < 1e-9
    pts = [types.SimpleNamespace(tip_mm=np.zeros(3), run="r", index=i) for i in idx]
    run = types.SimpleNamespace(name="r", q_path=q, points=pts, rows=list(idx))
    e_law = heldout_errors(p, m.effects, [run], law)[0][0]
    assert np.allclose(e_law, np.sum(t_law * t_law, axis=1), rtol=0, atol=1e-6)
