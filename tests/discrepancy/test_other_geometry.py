"""The workflow on geometry and a tracker it was not developed on.

Level: system. Runs of the second rig ``config/sim/effects-b`` (four cables at 90 deg, 8 disks,
120 mm, thinner cable, the robot tilted 30 deg, a 150 Hz tracker) and of the three-segment
example (``config/sim/effects-3seg``), made by ``scripts/make_discrepancy_runs.py`` with one effect
hidden each. Asserted: the hidden effect is named and the RAW tip RMS gap (tracker noise
included) shrinks by at least 70 % after the refit; nothing is named on a run without one; a
partial log without tension columns still works. Short runs (10 s at 50 Hz) keep this fast.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cdcr_ctl.discrepancy import analyse
from cdcr_ctl.model.cc_disk.effects import CANDIDATES, candidate

CONFIG = Path(__file__).resolve().parents[2] / "config" / "sim"
FAST = dict(max_points=120, jobs=1, progress=False, refit_evals=5)
#: The library but the friction-law refinement: this file is about geometry and tracker (the
#: refinement's five column simulations are test_other_laws.py's to pay)
TERMS = [c for c in CANDIDATES if c.name != "friction_law"]


@pytest.fixture(scope="module")
def b_runs(tmp_path_factory, gen):
    out = tmp_path_factory.mktemp("disc-b")

    def make(name: str, **kw) -> Path:
        return gen.make_run(
            CONFIG / "effects-b" / f"{name}.yaml",
            out,
            duration_s=10.0,
            rate_hz=50.0,
            seed=2,
            name=f"{name}-{'-'.join(kw.get('drop', ())) or 'full'}",
            **kw,
        )

    return make


def test_second_rig_without_a_hidden_effect_names_nothing(b_runs):
    res = analyse([b_runs("none")], candidates=TERMS, **FAST)
    assert res.selection.verdict == "nothing_missing", res.selection.reasons


@pytest.mark.parametrize("hidden", ["disk_friction", "gravity_sag"])
def test_second_rig_names_the_effect_and_shrinks_the_raw_gap(b_runs, hidden):
    res = analyse([b_runs(hidden)], candidates=TERMS, **FAST)
    assert res.named == hidden, res.selection.reasons
    assert res.runs[0].n_cables == 4
    assert res.gap_shrink >= 0.7, (res.tip_rms_before_mm, res.tip_rms_after_mm)


def test_second_rig_partial_log_without_tensions(b_runs):
    run = b_runs("disk_friction", drop=("tension",))
    names = ("disk_friction", "pulley_losses", "cable_elongation", "gravity_sag")
    res = analyse([run], candidates=[candidate(n) for n in names], **FAST)
    assert any("no tension columns" in n for n in res.notes)
    assert any("skipped pulley_losses" in n for n in res.notes)
    assert res.named == "disk_friction" and res.gap_shrink >= 0.7


def test_three_segments_coupling_named_and_refitted(tmp_path, gen):
    run = gen.make_run(
        CONFIG / "effects-3seg" / "coupling.yaml",
        tmp_path,
        duration_s=8.0,
        rate_hz=50.0,
        seed=2,
        name="coupling-3seg",
    )
    terms = [candidate(n) for n in ("coupling", "gravity_sag", "disk_friction")]
    res = analyse([run], candidates=terms, pairs=False, **{**FAST, "max_points": 120})
    assert res.named == "coupling", res.selection.reasons
    assert res.gap_shrink >= 0.7
