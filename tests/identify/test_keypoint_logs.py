"""Identification from the logs labs have: kinds, observability, pulls, CLI.

Small simulated logs of ``config/three_segment_example.yaml`` (``cdcr_ctl.sim.keypoint_log``:
the world is the forward model with EI, EA, pretension off nominal by 20-50 % and hole offsets
of 1-4 deg). The full-size acceptance numbers (held-out RMSE against the true model, CI
coverage over 20 seeds, 2000-row timing) are in ``benchmarks/bench_keypoint_identify.py``.
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
from cdcr_ctl.discrepancy.keypoint_path import reversals_from_path
from cdcr_ctl.identify.geometry import hole_offsets_from_pulls
from cdcr_ctl.identify.logkind import detect_kind, keypoint_points, split_by_time
from cdcr_ctl.identify.observability import analyse
from cdcr_ctl.identify.parameters import FitParameter
from cdcr_ctl.runlog import load_run
from cdcr_ctl.sim.keypoint_log import Truth, make_keypoint_log, make_pull_log

CONFIG = Path(__file__).resolve().parents[2] / "config" / "three_segment_example.yaml"


@pytest.fixture(scope="module")
def model():
    return build_model(load_rig_config(CONFIG))


@pytest.fixture(scope="module")
def keypoint_log(model, tmp_path_factory):
    out = tmp_path_factory.mktemp("kp")
    run, truth = make_keypoint_log(model.params, model.effects, out, n_rows=40, seed=5)
    return run, truth


def test_keypoint_log_is_detected_and_split_by_time(model, keypoint_log):
    run_dir, _ = keypoint_log
    run = load_run(run_dir)
    kind, why = detect_kind(run)
    assert kind == "keypoint" and "no commanded pose" in why
    pts, q, _ = keypoint_points(run, model.params.n_segments)
    assert len(pts) == 40 and q.shape == (40, 9)
    fit, held = split_by_time(pts, 0.3)
    assert max(p.t_end_s for p in fit) < min(p.t_start_s for p in held)
    assert len(held) == pytest.approx(12, abs=1)
    # friction directions come from the actuator path; reversals make some of them unknown
    assert any(not all(p.s_known) for p in pts[1:])


def test_reversals_from_the_actuator_path():
    q = np.array([[0, 0], [1, 0], [2, 0.001], [1.5, 0], [1.5, 0], [3, 0]], dtype=float)
    # cable 1: up, up, down, (still), up -> 2 reversals; cable 2 moves below eps -> none
    assert reversals_from_path(q).tolist() == [2, 0]


def test_observability_names_a_parameter_the_data_cannot_see():
    """Two parameters with the same column: neither alone resolves the direction they share."""

    def fp(name):
        return FitParameter(name, "EI", 0, (), (), 1.0, 0.1, 10.0)

    rng = np.random.default_rng(0)
    a = rng.normal(size=50)
    J = np.column_stack([a, a, rng.normal(size=50) * 100])
    ob = analyse(J, [fp("p1"), fp("p2"), fp("p3")], [0.25, 0.25, 0.25])
    assert ob.singular_values[-1] < 1e-9 * ob.singular_values[0]
    assert not ob.identifiable("p1") and not ob.identifiable("p2")
    assert ob.identifiable("p3")


def test_hole_offsets_from_tendon_pulls_within_one_degree(model, tmp_path):
    """Acceptance 3: hole offsets from simulated one-cable-at-a-time pulls within 1 deg."""
    truth = Truth((1.3, 0.7, 1.4), 0.75, 1.35, tuple(math.radians(d) for d in (3.0, -2.5, 1.5)))
    run = make_pull_log(model.params, model.effects, tmp_path, truth, seed=2, steps=3)
    offs, _ = hole_offsets_from_pulls(model.params, [run])
    assert [h.segment for h in offs] == ["seg1", "seg2", "seg3"]
    for h, true in zip(offs, truth.hole_offset_rad, strict=True):
        assert abs(math.degrees(h.offset_rad - true)) < 1.0
        assert h.ci95_rad[0] < h.offset_rad < h.ci95_rad[1]


def test_identify_from_keypoint_log_through_the_cli(keypoint_log, tmp_path, capsys):
    """``identify --from-run`` on a keypoint log: kind detected, observability and the
    fitted/fixed split reported, reduced chi^2 and a held-out residual printed."""
    run_dir, _ = keypoint_log
    out = tmp_path / "ident"
    code = main(
        [
            "--config",
            str(CONFIG),
            "identify",
            "--from-run",
            str(run_dir),
            "--out",
            str(out),
            "--max-points",
            "12",
            "--max-nfev",
            "3",
        ]
    )
    text = capsys.readouterr().err
    assert "log kind: keypoint" in text
    assert "observability" in text and "fitted: " in text
    assert "reduced chi^2" in text and "held-out rows" in text and "tip RMSE" in text
    rep = json.loads((out / "identification.json").read_text())["keypoint_fit"]
    names = [f["name"] for f in rep["fitted"]] + [f["name"] for f in rep["fixed"]]
    assert "seg1.EI_Nmm2" in names and "seg3.hole_offset_rad" in names
    assert len(rep["observability"]["singular_values"]) == len(names)
    h = rep["heldout"]
    assert h["n_rows"] >= 10 and math.isfinite(h["rmse_nominal"]) and h["failed"] == []
    # an overlay only when the held-out rows improved beyond their noise; else exit 1
    improved = rep["gate"]["heldout_improved"]
    assert (out / "identified.yaml").exists() == improved and (code == 0) == improved, text
