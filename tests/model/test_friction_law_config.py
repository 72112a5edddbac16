"""The disk friction's law as a rig-config key (``robot.friction_law``) read by the controller's
compensation: validated on load, the capstan law by default, and the law it states otherwise
(cdcr_ctl/model/cc_disk/friction_law.py; Qi et al. 2023 eq. 16-24 at its defaults)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_cc_disk_model, friction_law
from cdcr_ctl.errors import ConfigError, ConfigErrors
from cdcr_ctl.model.cc_disk.friction_law import SPEED_MEMORY_S, LawTransfer
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer

ROOT = Path(__file__).resolve().parents[2]
QI = ROOT / "config" / "qi2023.yaml"


def _rig(tmp_path: Path, law: str) -> Path:
    p = tmp_path / "rig.yaml"
    p.write_text(f"extends: {QI}\nrobot:\n  friction_law: {law}\n")
    return p


def test_a_bad_law_is_refused_naming_file_key_and_value(tmp_path):
    """Every bad value of the section is named in one pass (file, key, value), a typo too."""
    path = _rig(
        tmp_path,
        "{wrap_exponent: 0.0, viscous_s_per_mm: -0.1, breakaway: .nan, stribeck_mm_s: 2000.0,"
        " exponent: 2.0}",
    )
    with pytest.raises((ConfigError, ConfigErrors)) as info:
        load_rig_config(path)
    errors = info.value.errors if isinstance(info.value, ConfigErrors) else [info.value]
    named = {e.key.removeprefix("robot.friction_law."): e for e in errors}
    assert set(named) == {
        "wrap_exponent",
        "viscous_s_per_mm",
        "breakaway",
        "stribeck_mm_s",
        "exponent",
    }, [str(e) for e in errors]
    assert {e.file for e in errors} == {str(path)}
    for key, value in (
        ("wrap_exponent", 0.0),
        ("viscous_s_per_mm", -0.1),
        ("stribeck_mm_s", 2000.0),
    ):
        assert named[key].value == value
        assert repr(value) in str(named[key])
    assert math.isnan(named["breakaway"].value)


def test_the_capstan_defaults_command_what_the_model_always_commanded(tmp_path):
    """The defaults written out are no law (None: the plain chain), and the law's own chain at
    p = 1 + 1e-9 commands the same as the capstan chain: W(z) = z^p moves the log ratio by
    mu z^p ln z (p - 1) < 1e-9 over the wrap here (z < 2 rad), so the commands (whose friction
    part is under 1 mm) agree to 1e-6 mm, a thousandth of a drive count (1/1238.6 mm)."""
    explicit = load_rig_config(
        _rig(
            tmp_path,
            "{wrap_exponent: 1.0, viscous_s_per_mm: 0.0, breakaway: 0.0, stribeck_mm_s: 0.4}",
        )
    )
    assert friction_law(explicit.robot) is None  # what the builder reads
    base = build_cc_disk_model(load_rig_config(QI))
    assert type(base.transfer) is ForceTransfer
    near = build_cc_disk_model(load_rig_config(_rig(tmp_path, "{wrap_exponent: 1.000000001}")))
    assert isinstance(near.transfer, LawTransfer)
    sb, sn = base.new_state(), near.new_state()
    worst = 0.0
    for t in np.linspace(0.0, 2.0 * math.pi, 13):  # out to 1.2 rad, a turn about z, and back
        psi = np.array([[1.2 * math.sin(0.5 * t), 2.0 * t]])
        qb = base.q_command(psi, base.q_nominal(psi), sb, "model", None)
        qn = near.q_command(psi, near.q_nominal(psi), sn, "model", None)
        worst = max(worst, float(np.max(np.abs(qb - qn))))
    assert worst < 1e-6


def test_a_squared_wrap_transfers_the_tension_as_the_law_says(tmp_path):
    """Qi rig, one segment of n = 5 disks: the chord routing wraps a cable by Zb = theta (2n - 1)
    / (2n) = 0.9 theta from anchor to base hole (half a disk's turn at the base, whole ones at
    the 4 inner disks). Bent to theta = 4/3 rad, Zb = 1.2 rad, so pulling (s = +1) the capstan
    law gives ln(T_base/T_distal) = mu Zb = 1.2 mu, the squared law mu Zb^2 = 1.44 mu; bent to
    Zb = 1 rad (the law's z_ref) both give mu. The squared law's larger ratio is tension the
    compensation stretches out: more pull on the loaded cable."""
    cfg = load_rig_config(_rig(tmp_path, "{wrap_exponent: 2.0}"))
    assert friction_law(cfg.robot) == FrictionLawShape(exponent=2.0)
    law = build_cc_disk_model(cfg)
    cap = build_cc_disk_model(load_rig_config(QI))
    mu = [c.mu_disk for c in cfg.robot.cables]
    s = np.ones(3)
    for zb, want_law, want_cap in ((1.2, 1.44, 1.2), (1.0, 1.0, 1.0)):
        psi = np.array([[zb / 0.9, 0.0]])
        for model, want in ((law, want_law), (cap, want_cap)):
            tr = model.compensate(psi, s)
            ln_ratio = np.log(np.asarray(tr.T_base) / np.asarray(tr.T_distal))
            assert ln_ratio == pytest.approx([want * m for m in mu], rel=1e-9)
    psi = np.array([[1.2 / 0.9, 0.0]])  # towards c1's hole: c1 carries the bend
    q_law = law.q_command(psi, law.q_nominal(psi), law.new_state(), "model", None)
    q_cap = cap.q_command(psi, cap.q_nominal(psi), cap.new_state(), "model", None)
    assert q_law[0] - q_cap[0] > 1.0 / 1238.6  # more than a drive count more pull


def test_a_speed_dependent_law_follows_the_cable_speed_of_the_loop(tmp_path):
    """m(v) = 1 + c_v v (no breakaway): one loop cycle after a step of the pose, each cable's
    speed is |dq_geom| / dt through the first-order lag, a = 1 - exp(-dt / 0.05 s)."""
    cfg = load_rig_config(_rig(tmp_path, "{viscous_s_per_mm: 0.5}"))
    model = build_cc_disk_model(cfg)
    dt = 1.0 / cfg.control.rate_hz
    st = model.new_state()
    p0, p1 = np.array([[0.6, 0.3]]), np.array([[0.605, 0.3]])
    model.q_command(p0, model.q_nominal(p0), st, "model", None)
    assert model.transfer._mu == pytest.approx([c.mu_disk for c in cfg.robot.cables], rel=1e-12)
    model.q_command(p1, model.q_nominal(p1), st, "model", None)
    v = np.abs(model.q_nominal(p1) - model.q_nominal(p0)) / dt * -math.expm1(-dt / SPEED_MEMORY_S)
    want = [c.mu_disk * (1.0 + 0.5 * vk) for c, vk in zip(cfg.robot.cables, v, strict=True)]
    assert model.transfer._mu == pytest.approx(want, rel=1e-9)
    assert max(v) > 0.1  # the step moved the cables
