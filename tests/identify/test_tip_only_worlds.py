"""Identification from tip-only keypoint logs of worlds unlike the model.

The worlds are :mod:`cdcr_ctl.sim.keypoint_world` (a chain of rigid links on torsional springs,
energy minimisation, friction decaying along the length, per-segment play, routing offsets,
gravity sag, registration error, tracker noise >= 1 mm), which shares no code with the model.
The full-size figures (1600-row logs, timing) are ``benchmarks/bench_keypoint_identify.py
worlds``; here the same paths at a size the CI budget allows.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.cli.main import main
from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.identify.keypoint_gate import heldout_gain, tracker_noise
from cdcr_ctl.identify.rowselect import farthest_points, features, replay_path, spread
from cdcr_ctl.sim.keypoint_world import (
    ChainWorld,
    WorldSpec,
    hard_world,
    lab_path,
    make_world_dwell_log,
    make_world_log,
    pull_only_path,
)

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "three_segment_example.yaml"


@pytest.fixture(scope="module")
def nominal():
    return build_model(load_rig_config(CONFIG)).params


def test_chain_world_gradient_straight_pose_and_pull_plane(nominal):
    """The world's analytic gradient against central differences (error O(h^2 E''') ~ 1e-6
    relative); with no gravity and no pull the chain is straight (tip at the summed lengths);
    one tendon pulled alone bends the arm in its hole's plane (azimuth = hole angle)."""
    w = ChainWorld(nominal, WorldSpec(mu=(0.3, 0.2, 0.1), ei_gradient=0.5, tip_mass_g=5.0))
    rng = np.random.default_rng(0)
    x = rng.normal(size=2 * w.J) * 0.1
    q = rng.uniform(-1, 2, nominal.n_cables)
    wts = w._weights()
    _, g = w.energy(x, q, wts)
    h = 1e-5
    num = np.array(
        [
            (w.energy(x + h * e, q, wts)[0] - w.energy(x - h * e, q, wts)[0]) / (2 * h)
            for e in np.eye(len(x))
        ]
    )
    assert np.max(np.abs(g - num)) < 1e-5 * np.max(np.abs(g))
    flat = ChainWorld(nominal, WorldSpec(link_mass_g=0.0))
    tip0 = flat.step(np.zeros(nominal.n_cables))
    assert np.allclose(tip0, [0, 0, nominal.lengths_mm.sum()], atol=1e-6)
    for k in (0, 4, 8):
        qk = np.zeros(nominal.n_cables)
        qk[k] = 2.0
        pull = ChainWorld(nominal, WorldSpec(link_mass_g=0.0)).step(qk)
        az = math.atan2(pull[1], pull[0])
        assert abs(math.remainder(az - nominal.cables[k].hole_angle_rad, 2 * math.pi)) < 1e-3


def test_rows_chosen_span_the_log_where_its_prefix_does_not(nominal):
    """A lab path starts with single-tendon pulls; the farthest-point rows cover every cable's
    range, the combined pulls and the reversals, the first rows do not."""
    q = lab_path(nominal, 600, seed=2)
    cand = np.arange(420)  # the rows before a 30 % hold-out cut
    f, _ = features(q, cand)
    pick = farthest_points(f, 60)
    prefix = np.arange(60)
    sp, sp0 = spread(q, cand, pick), spread(q, cand, prefix)
    moved = np.sum(np.abs(q) > 1e-9, axis=1)
    assert np.all(moved[prefix] <= 1)  # the prefix is only single pulls
    assert np.mean(moved[cand[pick]] > 1) > 0.5
    assert sp.reversals_chosen > sp0.reversals_chosen
    assert sp.covering_radius < 0.6 * sp0.covering_radius
    text = "\n".join(sp.lines())
    assert "rows fitted: 60 of 420" in text and "reversal" in text
    path, pos = replay_path(q, cand[pick])
    assert np.allclose(path[pos], q[cand[pick]]) and len(path) < 2 * len(pick) + 1


def test_tracker_noise_from_the_log_and_the_heldout_gain():
    """Second differences of a smooth tip map stepped along lines: sigma_hat is the noise
    (chi-square median, relative spread ~1/sqrt(n) = 5 %) plus a small curvature term."""
    rng = np.random.default_rng(1)
    s = np.concatenate([np.linspace(0, 1, 40), np.linspace(1, 0.2, 30)] * 6)
    q = np.column_stack([s, 0.5 * s, -s])
    tip = np.column_stack([30 * np.sin(s), 30 * np.cos(s), 5 * s]) + rng.normal(0, 1.0, (len(s), 3))
    sigma, n = tracker_noise(q, tip)
    assert n > 300 and 0.9 < sigma < 1.15
    e_nom = rng.normal(0, 1, 200) ** 2 * 3 + 2.0
    gain, se = heldout_gain(e_nom, e_nom - 1.0 + rng.normal(0, 0.1, 200))
    assert gain > 2 * se
    g0, se0 = heldout_gain(e_nom, e_nom + rng.normal(0, 1.0, 200))
    assert not g0 > 2 * se0


@pytest.fixture(scope="module")
def hard_log(nominal, tmp_path_factory):
    out = tmp_path_factory.mktemp("hard")
    return make_world_log(nominal, hard_world(3), out, 160, name="hard3")


# one process (--jobs 1); the limit guards a hang, not speed
@pytest.mark.timeout(600)
def test_identify_defaults_on_a_hard_world(hard_log, tmp_path, capsys):
    """``identify`` with its defaults but 30 rows and 4 evaluations (the full-size run with the
    defaults is ``benchmarks/bench_keypoint_identify.py worlds``) on a tip-only keypoint log of
    the hard world: rows chosen and their spread printed, the gate from the data, every
    interval finite within its bounds, every warning printed and written; an overlay only when
    the held-out rows improved beyond their noise, marked when the residual is far above the
    noise."""
    out = tmp_path / "ident"
    args = ["-c", str(CONFIG), "identify", "--from-run", str(hard_log), "--out", str(out)]
    code = main([*args, "--max-points", "30", "--max-nfev", "4", "--jobs", "1"])
    err = capsys.readouterr().err
    rep = json.loads((out / "identification.json").read_text())
    kp = rep["keypoint_fit"]
    assert "rows fitted:" in err and "spread: each cable's q range covered" in err
    assert "given by --log-kind" not in err and "nan%" not in err
    assert 0.8 < kp["tip_noise_mm"] < 1.6  # the world's 1 mm per axis, an upper bound
    for e in kp["fitted"]:
        lo, hi = e["ci95"]
        assert math.isfinite(lo) and math.isfinite(hi)
        assert e["bounds"][0] - 1e-9 <= lo <= e["value"] <= hi <= e["bounds"][1] + 1e-9
        if lo > 0:
            assert hi / lo <= 1e3
    for w in kp["warnings"]:
        assert w in err
    gate = kp["gate"]
    overlay = out / "identified.yaml"
    if gate["heldout_improved"]:
        assert code == 0 and overlay.is_file()
        if gate["misfit"]:
            assert overlay.read_text().startswith("# MISFIT")
    else:
        assert code != 0 and not overlay.exists() and "--accept-misfit" in err


# the limit guards a hang, not speed
@pytest.mark.timeout(600)
def test_a_world_the_model_cannot_represent_writes_no_silent_overlay(nominal, tmp_path, capsys):
    """Keypoint, tip (dwell) and pull logs of worlds the model cannot represent (a 9 mm
    registration error; two drives of one segment swapped): the gate sees the residual far
    above the noise read from the log, and no overlay is written without saying so. (Load-cell
    logs: tests/identify/test_misfit_gate.py.) At most 30 rows and 4 evaluations: fewer
    evaluations can only leave the residual larger, so the misfit does not depend on them."""
    reg = WorldSpec(
        registration_rotvec_rad=(0.0, 0.0, 0.0),
        registration_mm=(6.0, -5.0, 4.0),
        tip_noise_mm=0.3,
        link_mass_g=0.0,
        seed=4,
    )
    logs = {
        "keypoint": make_world_log(nominal, reg, tmp_path, 150, name="reg"),
        "tip": make_world_dwell_log(nominal, reg, tmp_path, 20, name="regdw", dwell_s=0.6),
    }
    for kind, run in logs.items():
        out = tmp_path / f"o-{kind}"
        args = ["-c", str(CONFIG), "identify", "--from-run", str(run), "--out", str(out)]
        code = main([*args, "--max-points", "30", "--max-nfev", "4", "--jobs", "1"])
        err = capsys.readouterr().err
        assert f"log kind: {kind}" in err
        rep = json.loads((out / "identification.json").read_text())["keypoint_fit"]
        assert rep["gate"]["misfit"] and "MISFIT" in err and "model error, not noise" in err
        overlay = out / "identified.yaml"
        if code == 0:
            assert overlay.read_text().startswith("# MISFIT")
        else:
            assert not overlay.exists() and "--accept-misfit" in err
    # pulls: the drives of c11 and c12 swapped (their tendons' holes trade places, +-120 deg):
    # no one offset of segment 1 explains both
    swap = 2 * math.pi / 3
    twist = WorldSpec(
        angle_offset_rad=(swap, -swap, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        tip_noise_mm=0.3,
        link_mass_g=0.0,
        seed=5,
    )
    prun = make_world_log(nominal, twist, tmp_path, 0, name="pulls", path=pull_only_path(nominal))
    out2 = tmp_path / "o2"
    code2 = main(["-c", str(CONFIG), "identify", "--from-run", str(prun), "--out", str(out2)])
    err2 = capsys.readouterr().err
    assert code2 != 0 and not (out2 / "identified.yaml").exists()
    assert "seg1" in err2 and "--accept-misfit" in err2
    rep2 = json.loads((out2 / "identification.json").read_text())
    assert rep2["refused"] and rep2["overlay"] is None
    # the override writes it, marked
    args = ["-c", str(CONFIG), "identify", "--from-run", str(prun), "--out", str(out2)]
    code3 = main([*args, "--accept-misfit"])
    capsys.readouterr()
    assert code3 == 0 and (out2 / "identified.yaml").read_text().startswith("# MISFIT ACCEPTED")
