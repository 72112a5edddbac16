"""Rig configs of the universal-joint and vertebra designs: loading, design sections, bus budget,
model dispatch, and the simulator's truths built from the -sim / -truth configs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.config.loader import validate_mapping
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.drives.busload import check_drives_bus_load
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.model.ujoint import UJointModel
from cdcr_ctl.model.vertebra import VertebraModel, decode_from_rotations
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.simconfig import load_sim_config

CONFIG = Path(__file__).resolve().parents[2] / "config"


@pytest.mark.parametrize(
    ("name", "cls"),
    [
        ("yang2022", UJointModel),
        ("yang2022-sim", UJointModel),
        ("vertebra", VertebraModel),
        ("vertebra-sim", VertebraModel),
    ],
)
def test_design_configs_load_and_build_their_model(name, cls):
    cfg = load_rig_config(CONFIG / f"{name}.yaml")
    model = build_model(cfg)
    assert isinstance(model, cls)
    assert model.n_cables == len(cfg.drives) and model.n_segments == len(cfg.robot.segments)
    # the loop sends one SYNC per cycle
    assert cfg.control.rate_hz == pytest.approx(1.0 / cfg.can.sync_period_s)


@pytest.mark.parametrize("name", ["yang2022", "vertebra"])
def test_sync_period_is_the_shortest_that_fits_the_bus(name):
    cfg = load_rig_config(CONFIG / f"{name}.yaml")
    args = (cfg.can.bitrate, cfg.can.max_bus_load, name)
    load = check_drives_bus_load(cfg.drives, cfg.can.sync_period_s, *args)
    assert load.load <= cfg.can.max_bus_load
    with pytest.raises(ConfigError, match="bus load"):
        check_drives_bus_load(cfg.drives, cfg.can.sync_period_s - 0.001, *args)


def test_design_sections_are_required_and_exclusive():
    data = yaml.safe_load((CONFIG / "qi2023.yaml").read_text())
    with pytest.raises(ConfigError) as err:
        validate_mapping({**data, "design": "ujoint"}, RigConfig, "x.yaml")
    assert "ujoint" in str(err.value) and "needs a 'ujoint:' section" in str(err.value)
    yang = yaml.safe_load((CONFIG / "yang2022.yaml").read_text())
    with pytest.raises(ConfigError, match="only for design ujoint"):
        validate_mapping({**yang, "design": "vertebra"}, RigConfig, "x.yaml")
    assert validate_mapping(data, RigConfig, "x.yaml").ujoint is None  # cc_disk unchanged


def test_ujoint_truth_differs_from_the_controller_where_the_sim_config_says():
    loaded = load_sim_config(CONFIG / "sim" / "yang2022-truth.yaml")
    truth = make_truth(loaded)
    nominal = build_model(loaded.rig).arm
    assert truth.arm.deformation.eta == pytest.approx(0.115)
    assert nominal.deformation.eta == pytest.approx(0.1)
    assert np.all(truth.arm.dead_zones_mm[0] > nominal.dead_zones_mm[0])
    assert truth.state.tip_mm[2] == pytest.approx(1110.0, abs=0.1)


def test_ujoint_truth_sags_under_gravity(tmp_path):
    """The long arm cantilevered off the air-bearing table (gravity along -x of the base)."""
    src = CONFIG / "sim" / "yang2022-truth.yaml"
    doc = yaml.safe_load(src.read_text())
    doc["rig"] = str((src.parent / doc["rig"]).resolve())
    doc["truth_robot"]["gravity_mm_s2"] = [-9810.0, 0.0, 0.0]
    for seg in ("seg1", "seg2"):
        doc["truth_robot"].setdefault("segments", []).append(
            {"name": seg, "disks": {"count": 6, "mass_g": 15.0, "thickness_mm": 0.0}}
        )
    path = tmp_path / "sim.yaml"
    path.write_text(yaml.safe_dump(doc))
    flat = make_truth(load_sim_config(src)).state.tip_mm
    sag = make_truth(load_sim_config(path)).state.tip_mm
    assert sag[0] < flat[0] - 1.0  # towards gravity


def test_vertebra_truth_sensors_show_the_sagged_joints():
    loaded = load_sim_config(CONFIG / "sim" / "vertebra-truth.yaml")
    truth = make_truth(loaded)
    model = build_model(loaded.rig)
    psi = np.array([[0.6, 0.66], [0.8, 0.66], [0.8, 0.66]])
    cpm = np.array([d.counts_per_mm for d in loaded.rig.drives])
    s = truth.step(np.rint(model.q_nominal(psi) * cpm).astype(np.int64))
    R = [truth.sensor_orientation(i) for i in range(3)]
    np.testing.assert_allclose(decode_from_rotations(R), s.psi, atol=1e-9)
    assert np.abs(s.psi[:, 0] - psi[:, 0]).max() > math.radians(1.0)  # gravity sag
