"""An MCAP run and its CSV export give the same identification and discrepancy results.

The MCAP run is written by the run log's MCAP sink from the rows of a generated run (the same
rows the loop would queue), with no ``samples.csv`` beside it, so every reader goes through
``run.mcap``; the CSV run is ``cdcr-ctl export --csv`` of it.

Tolerance: the loaded arrays are asserted equal bit for bit (JSON and CSV both carry each float
as its shortest ``repr``, which IEEE 754 round-trips exactly), so identify and discrepancy see the
same inputs; their results are then compared at a relative 1e-9, room only for a non-associative
reduction that a threaded BLAS may order differently between two calls.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from scriptload import load_script

from cdcr_ctl.cli.main import main
from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model, loadcell_locations
from cdcr_ctl.discrepancy import analyse
from cdcr_ctl.identify.dwell import extract_dwells
from cdcr_ctl.identify.estimator import identify
from cdcr_ctl.identify.parameters import plan_parameters
from cdcr_ctl.identify.sweep import SweepSpec, calibration_sweep
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.runlog import load_run
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP, McapSink
from cdcr_ctl.runlog.writer import CONFIG_YAML, EFFECTIVE_CONFIG_YAML, RUN_YAML, SAMPLES_CSV

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "identify"))
import synth  # noqa: E402  tests/identify/synth.py: a run of a known made-up rig

REL = 1e-9
FAST = dict(max_points=200, jobs=1, progress=False, refit_evals=5)


def as_mcap_run(src: Path, dst: Path) -> Path:
    """``dst``: the run of ``src`` as ``run.mcap`` (+ run.yaml and configs), no samples.csv."""
    run = load_run(src)
    dst.mkdir(parents=True)
    for name in (CONFIG_YAML, EFFECTIVE_CONFIG_YAML, RUN_YAML):
        if (src / name).is_file():
            shutil.copyfile(src / name, dst / name)
    files = {n: (src / n).read_text() for n in (CONFIG_YAML, EFFECTIVE_CONFIG_YAML)
             if (src / n).is_file()}  # fmt: skip
    sink = McapSink(dst / RUN_MCAP, run.columns, attachments=files)
    cols = [run.data[c] for c in run.columns]
    rows = [
        [None if (isinstance(v, float) and np.isnan(v)) else v for v in (a[i] for a in cols)]
        for i in range(len(run))
    ]
    sink.write_rows(rows)
    sink.close((src / RUN_YAML).read_text())
    assert not (dst / SAMPLES_CSV).exists()
    return dst


def exported(mcap_dir: Path, out: Path) -> Path:
    assert main(["export", str(mcap_dir), "--csv", "--out", str(out)]) == 0
    return out


def assert_same_arrays(a, b) -> None:
    assert a.columns == b.columns and len(a) == len(b)
    for c in a.columns:
        x, y = a.data[c], b.data[c]
        if x.dtype == object:
            assert [str(v) for v in x] == [str(v) for v in y], c
        else:
            assert np.array_equal(x, y, equal_nan=True), c


def _discrepancy_generator():
    return load_script("make_discrepancy_runs")


def test_discrepancy_same_on_the_mcap_run_and_its_csv_export(tmp_path):
    gen = _discrepancy_generator()
    src = gen.make_run(
        ROOT / "config" / "sim" / "effects" / "backlash.yaml",
        tmp_path / "gen",
        duration_s=12.0,
        rate_hz=50.0,
        trajectory="rich",
        bend_rad=1.0,
        seed=2,
        name="backlash",
    )
    mcap_dir = as_mcap_run(Path(src), tmp_path / "mcap" / "backlash")
    csv_dir = exported(mcap_dir, tmp_path / "csv" / "backlash")
    assert_same_arrays(load_run(mcap_dir), load_run(csv_dir))
    a = analyse([mcap_dir], **FAST)
    b = analyse([csv_dir], **FAST)
    assert a.named == b.named == "backlash"
    assert a.selection.verdict == b.selection.verdict
    assert a.gap_shrink == pytest.approx(b.gap_shrink, rel=REL)
    assert a.systematic_gap_shrink == pytest.approx(b.systematic_gap_shrink, rel=REL)
    assert np.allclose(a.refit.values, b.refit.values, rtol=REL, atol=0)


def test_identify_same_on_the_mcap_run_and_its_csv_export(tmp_path):
    effects = Effects(geometry="chord", capstan_points=25)
    world = synth.World(synth.perturbed_world(seed=7, pulleys=False).params, effects)
    spec = SweepSpec(theta_step_deg=30.0, approach_step_deg=0.0, dwell_s=0.6, start_dwell_s=0.6)
    src = tmp_path / "sweep"
    synth.write_run(src, calibration_sweep(1, spec), world, samples_per_dwell=8, seed=3)
    mcap_dir = as_mcap_run(src, tmp_path / "mcap" / "sweep")
    csv_dir = exported(mcap_dir, tmp_path / "csv" / "sweep")
    run_m, run_c = load_run(mcap_dir), load_run(csv_dir)
    assert run_m.samples_path.name == RUN_MCAP and run_c.samples_path.name == SAMPLES_CSV
    assert_same_arrays(run_m, run_c)

    cfg = load_rig_config(synth.RIG_CONFIG)
    nominal = build_model(cfg).params
    locs = loadcell_locations(cfg)
    pm, _ = extract_dwells(run_m)
    pc, _ = extract_dwells(run_c)
    assert len(pm) == len(pc) > 10
    for p, q in zip(pm, pc, strict=True):
        assert np.allclose(p.q_act_mm, q.q_act_mm, rtol=REL, atol=0, equal_nan=True)
        assert np.allclose(p.tension_N, q.tension_N, rtol=REL, atol=0, equal_nan=True)
    # The fit of one parameter (the whole plan takes ~40 s; `identify --from-run` on both
    # directories is the same call with all of them, see the README's run-log section).
    fps, fixed = plan_parameters(nominal, pm, locs, fit_pulleys="off")
    fps = [f for f in fps if f.name == "c1.mu_disk"]
    rm = identify(nominal, effects, pm, locs, fps, fixed)
    rc = identify(nominal, effects, pc, locs, fps, fixed)
    for em, ec in zip(rm.estimates, rc.estimates, strict=True):
        assert em.parameter.name == ec.parameter.name
        assert em.value == pytest.approx(ec.value, rel=REL)
