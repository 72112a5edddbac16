"""The workflow end to end on short logged runs of the simulated rig (one hidden effect each).

Level: system. The runs come from the simulator's truth through the run-log writer; the workflow
only sees the run directories. Short runs (12 s at 50 Hz) and few simulated samples keep this fast;
the 60 s / 100 Hz acceptance numbers are in benchmarks/bench_discrepancy.py and readme-9.md.
"""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdcr_ctl.cli.main import main
from cdcr_ctl.config.loader import merge_tree, validate_mapping
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.discrepancy import analyse
from cdcr_ctl.discrepancy.alignment import align_run, decimate, noise_sigma, turning_points
from cdcr_ctl.discrepancy.report import config_fragment, text_report
from cdcr_ctl.model.cc_disk.effects import candidate

EFFECTS = Path(__file__).resolve().parents[2] / "config" / "sim" / "effects"
FAST = dict(max_points=200, jobs=1, progress=False, refit_evals=5)


def test_noise_estimate_of_white_noise_on_a_smooth_signal():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 10, 2000)
    x = np.column_stack([5 * np.sin(t), 3 * np.cos(0.5 * t)]) + 0.05 * rng.standard_normal(
        (2000, 2)
    )
    assert noise_sigma(x, 1e-3) == pytest.approx(0.05, rel=0.15)


def test_decimation_keeps_turning_points_and_respects_the_budget():
    t = np.linspace(0, 20, 4001)
    q = np.column_stack([np.sin(t), 0.5 * np.cos(1.3 * t)])
    turns = turning_points(q, 0.01)
    # sin turns at pi/2 + k pi, 0.5 cos(1.3 t) at k pi / 1.3
    expected = sorted(
        [np.pi / 2 + k * np.pi for k in range(6)] + [k * np.pi / 1.3 for k in range(1, 9)]
    )
    assert np.allclose(sorted(t[turns]), [e for e in expected if e < 20], atol=0.02)
    idx, dq = decimate(q, t, 300, 0.5)
    assert len(idx) <= 300 and set(turns) <= set(idx.tolist()) and dq > 0


@pytest.fixture(scope="module")
def analysed(short_runs):
    """Each short run analysed once (the tests below look at different parts of the result)."""
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = analyse([short_runs[name]], **FAST)
        return cache[name]

    return get


def test_no_hidden_effect_reports_nothing_missing(analysed):
    res = analysed("none")
    assert res.selection.verdict == "nothing_missing", res.selection.reasons
    assert res.named is None and res.refit is None
    assert "NOTHING SIGNIFICANT IS MISSING" in text_report(res)


@pytest.mark.parametrize("hidden", ["backlash", "actuator_scale", "tracker_offset"])
def test_names_the_hidden_effect_and_closes_the_gap(analysed, hidden):
    res = analysed(hidden)
    assert res.named == hidden, res.selection.reasons
    assert res.systematic_gap_shrink > 0.7
    assert res.gap_shrink > 0.5


def test_fitted_values_match_the_truth_variant(analysed):
    res = analysed("backlash")
    truth = yaml.safe_load((EFFECTS / "backlash.yaml").read_text())["effects"]["backlash_mm"]
    (v,) = res.refit.values
    (ci,) = res.refit.ci95
    assert abs(v - truth) < max(3 * ci, 0.02 * truth)


def test_partial_log_without_tensions_skips_tension_effects(short_runs, tmp_path):
    src = short_runs["actuator_scale"]
    dst = tmp_path / "no_tensions"
    shutil.copytree(src, dst)
    rows = list(csv.reader((dst / "samples.csv").open()))
    keep = [j for j, c in enumerate(rows[0]) if not c.endswith("_tension_N")]
    with (dst / "samples.csv").open("w", newline="") as f:
        csv.writer(f).writerows([[r[j] for j in keep] for r in rows])
    terms = [candidate(n) for n in ("pulley_losses", "actuator_scale", "cable_elongation")]
    res = analyse([dst], candidates=terms, **FAST)
    assert any("skipped pulley_losses" in n and "tension" in n for n in res.notes)
    assert res.named == "actuator_scale"


def test_a_missing_effect_that_was_skipped_is_not_reported_as_nothing(gen, tmp_path):
    """Hidden pulley losses in a log without tensions: the pulley term is skipped, yet the tip
    misses by far more than the noise. That is 'no effect in the library explains this', never
    'nothing significant is missing'."""
    run = gen.make_run(
        EFFECTS / "pulley_losses.yaml",
        tmp_path,
        duration_s=12.0,
        rate_hz=50.0,
        seed=2,
        name="pulley-no-tensions",
        drop=("tension",),
    )
    terms = [candidate(n) for n in ("pulley_losses", "backlash", "tracker_offset")]
    res = analyse([run], candidates=terms, **FAST)
    assert any("skipped pulley_losses" in n for n in res.notes)
    assert res.selection.baseline_ms > 2.0
    assert res.selection.verdict == "unexplained", res.selection.reasons
    assert res.named is None


def test_fragment_overlays_on_the_rig_config(short_runs, analysed):
    res = analysed("actuator_scale")
    frag = yaml.safe_load(config_fragment(res))
    run = align_run(short_runs["actuator_scale"])
    base = run.cfg.model_dump(mode="json")
    merged = validate_mapping(merge_tree(base, frag, (), {}, "fragment"), RigConfig, "merged")
    scale = yaml.safe_load((EFFECTS / "actuator_scale.yaml").read_text())["effects"][
        "counts_per_mm_scale"
    ]
    got = [
        d.counts_per_mm / b["counts_per_mm"]
        for d, b in zip(merged.drives, base["drives"], strict=True)
    ]
    assert got == pytest.approx(scale, abs=0.003)


def test_tracker_fragment_without_a_tracker_section_is_a_comment(analysed):
    """A rig config with no tracker section (e.g. the three-segment example): the fitted
    alignment is reported as a comment, the overlay stays valid (no half tracker section)."""
    from dataclasses import replace

    res = analysed("tracker_offset")
    cfg = res.runs[0].cfg
    bare = cfg.model_copy(update={"sensors": cfg.sensors.model_copy(update={"tracker": None})})
    res_bare = replace(res, runs=[replace(res.runs[0], cfg=bare)])
    text = config_fragment(res_bare)
    assert "sensors.tracker.base_from_tracker" in text and "no tracker" in text
    assert "tracker" not in (yaml.safe_load(text) or {}).get("sensors", {})


def test_cli_writes_report_plots_and_fragment(short_runs, tmp_path, capsys):
    out = tmp_path / "rep"
    code = main(
        [
            "--json",
            "discrepancy",
            str(short_runs["tracker_offset"]),
            "--out",
            str(out),
            "--max-points",
            "250",
            "--jobs",
            "1",
            "--no-progress",
            "--effects",
            "tracker_offset,backlash",
        ]
    )
    assert code == 0
    doc = yaml.safe_load(capsys.readouterr().out)
    assert doc["effect"] == "tracker_offset" and doc["gap_shrink_percent"] > 50
    for name in (
        "report.txt",
        "fragment.yaml",
        "residuals.png",
        "localisation.png",
        "candidates.png",
    ):
        assert (out / name).stat().st_size > 0
    frag = yaml.safe_load((out / "fragment.yaml").read_text())
    assert "base_from_tracker" in frag["sensors"]["tracker"]
