"""Lost motion (Yang et al. 2022 eq. 13-17): the play operator, its rate-bounded inverse, and the
controller's command with it (cdcr_ctl.model.shared.deadzone, BacklashPlay, build_model)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import DEAD_ZONE_STEP_FRACTION, build_model
from cdcr_ctl.model.cc_disk.effects import BacklashPlay
from cdcr_ctl.model.shared.deadzone import dead_zone_inverse, play_forward

ROOT = Path(__file__).resolve().parents[2]
B = np.array([0.25, 0.35, 0.3])


def _inverse(b: np.ndarray, step: float = math.inf):
    """The rate-bounded inverse with the sample-to-sample reversal rule, fed row by row:
    returns x(row) as an array, its state (rows [y_prev, c, y_ext, dir]) kept inside."""
    state = [[0.0, 0.0, 0.0, 0.0] for _ in b]
    half = (b / 2).tolist()

    def call(row: np.ndarray) -> np.ndarray:
        return np.array(dead_zone_inverse(row.tolist(), state, half, step))

    call.state = state  # type: ignore[attr-defined]
    return call


def _play(x: np.ndarray, cable: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array(play_forward(x.tolist(), cable.tolist(), (b / 2).tolist()))


def _path(n: int = 400, seed: int = 0) -> np.ndarray:
    """A wandering cable path (mm) with many reversals of every cable."""
    rng = np.random.default_rng(seed)
    return np.cumsum(0.02 * np.sign(rng.normal(size=(n, 3))) * rng.uniform(size=(n, 3)), axis=0)


def test_zero_play_is_the_identity():
    inverse = _inverse(np.zeros(3))
    for row in _path(50):
        assert np.array_equal(inverse(row), row)


def test_exact_inverse_drives_the_play_to_the_wanted_path():
    """Inverse then play operator: the cable follows the wanted path exactly (up to rounding:
    x = y + c then y' = clip(y_prev, x - b/2, x + b/2) subtracts the same c again)."""
    inverse, cable = _inverse(B), np.zeros(3)
    for row in _path():
        cable = _play(inverse(row), cable, B)
        assert np.allclose(cable, row, atol=1e-12)


def test_without_the_inverse_the_play_loses_half_a_gap_on_each_side():
    cable = np.zeros(3)
    up = np.linspace(0, 2, 50)[:, None] * np.ones(3)
    for row in up:
        cable = _play(row, cable, B)
    assert np.allclose(up[-1] - cable, B / 2)


def test_rate_bounded_inverse_crosses_the_gap_in_bounded_steps():
    step = 0.04
    inverse, cable = _inverse(B, step), np.zeros(3)
    up = np.linspace(0.0, 1.0, 30)
    down = np.linspace(1.0, 0.5, 40)[1:]
    c = np.zeros(3)
    for v in np.concatenate([up, down]):
        row = np.full(3, v)
        x = inverse(row)
        c_old, c = c, x - row
        # c = x - y is rounded once: the bound holds to a few ulps of |y| <= 1 mm
        assert np.all(np.abs(c - c_old) <= step + 1e-15)
        cable = _play(x, cable, B)
    # after the reversal, once ceil(b / step) calls have passed, the cable is on the path again
    assert np.allclose(cable, down[-1], atol=1e-12)
    assert np.allclose([r[1] for r in inverse.state], -B / 2)


def test_backlash_play_round_trip_and_state_in_the_callers_hands():
    play = BacklashPlay(tuple(B))
    inv_state, fwd_state = play.new_state(3), play.new_state(3)
    for row in _path(100, seed=5):
        x = play.to_actuator(row, inv_state)
        assert np.allclose(play.to_cable(x, fwd_state), row, atol=1e-12)
    with pytest.raises(ValueError):
        BacklashPlay(-0.1).to_actuator(np.zeros(3), play.new_state(3))


def _rig_with_play(tmp_path: Path, play_mm: float) -> Path:
    doc = {
        "extends": str(ROOT / "config" / "qi2023.yaml"),
        "robot": {"cables": [{"name": n, "backlash_mm": play_mm} for n in ("c1", "c2", "c3")]},
    }
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_the_controller_pre_travels_the_gap_every_cycle_in_model_mode_only(tmp_path: Path):
    cfg = load_rig_config(_rig_with_play(tmp_path, 0.3))
    model = build_model(cfg)
    plays = [e for e in model.effects.actuator if isinstance(e, BacklashPlay)]
    assert len(plays) == 1 and plays[0].width_mm == (0.3, 0.3, 0.3)
    step = DEAD_ZONE_STEP_FRACTION * cfg.limits.cable_velocity_mm_s / cfg.control.rate_hz
    assert plays[0].max_step_mm == pytest.approx(step)
    plain = build_model(load_rig_config(ROOT / "config" / "qi2023.yaml"))
    assert not plain.effects.actuator
    s_model, s_plain, s_off = model.new_state(), plain.new_state(), model.new_state()
    thetas = np.concatenate([np.linspace(0, 1.0, 400), np.linspace(1.0, 0.6, 200)[1:]])
    for th in thetas:
        psi = np.array([[th, 0.0]])
        qn = model.q_nominal(psi)
        q = model.q_command(psi, qn, s_model, "model", None)
        q0 = plain.q_command(psi, qn, s_plain, "model", None)
        assert np.array_equal(model.q_command(psi, qn, s_off, "off", None), qn)
    # paying out at the end: cable 1 (pulled at phi = 0) pays out, the others are pulled in;
    # each drive stands half its gap beyond the cable in the direction of its motion
    assert q[0] - q0[0] == pytest.approx(-0.15, abs=1e-9)
    assert q[1] - q0[1] == pytest.approx(0.15, abs=1e-9)
    assert math.isfinite(float(q.sum()))
