"""RigConfig -> model dataclasses: values, units, order, pulleys, load cells, design guard."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model, cable_names, loadcell_locations, robot_params
from cdcr_ctl.errors import ConfigErrors
from cdcr_ctl.model.cc_disk.compensation import CCDiskModel

ROOT = Path(__file__).resolve().parents[2]
QI = ROOT / "config" / "qi2023.yaml"
THREE = ROOT / "config" / "three_segment_example.yaml"


def test_qi_config_to_params():
    cfg = load_rig_config(QI)
    p = robot_params(cfg.robot)
    assert p.n_segments == 1 and p.n_cables == 3
    seg = p.segments[0]
    assert seg.EI_Nmm2 == pytest.approx(60000.0 * math.pi * 0.8**4 / 64.0)
    assert (seg.length_mm, seg.n_disks, seg.disk_mass_g, seg.disk_thickness_mm) == (
        90.0,
        5,
        0.8,
        2.0,
    )
    c = p.cables[1]
    assert c.segment == 0 and c.hole_angle_rad == 2.0944 and c.mu_disk == 0.31
    assert c.EA_N == pytest.approx(4960.0 * math.pi * 0.8**2 / 4.0)
    assert [q.name for q in c.pulleys] == ["guide_a", "guide_b"]
    assert c.pulleys[0].n == 0.67 and c.pulleys[0].radius_mm == 8.0
    assert p.gravity_mm_s2 == (0.0, 0.0, -9810.0)
    assert loadcell_locations(cfg) == ["robot_base"] * 3
    assert cable_names(cfg) == ["c1", "c2", "c3"]


def test_three_segment_example_builds_a_loop_model():
    cfg = load_rig_config(THREE)
    model = build_model(cfg)
    assert isinstance(model, CCDiskModel)
    assert model.n_segments == 3 and model.n_cables == 9
    assert [c.segment for c in model.params.cables] == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert model.locations == ["actuator"] * 3 + ["robot_base"] * 6
    psi = np.array([[0.5, 0.2], [0.4, 1.0], [0.3, -1.0]])
    state = model.new_state()
    q = model.q_command(psi, model.q_nominal(psi), state, "model", None)
    assert q.shape == (9,) and np.all(np.isfinite(q))
    assert model.tip(psi).shape == (3,)


def test_cable_order_follows_config_and_segments_resolve_by_name(tmp_path):
    data = yaml.safe_load(THREE.read_text())
    data["robot"]["cables"] = list(reversed(data["robot"]["cables"]))
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    p = robot_params(load_rig_config(path).robot)
    assert [c.name for c in p.cables][:2] == ["c33", "c32"]
    assert [c.segment for c in p.cables] == [2, 2, 2, 1, 1, 1, 0, 0, 0]


def test_a_design_without_its_section_is_refused(tmp_path):
    data = yaml.safe_load(QI.read_text())
    data["design"] = "ujoint"
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigErrors) as err:
        load_rig_config(path)
    assert any(e.key.startswith("ujoint") and e.file == str(path) for e in err.value.errors)
    assert "needs a 'ujoint:' section" in str(err.value)
