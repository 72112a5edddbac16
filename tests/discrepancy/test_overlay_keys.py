"""Every effect ``discrepancy`` can name writes rig-config keys the controller's model reads.

For each candidate term (but the tracker alignment, which needs a fitted result and has its own
test in test_workflow.py): the term applied to the controller's model (every switch off, so the
term has to switch its effect on) and the overlay its fitted values write, merged into the rig
config and built as the controller builds its model, give the same parameters and switches, to
the overlay's rounding (5 significant digits for cable values, 4 decimals for masses and gains).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import friction_law, model_effects, robot_params
from cdcr_ctl.config.loader import merge_tree, validate_mapping
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.discrepancy.report import put_fitted
from cdcr_ctl.model.cc_disk.effects import CANDIDATES, ModelSpec
from cdcr_ctl.model.cc_disk.params import Effects

ROOT = Path(__file__).resolve().parents[2]
SWITCHES = ("disk_friction", "pulley_friction", "elongation", "coupling", "gravity")
# the tracker alignment needs a fitted result (test_workflow.py)
TERMS = [t for t in CANDIDATES if t.name != "tracker_offset"]


def _base(rig: str) -> tuple[RigConfig, ModelSpec]:
    cfg = load_rig_config(ROOT / "config" / rig)
    off = dict.fromkeys(SWITCHES, False)
    me = cfg.control.model_effects.model_copy(update=off)
    cfg = cfg.model_copy(update={"control": cfg.control.model_copy(update={"model_effects": me})})
    return cfg, ModelSpec(robot_params(cfg.robot), Effects(geometry="chord", **off))


@pytest.mark.parametrize("term", TERMS, ids=lambda t: t.name)
def test_the_overlay_carries_what_the_applied_term_changes(term):
    cfg, base = _base("three_segment_example.yaml" if term.name == "coupling" else "qi2023.yaml")
    values = np.array([p.step for p in term.parameters(base)])
    applied = term.apply(base, values)
    doc: dict = {}
    for fv in term.fitted(base, values):
        put_fitted(doc, [], fv, cfg, None)
    assert doc, term.name
    text = yaml.safe_dump(doc)
    merged = validate_mapping(
        merge_tree(cfg.model_dump(mode="json"), yaml.safe_load(text), (), {}, "overlay"),
        RigConfig,
        "merged",
    )
    got_p = robot_params(merged.robot)
    got_e = model_effects(merged)
    want_e = applied.effects
    for s in SWITCHES:
        want = getattr(want_e, s)
        if term.name == "coupling" and s == "coupling":
            want = applied.coupling_gain > 0
        assert getattr(got_e, s) == want, (term.name, s)
    if term.name == "coupling":
        assert got_e.coupling_gain == pytest.approx(applied.coupling_gain, abs=1e-4)
    if term.name == "actuator_scale":
        # the drive's counts per mm of cable: the transmission scale the term applies
        (scale,) = [a for a in applied.effects.actuator]
        factors = np.broadcast_to(np.asarray(scale.factor, dtype=float), (len(cfg.drives),))
        for d0, d1, f in zip(cfg.drives, merged.drives, factors, strict=True):
            assert d1.counts_per_mm == pytest.approx(d0.counts_per_mm / f, rel=1e-4)
        return
    if term.name == "backlash":
        assert [c.backlash_mm for c in got_p.cables] == pytest.approx(
            [c.backlash_mm for c in applied.params.cables], abs=1e-5
        )
        return
    if term.name == "friction_law":
        # robot.friction_law: the law the controller's compensation and the discrepancy
        # model read (5 decimals in the overlay)
        got, want = friction_law(merged.robot), applied.friction_law
        assert got is not None and want is not None
        for f in ("exponent", "viscous_s_per_mm", "breakaway", "breakaway_mm_s"):
            assert getattr(got, f) == pytest.approx(getattr(want, f), abs=1e-5), f
    want_p = applied.params
    assert got_p.tip_mass_g == pytest.approx(want_p.tip_mass_g, abs=1e-3)
    assert got_p.gravity_mm_s2 == pytest.approx(want_p.gravity_mm_s2, abs=0.01)
    for a, b in zip(got_p.cables, want_p.cables, strict=True):
        for f in ("mu_disk", "EA_N", "backlash_mm"):
            assert getattr(a, f) == pytest.approx(getattr(b, f), rel=1e-4, abs=1e-5), (f, a.name)
    if term.name in ("gravity_sag", "gravity_direction"):
        for a, b in zip(got_p.segments, want_p.segments, strict=True):
            assert a.disk_mass_g == pytest.approx(b.disk_mass_g, abs=1e-4)
    for a, b in zip(got_p.cables, want_p.cables, strict=True):
        for pa, pb in zip(a.pulleys, b.pulleys, strict=True):
            for f in dataclasses.fields(pa):
                va, vb = getattr(pa, f.name), getattr(pb, f.name)
                if isinstance(va, float):
                    assert va == pytest.approx(vb, rel=1e-4, abs=1e-6), (a.name, f.name)


def test_an_overlay_is_always_a_mapping():
    """A named effect whose every value is a switch, and no effect at all, still give a YAML
    mapping the config loader takes as an overlay."""
    from cdcr_ctl.discrepancy.report import config_fragment

    class NoRefit:
        refit = None

    assert yaml.safe_load(config_fragment(NoRefit())) == {}
