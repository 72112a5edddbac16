"""Issue #17: the mount direction as an effect, the other friction law of the simulated worlds,
and the tracker delay bounded by the log's timing evidence."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import robot_params
from cdcr_ctl.discrepancy.timing import (
    MAX_TRACKER_LATENCY_S,
    TipTiming,
    delay_bound_s,
    frame_period_s,
)
from cdcr_ctl.model.cc_disk.effects import GravityDirection, ModelSpec, candidate
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer
from cdcr_ctl.sim.friction_law import WrapPowerTransfer
from cdcr_ctl.sim.simconfig import load_sim_config
from cdcr_ctl.sim.truth import TruthModel

ROOT = Path(__file__).resolve().parents[2]


def _spec() -> ModelSpec:
    cfg = load_rig_config(ROOT / "config" / "qi2023.yaml")
    return ModelSpec(robot_params(cfg.robot), Effects())


def test_gravity_direction_turns_the_configs_vector_and_keeps_its_size():
    spec = _spec()
    term = candidate("gravity_direction")
    assert isinstance(term, GravityDirection)
    same = term.apply(spec, np.zeros(2))
    assert np.allclose(same.params.gravity_mm_s2, spec.params.gravity_mm_s2)
    tilt = math.radians(40)
    g = np.array(term.apply(spec, np.array([0.0, -tilt])).params.gravity_mm_s2)
    assert np.linalg.norm(g) == pytest.approx(9810.0)
    # -40 deg about y turns -z towards +x: the default world's kind of tilt
    assert g[0] == pytest.approx(9810.0 * math.sin(tilt)) and g[1] == pytest.approx(0.0)
    (fv,) = term.fitted(spec, np.array([0.0, -tilt]))
    assert (fv.what, fv.key) == ("robot", "gravity_mm_s2")


def test_wrap_power_law_with_exponent_one_is_the_models_law():
    params = robot_params(load_rig_config(ROOT / "config" / "qi2023.yaml").robot)
    model = ForceTransfer(params, Effects())
    same = WrapPowerTransfer(params, Effects(), exponent=1.0)
    other = WrapPowerTransfer(params, Effects(), exponent=2.0)
    for theta in (0.3, 0.9, 1.5):
        P = model.pose([theta, 0.0])
        a, ea = model.factors_k(P, 0, 1.0)
        b, eb = same.factors_k(P, 0, 1.0)
        assert np.allclose(a, b, rtol=1e-12) and ea == pytest.approx(eb, rel=1e-12)
        _, e2 = other.factors_k(P, 0, 1.0)
        z = P.Zb[0]
        # ln(T_base/T_anchor) = mu z^2 (z in rad) against the model's mu z
        assert e2 == pytest.approx(params.cables[0].mu_disk * z**2, rel=1e-12)
        assert other.friction_capacity(P, 0) > model.friction_capacity(P, 0) or z < 1.0


def test_default_world_has_lost_motion_tilted_mount_and_the_clean_world_neither():
    hard = TruthModel(load_sim_config(ROOT / "config" / "sim" / "qi2023-truth.yaml"))
    widths = [c.backlash_mm for c in hard.params.cables]
    assert all(0.2 <= w <= 0.4 for w in widths)
    g = np.array(hard.params.gravity_mm_s2)
    assert math.degrees(math.acos(-g[2] / np.linalg.norm(g))) == pytest.approx(20.0, abs=0.1)
    assert hard.effects.actuator  # the play acts between drive and cable
    clean = TruthModel(load_sim_config(ROOT / "config" / "sim" / "qi2023-truth-clean.yaml"))
    assert not clean.effects.actuator
    assert np.allclose(clean.params.gravity_mm_s2, (0.0, 0.0, -9810.0))
    other = load_sim_config(ROOT / "config" / "sim" / "effects" / "friction_law.yaml")
    assert other.sim.effects.friction_law == "wrap_power"
    assert isinstance(TruthModel(other).stepper.model.ft, WrapPowerTransfer)


def _held(t: np.ndarray, f: np.ndarray, frame_s: float) -> np.ndarray:
    """A sample-and-hold tracker of period frame_s showing f (N, 3)."""
    idx = np.floor(t / frame_s) * frame_s
    return np.interp(idx, t, f[:, 0])[:, None] * np.ones(3)


def test_delay_bound_comes_from_the_logs_frame_period():
    t = np.arange(0.0, 5.0, 0.01)
    tip = _held(t, np.sin(t)[:, None] * np.ones((1, 3)), 1 / 30)
    assert frame_period_s(t, tip) == pytest.approx(1 / 30, abs=0.011)
    bound = delay_bound_s(t, tip)
    assert bound == pytest.approx(MAX_TRACKER_LATENCY_S + frame_period_s(t, tip) + 0.01)


def test_a_delay_beyond_the_evidence_is_clipped_and_marked_suspect():
    t = np.arange(0.0, 10.0, 0.01)
    path = np.stack([np.sin(t), np.cos(0.7 * t), 0.1 * t], axis=1)
    measured = np.stack([np.sin(t - 0.07), np.cos(0.7 * (t - 0.07)), 0.1 * (t - 0.07)], axis=1)
    base = TipTiming(1, np.zeros(1), np.zeros(t.size, dtype=int), t)
    free = base.with_common_delay(measured, path)
    assert free.delay_s[0] == pytest.approx(0.07, abs=2e-3) and not free.suspect
    bounded = base.with_common_delay(measured, path, bound_s=0.03)
    assert bounded.delay_s[0] == pytest.approx(0.03) and "SUSPECT" in bounded.note
    assert "physics, not lag" in bounded.suspect


def test_backlash_correction_adds_to_the_configs_play():
    spec = _spec()
    params = replace(
        spec.params,
        cables=tuple(replace(c, backlash_mm=0.1) for c in spec.params.cables),
    )
    out = candidate("backlash").apply(replace(spec, params=params), np.array([0.2]))
    assert [c.backlash_mm for c in out.params.cables] == pytest.approx([0.3, 0.3, 0.3])
    assert len(out.effects.actuator) == 1
