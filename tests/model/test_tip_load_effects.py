"""Tip load, the model-effect config keys, the mount direction over the sphere, the disk-friction
zero, and the dead-zone reversal threshold: each checked against the physics it states."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_cc_disk_model, reversal_hysteresis_mm, robot_params
from cdcr_ctl.errors import ConfigError, ConfigErrors
from cdcr_ctl.model.cc_disk.compensation import Compensator, psi_to_flat_x
from cdcr_ctl.model.cc_disk.effect_spec import ModelSpec, rotation_from_rotvec
from cdcr_ctl.model.cc_disk.effect_terms import DiskFriction, GravityDirection, mount_axes
from cdcr_ctl.model.cc_disk.params import Effects
from cdcr_ctl.model.cc_disk.statics import moment_demand, moment_residual, solve_tensions
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer
from cdcr_ctl.model.shared.deadzone import dead_zone_inverse

ROOT = Path(__file__).resolve().parents[2]
QI = ROOT / "config" / "qi2023.yaml"
THREE = ROOT / "config" / "three_segment_example.yaml"


def _overlay(tmp_path: Path, base: Path, text: str) -> Path:
    p = tmp_path / "rig.yaml"
    p.write_text(f"extends: {base}\n{text}")
    return p


@pytest.mark.parametrize("geometry", ["cc", "chord"])
def test_tip_load_fast_chain_matches_reference_statics(geometry):
    """The payload (a point mass at arc fraction 1) and the tip force in the fast chain equal the
    reference J_tip^T F of statics.py (float rounding: 1e-12 of the largest moment)."""
    p = replace(
        robot_params(load_rig_config(THREE).robot),
        tip_mass_g=5.0,
        tip_force_N=(0.02, -0.03, 0.01),
    )
    psi = np.array([[0.5, 0.3], [0.4, 1.2], [0.6, -0.7]])
    eff = Effects(geometry=geometry)
    m_fast = np.array(ForceTransfer(p, eff).pose(psi_to_flat_x(psi)).m_req)
    m_ref = moment_demand(psi, p, eff)
    assert np.max(np.abs(m_fast - m_ref)) <= 1e-12 * np.abs(m_ref).max()
    # and the load is there: without it the demand differs by far more than the rounding
    m_bare = moment_demand(psi, replace(p, tip_mass_g=0.0, tip_force_N=(0.0, 0.0, 0.0)), eff)
    assert np.max(np.abs(m_ref - m_bare)) > 1.0


def test_tip_force_straight_pose_is_force_times_half_length():
    """Straight segment: the tip moves l/2 per unit bending vector (p = l x/2 + O(x^2)), so a
    lateral tip force F gives Q_x = (l/2) F and the demand m = -(l/2) F (N*mm)."""
    p = robot_params(load_rig_config(QI).robot)
    F = (0.05, -0.02, 0.3)  # the axial part does no work at the straight pose
    p = replace(p, tip_force_N=F)
    m = moment_demand(np.zeros((1, 2)), p, Effects(gravity=False))
    length = p.segments[0].length_mm
    assert m[0] == pytest.approx([-0.5 * length * F[0], -0.5 * length * F[1]], abs=1e-12)


@pytest.mark.parametrize("geometry", ["cc", "chord"])
def test_tip_force_commands_the_stretch_of_the_extra_tension(geometry):
    """Straight pose, lateral tip force F along +x on the Qi rig (holes at 0, 120, 240 deg,
    r = 4 mm): the demand -(l/2) F along x is met by cables 2 and 3 (cos = -1/2) with
    y = l F / (2 r) extra each, so they are commanded y L / EA more (L = l + free length + the
    cable on the pulleys, R * wrap each; no friction) and cable 1 nothing more. The stretch on
    the thin disks' channels is left out of L: 1 % tolerance."""
    cfg = load_rig_config(QI)
    p = robot_params(cfg.robot)
    eff = Effects(disk_friction=False, pulley_friction=False, gravity=False, geometry=geometry)
    F = 0.05
    psi = np.zeros((1, 2))
    r0 = Compensator(p, eff).compensate(psi, [1.0] * 3)
    rF = Compensator(replace(p, tip_force_N=(F, 0.0, 0.0)), eff).compensate(psi, [1.0] * 3)
    length, r = p.segments[0].length_mm, p.cables[0].routing_radius_mm
    y = length * F / (2 * r)
    dT = np.asarray(rF.T_distal) - np.asarray(r0.T_distal)
    # the config's hole angles are 2.0944 / 4.1888 rad (120 / 240 deg to 1e-5 rel)
    assert dT == pytest.approx([0.0, y, y], rel=1e-4, abs=1e-9)
    c = p.cables[1]
    L = length + c.free_length_mm + sum(pl.radius_mm * pl.wrap_angle_rad for pl in c.pulleys)
    dq = np.asarray(rF.q) - np.asarray(r0.q)
    assert dq[0] == pytest.approx(0.0, abs=1e-12)
    assert dq[1:] == pytest.approx([y * L / c.EA_N] * 2, rel=0.01)


def test_payload_in_the_config_changes_what_the_model_commands(tmp_path):
    """``robot.tip_load.payload_kg`` reaches the controller's model: on the Qi rig bent towards
    +x (gravity -z) the payload's weight pulls the tip further over, so the +x cable (c1) needs
    less tension and is commanded less; its drop equals the reference statics' (fast chain vs
    statics.py, float rounding)."""
    cfg = load_rig_config(_overlay(tmp_path, QI, "robot:\n  tip_load: {payload_kg: 0.005}\n"))
    assert robot_params(cfg.robot).tip_mass_g == pytest.approx(5.0)
    base = build_cc_disk_model(load_rig_config(QI))
    loaded = build_cc_disk_model(cfg)
    psi = np.array([[0.8, 0.0]])
    q_base = base.q_command(psi, base.q_nominal(psi), base.new_state(), "model", None)
    q_load = loaded.q_command(psi, loaded.q_nominal(psi), loaded.new_state(), "model", None)
    assert q_base[0] - q_load[0] > 1e-3
    # the reference statics.py has the cc arms: compare the cc chains
    s = np.ones(3)
    cc = replace(base.effects, geometry="cc")
    dT_ref = solve_tensions(psi, loaded.params, cc, s) - solve_tensions(psi, base.params, cc, s)
    dT = np.asarray(Compensator(loaded.params, cc).compensate(psi, s).T_distal) - np.asarray(
        Compensator(base.params, cc).compensate(psi, s).T_distal
    )
    assert dT[0] < -0.1
    assert dT == pytest.approx(dT_ref, abs=1e-9)


def test_tip_load_config_errors_name_the_key(tmp_path):
    with pytest.raises((ConfigError, ConfigErrors)) as exc:
        load_rig_config(_overlay(tmp_path, QI, "robot:\n  tip_load: {payload_kg: -0.001}\n"))
    assert "robot.tip_load.payload_kg" in str(exc.value)
    with pytest.raises((ConfigError, ConfigErrors)) as exc:
        load_rig_config(_overlay(tmp_path, QI, "robot:\n  tip_load: {force_N: [0, 1]}\n"))
    assert "robot.tip_load.force_N" in str(exc.value)


@pytest.mark.parametrize(
    "key", ["disk_friction", "pulley_friction", "elongation", "gravity", "coupling"]
)
def test_model_effect_switches_reach_the_model(tmp_path, key):
    """``control.model_effects.<key>: false`` builds the model with that effect off: its
    commands equal a model built with the switch off by hand, and differ from the default."""
    base_cfg = THREE if key == "coupling" else QI
    cfg = load_rig_config(
        _overlay(tmp_path, base_cfg, f"control:\n  model_effects: {{{key}: false}}\n")
    )
    m = build_cc_disk_model(cfg)
    assert getattr(m.effects, key) is False
    default = build_cc_disk_model(load_rig_config(base_cfg))
    by_hand = Compensator(default.params, replace(default.effects, **{key: False}))
    S = default.n_segments
    psi = np.array([[0.7, 0.4 + 0.9 * i] for i in range(S)])
    s = [1.0] * default.n_cables
    q_cfg = np.asarray(m.compensate(psi, s).q)
    assert np.array_equal(q_cfg, np.asarray(by_hand.compensate(psi, s).q))
    assert np.max(np.abs(q_cfg - np.asarray(default.compensate(psi, s).q))) > 1e-4


def test_coupling_gain_weights_the_distal_load(tmp_path):
    """``control.model_effects.coupling_gain``: 0 is the uncoupled model exactly, 1 the default
    exactly, and 0.5 balances the moments with half the distal cables' load (reference
    statics.py residual, N*mm, float rounding)."""
    cfg = load_rig_config(THREE)
    psi = np.array([[0.5, 0.3], [0.4, 1.2], [0.6, -0.7]])
    s = [1.0] * 9

    def model(text: str):
        return build_cc_disk_model(load_rig_config(_overlay(tmp_path, THREE, text)))

    T_off = np.asarray(
        Compensator(robot_params(cfg.robot), Effects(coupling=False, geometry="chord"))
        .compensate(psi, s)
        .T_distal
    )
    T_zero = np.asarray(
        model("control:\n  model_effects: {coupling_gain: 0.0}\n").compensate(psi, s).T_distal
    )
    half = model("control:\n  model_effects: {coupling_gain: 0.5}\n")
    T_half = np.asarray(half.compensate(psi, s).T_distal)
    T_one = np.asarray(model("").compensate(psi, s).T_distal)
    T_default = np.asarray(build_cc_disk_model(cfg).compensate(psi, s).T_distal)
    assert np.allclose(T_zero, T_off, rtol=0, atol=1e-9)
    assert np.array_equal(T_one, T_default)
    assert not np.allclose(T_half, T_one, atol=1e-3) and not np.allclose(T_half, T_off, atol=1e-3)
    ft = half.transfer
    P = ft.pose(psi_to_flat_x(psi))
    Fb, _ = ft.factors(P, s)
    assert np.abs(ft.moment_residual(P, Fb, T_half.tolist())).max() < 1e-9
    # the reference statics.py (cc arms) with the same gain
    eff = Effects(coupling_gain=0.5, geometry="cc")
    T_cc = np.asarray(Compensator(half.params, eff).compensate(psi, s).T_distal)
    assert np.abs(moment_residual(psi, half.params, eff, T_cc, np.asarray(s))).max() < 1e-9
    full = replace(eff, coupling_gain=1.0)
    assert np.abs(moment_residual(psi, half.params, full, T_cc, np.asarray(s))).max() > 1e-3


def test_disk_friction_zero_correction_keeps_a_frictionless_model():
    """Switch on but every mu_disk 0: d = 0 is the model as it is (no friction), and the
    lower bound is 0 (nothing to take away)."""
    p = robot_params(load_rig_config(QI).robot)
    p0 = replace(p, cables=tuple(replace(c, mu_disk=0.0) for c in p.cables))
    base = ModelSpec(p0, Effects())
    term = DiskFriction()
    assert term.parameters(base)[0].lower == 0.0
    out = term.apply(base, np.array([0.0]))
    psi = np.array([[0.8, 0.3]])
    q_out = Compensator(out.params, out.effects).compensate(psi, [1.0] * 3).q
    q_base = Compensator(base.params, base.effects).compensate(psi, [1.0] * 3).q
    assert np.allclose(q_out, q_base, rtol=0, atol=1e-12)
    # a positive correction switches on the reference mu
    assert any(c.mu_disk > 0 for c in term.apply(base, np.array([1.0])).params.cables)


def test_gravity_direction_reaches_every_direction():
    """The mount turn w = a e1 + b e2 (e1, e2 perpendicular to g_cfg): config g along -z gives
    the base x/y tilt exactly; g along +y (where a tilt about y did nothing) turns with both
    parameters; any target direction, the opposite one included, is reached with |w| <= pi."""
    p = robot_params(load_rig_config(QI).robot)
    term = GravityDirection()
    spec = ModelSpec(p, Effects())
    w = np.array([0.3, -0.2])
    g = np.array(term.apply(spec, w).params.gravity_mm_s2)
    assert np.array_equal(g, rotation_from_rotvec((0.3, -0.2, 0.0)) @ np.array(p.gravity_mm_s2))
    sideways = ModelSpec(replace(p, gravity_mm_s2=(0.0, 9810.0, 0.0)), Effects())
    for v in (np.array([0.4, 0.0]), np.array([0.0, 0.4])):
        gs = np.array(term.apply(sideways, v).params.gravity_mm_s2)
        assert math.degrees(math.acos(gs[1] / np.linalg.norm(gs))) == pytest.approx(
            math.degrees(0.4), rel=1e-9
        )
    lo, hi = (x.lower for x in term.parameters(spec)), (x.upper for x in term.parameters(spec))
    assert list(lo) == [-math.pi, -math.pi] and list(hi) == [math.pi, math.pi]
    g0 = np.array(p.gravity_mm_s2)
    e1, e2 = mount_axes(g0)
    for target in ([1.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-0.3, 0.5, -0.8]):
        t = np.asarray(target) / np.linalg.norm(target)
        d = g0 / np.linalg.norm(g0)
        axis = np.cross(d, t)
        ang = math.atan2(np.linalg.norm(axis), d @ t)
        n = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-12 else e1
        a, b = ang * (n @ e1), ang * (n @ e2)
        assert math.hypot(a, b) <= math.pi + 1e-12
        gt = np.array(term.apply(spec, np.array([a, b])).params.gravity_mm_s2)
        assert gt / np.linalg.norm(gt) == pytest.approx(t, abs=1e-9)
        assert np.linalg.norm(gt) == pytest.approx(np.linalg.norm(g0), rel=1e-12)


def test_dead_zone_ignores_a_sub_count_dip_and_turns_after_one_count():
    """Rising wanted position, then a dip of 1e-6 mm (below one count, 1/1238.6 mm): the
    pre-travel stays at +b/2; a retreat of two counts turns it to -b/2."""
    h = reversal_hysteresis_mm(load_rig_config(QI))
    assert h == pytest.approx(1 / 1238.6)
    half = [0.15]
    rows = [[0.0, 0.0, 0.0, 0.0]]
    for y in np.linspace(0.0, 1.0, 11):
        x = dead_zone_inverse([float(y)], rows, half, math.inf, h)
    assert x[0] == pytest.approx(1.15)
    x = dead_zone_inverse([1.0 - 1e-6], rows, half, math.inf, h)
    assert x[0] == pytest.approx(1.0 - 1e-6 + 0.15)
    x = dead_zone_inverse([1.0 - 2 * h], rows, half, math.inf, h)
    assert x[0] == pytest.approx(1.0 - 2 * h - 0.15)
    # without the threshold the sub-count dip flips the pre-travel across the whole play
    rows0 = [[1.0, 0.15, 1.0, 1.0]]
    assert dead_zone_inverse([1.0 - 1e-6], rows0, half)[0] == pytest.approx(1.0 - 0.15, abs=1e-5)


def test_sideways_gravity_loads_a_straight_robot_as_the_disk_levers_say(tmp_path):
    """``robot.gravity_mm_s2`` along +x (a robot mounted sideways) at the straight pose: disk j
    of n at arc fraction s_j = j/n moves s_j^2 l / 2 per unit bending vector, so the weights
    give Q_x = g_x sum_j m s_j^2 l / 2 and the demand -Q_x; along -z they give nothing there."""
    path = _overlay(tmp_path, QI, "robot:\n  gravity_mm_s2: [9810.0, 0.0, 0.0]\n")
    p = robot_params(load_rig_config(path).robot)
    seg = p.segments[0]
    gx_N_per_g = 9810.0 * 1e-6
    Q = gx_N_per_g * sum(
        seg.disk_mass_g * (j / seg.n_disks) ** 2 * seg.length_mm / 2
        for j in range(1, seg.n_disks + 1)
    )
    m = np.array(ForceTransfer(p, Effects()).pose([0.0, 0.0]).m_req)
    assert m[0] == pytest.approx([-Q, 0.0], rel=1e-12, abs=1e-15)
    upright = robot_params(load_rig_config(QI).robot)
    assert np.array(ForceTransfer(upright, Effects()).pose([0.0, 0.0]).m_req)[0] == pytest.approx(
        [0.0, 0.0], abs=1e-15
    )
    # and the model built from the config commands it: c2/c3 (the -x side) carry it
    bent = build_cc_disk_model(load_rig_config(path))
    base = build_cc_disk_model(load_rig_config(QI))
    psi = np.zeros((1, 2))
    dT = np.asarray(bent.compensate(psi, [1.0] * 3).T_distal) - np.asarray(
        base.compensate(psi, [1.0] * 3).T_distal
    )
    assert dT[0] == pytest.approx(0.0, abs=1e-12) and dT[1] > 0 and dT[2] > 0


def test_a_tip_load_on_a_design_without_one_is_refused(tmp_path):
    from cdcr_ctl.config.build_model import build_model

    path = _overlay(
        tmp_path, ROOT / "config" / "yang2022.yaml", "robot:\n  tip_load: {payload_kg: 0.01}\n"
    )
    with pytest.raises(ConfigError) as exc:
        build_model(load_rig_config(path), source=str(path))
    assert "robot.tip_load" in str(exc.value) and str(path) in str(exc.value)


@pytest.mark.parametrize("geometry", ["cc", "chord"])
def test_forward_model_under_a_tip_load_inverts_the_compensation(geometry):
    """The simulated world's forward model carries the same tip load: the cable displacements
    the compensation commands for a pose under a 5 g payload and a sideways tip force bring the
    forward model (every effect on, stepped through a monotone path) to that pose (1e-8 rad
    of bending vector: the Newton tolerance), and not the unloaded robot."""
    from cdcr_ctl.model.cc_disk.forward import ForwardStepper
    from cdcr_ctl.model.cc_disk.kinematics import psi_to_x

    p = robot_params(load_rig_config(THREE).robot)
    loaded = replace(p, tip_mass_g=5.0, tip_force_N=(0.02, -0.01, 0.0))
    eff = Effects(geometry=geometry)
    comp, fwd, bare = Compensator(loaded, eff), ForwardStepper(loaded, eff), ForwardStepper(p, eff)
    st = comp.new_state()
    for t in np.linspace(0.05, 0.6, 8):
        psi = np.array([[t, 0.3], [0.8 * t, 1.0], [t, -0.5]])
        q = np.asarray(comp.step(psi, st).q)
        res = fwd.step(q)
        off = bare.step(q)
        assert np.max(np.abs(res.x - psi_to_x(psi).ravel())) < 1e-8
    assert np.max(np.abs(off.x - psi_to_x(psi).ravel())) > 1e-3
