"""Effect terms and transmission effects against hand-derived values and limits."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import robot_params
from cdcr_ctl.model.cc_disk.effects import (
    CANDIDATES,
    ActuatorScale,
    BacklashPlay,
    CableElongation,
    DiskFriction,
    GravitySag,
    ModelSpec,
    PulleyLosses,
    ReversalBacklash,
    SegmentCoupling,
    TrackerFrameOffset,
    TransmissionScale,
    candidate,
    rotation_from_rotvec,
    rotvec_from_rotation,
)
from cdcr_ctl.model.cc_disk.forward import ForwardStepper
from cdcr_ctl.model.cc_disk.params import Effects

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def spec():
    p = robot_params(load_rig_config(ROOT / "config" / "qi2023.yaml").robot)
    return ModelSpec(p, Effects(geometry="chord"))


def test_backlash_play_hand_derived():
    b = BacklashPlay(0.4)
    st = b.new_state(1)
    ys = [float(b.to_cable(np.array([x]), st)[0]) for x in (0.0, 0.3, 0.1, -0.3, 0.0, 0.35)]
    # starts centred; follows at x - b/2 pulling, stays inside the play, x + b/2 paying out
    assert ys == pytest.approx([0.0, 0.1, 0.1, -0.1, -0.1, 0.15])


def test_backlash_inverse_reaches_the_wanted_cable_position():
    b = BacklashPlay((0.4, 0.2))
    fwd, inv = b.new_state(2), b.new_state(2)
    path = np.array([[0.0, 0.0], [0.5, -0.3], [1.0, -0.6], [0.7, -0.2], [0.2, 0.4]])
    for y in path:
        x = b.to_actuator(y, inv)
        assert b.to_cable(x, fwd) == pytest.approx(y)


def test_scale_round_trip_and_truth_convention():
    s = TransmissionScale((1.0 / 1.04, 1.0))
    x = np.array([2.0, -1.0])
    assert s.to_cable(x, None) == pytest.approx([2.0 / 1.04, -1.0])
    assert s.to_actuator(s.to_cable(x, None), None) == pytest.approx(x)


def test_rotvec_round_trip():
    w = np.array([0.01, -0.3, 0.2])
    R = rotation_from_rotvec(w)
    assert R @ R.T == pytest.approx(np.eye(3))
    assert rotvec_from_rotation(R) == pytest.approx(w)


def test_zero_correction_leaves_every_model_unchanged(spec):
    for term in CANDIDATES:
        if term.not_applicable(spec):
            continue
        n = len(term.parameters(spec))
        out = term.apply(spec, np.zeros(n))
        if term.kind == "blend":
            assert out.coupling_gain == (1.0 if spec.effects.coupling else 0.0)
            continue
        assert out.params == spec.params or term.name in ("cable_elongation", "gravity_sag")
        q = np.array([1.0, -0.5, -0.5])
        a = ForwardStepper(spec.params, spec.effects).step(q)
        b = ForwardStepper(out.params, out.effects).step(q)
        assert out.tip_map(b.tip_mm) == pytest.approx(a.tip_mm, abs=1e-9), term.name


def test_switched_off_effects_are_switched_on_with_the_fitted_value(spec):
    off = ModelSpec(
        spec.params,
        Effects(
            geometry="chord",
            disk_friction=False,
            elongation=False,
            gravity=False,
            pulley_friction=False,
        ),
    )
    # friction switched on at d times the configured mu of each cable (0.26, 0.31, 0.28)
    f = DiskFriction().apply(off, np.array([0.5]))
    assert f.effects.disk_friction
    assert [c.mu_disk for c in f.params.cables] == pytest.approx([0.13, 0.155, 0.14])
    e = CableElongation().apply(off, np.array([0.5]))
    assert e.effects.elongation
    assert e.params.cables[0].EA_N == pytest.approx(spec.params.cables[0].EA_N / 0.5)
    g = GravitySag().apply(off, np.array([2.0]))
    assert g.effects.gravity and g.params.segments[0].disk_mass_g == pytest.approx(1.6)
    p = PulleyLosses().apply(off, np.array([0.2]))
    assert p.effects.pulley_friction
    assert all(pl.alpha == pytest.approx(0.2) for c in p.params.cables for pl in c.pulleys)
    # a model that has them gets corrections on top of its values
    f2 = DiskFriction().apply(spec, np.array([0.25]))
    assert [c.mu_disk for c in f2.params.cables] == pytest.approx([0.325, 0.3875, 0.35])


def test_disk_friction_without_configured_mu_uses_the_reference(spec):
    from dataclasses import replace

    from cdcr_ctl.model.cc_disk.effects import REFERENCE_MU_DISK

    cables = tuple(replace(c, mu_disk=0.0) for c in spec.params.cables)
    bare = ModelSpec(replace(spec.params, cables=cables), Effects(disk_friction=False))
    f = DiskFriction().apply(bare, np.array([1.0]))
    assert all(c.mu_disk == pytest.approx(REFERENCE_MU_DISK) for c in f.params.cables)
    assert DiskFriction().parameters(bare)[0].lower == 0.0


def test_scale_and_backlash_terms_add_transmission_effects(spec):
    s = ActuatorScale().apply(spec, np.array([0.02, -0.01, 0.0]))
    b = ReversalBacklash().apply(s, np.array([0.3]))
    kinds = [type(e).__name__ for e in b.effects.actuator]
    assert kinds == ["TransmissionScale", "BacklashPlay"]  # drive first, then the play
    fit = ActuatorScale().fitted(spec, np.array([0.04, 0.0, -0.02]))
    assert fit[0].value == pytest.approx(1 / 1.04)


def test_tracker_term_is_a_rigid_map(spec):
    t = TrackerFrameOffset().apply(spec, np.array([0.0, 0.0, math.pi / 2, 1.0, 2.0, 3.0]))
    assert t.tip_map(np.array([1.0, 0.0, 0.0])) == pytest.approx([1.0, 3.0, 3.0])


def test_coupling_needs_two_segments(spec):
    assert SegmentCoupling().not_applicable(spec)
    p3 = robot_params(load_rig_config(ROOT / "config" / "three_segment_example.yaml").robot)
    s3 = ModelSpec(p3, Effects(geometry="chord", coupling=False))
    assert SegmentCoupling().not_applicable(s3) is None
    (par,) = SegmentCoupling().parameters(s3)
    assert SegmentCoupling().apply(s3, np.array([par.step])).coupling_gain == 1.0


def test_library_lookup():
    assert candidate("backlash").name == "backlash"
    with pytest.raises(KeyError, match="known"):
        candidate("nope")
