"""Rig config loader: shipped configs load; malformed ones are rejected naming file and key."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.errors import ConfigError, ConfigErrors

ROOT = Path(__file__).resolve().parents[2]
QI = ROOT / "config" / "qi2023.yaml"


def _base() -> dict:
    return yaml.safe_load(QI.read_text())


def _write(tmp_path: Path, data: dict | str, name: str = "rig.yaml") -> Path:
    p = tmp_path / name
    p.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False))
    return p


def test_shipped_qi_config_loads_with_derived_stiffness():
    cfg = load_rig_config(QI)
    seg = cfg.robot.segments[0]
    # NiTi rod, E = 60 GPa, d = 0.8 mm: EI = E * pi d^4 / 64
    assert seg.backbone.EI == pytest.approx(60000.0 * math.pi * 0.8**4 / 64.0)
    cable = cfg.robot.cables[0]
    assert cable.EA == pytest.approx(4960.0 * math.pi * 0.8**2 / 4.0)
    assert [d.node_id for d in cfg.drives] == [1, 2, 3]
    assert [c.mu_disk for c in cfg.robot.cables] == [0.26, 0.31, 0.28]  # Qi et al. 2023 Table 1


def _del(d: dict, *path):
    for p in path[:-1]:
        d = d[p]
    del d[path[-1]]


def _set(d: dict, value, *path):
    for p in path[:-1]:
        d = d[p]
    d[path[-1]] = value


# Each case: (description, mutation, expected key path in the message, expected value or None)
CASES = [
    (
        "missing key",
        lambda d: _del(d, "robot", "segments", 0, "length_mm"),
        "robot.segments[0].length_mm",
        None,
    ),
    (
        "wrong unit type",
        lambda d: _set(d, "90 mm", "robot", "segments", 0, "length_mm"),
        "robot.segments[0].length_mm",
        "90 mm",
    ),
    (
        "negative length",
        lambda d: _set(d, -90.0, "robot", "segments", 0, "length_mm"),
        "robot.segments[0].length_mm",
        -90.0,
    ),
    (
        "cable ends in a missing segment",
        lambda d: _set(d, "seg7", "robot", "cables", 1, "segment"),
        "robot.cables[1].segment",
        "seg7",
    ),
    ("duplicate node id", lambda d: _set(d, 1, "drives", 2, "node_id"), "drives[2].node_id", 1),
    (
        "unknown key (typo)",
        lambda d: _set(d, 2.0, "robot", "cables", 0, "pretention_N"),
        "robot.cables[0].pretention_N",
        2.0,
    ),
    (
        "negative pretension",
        lambda d: _set(d, -1.0, "robot", "cables", 2, "pretension_N"),
        "robot.cables[2].pretension_N",
        -1.0,
    ),
    (
        "pulley not defined",
        lambda d: _set(d, ["guide_a", "guide_z"], "robot", "cables", 0, "pulleys"),
        "robot.cables[0].pulleys[1]",
        "guide_z",
    ),
    (
        "node id out of range",
        lambda d: _set(d, 200, "drives", 0, "node_id"),
        "drives[0].node_id",
        200,
    ),
    ("non-standard bitrate", lambda d: _set(d, 999_999, "can", "bitrate"), "can.bitrate", 999_999),
    (
        "drive pulls a missing cable",
        lambda d: _set(d, "c9", "drives", 1, "cable"),
        "drives[1].cable",
        "c9",
    ),
    ("EPOS2 asked for CSP", lambda d: d["drives"][0].update(type="epos2"), "drives[0]", None),
    (
        "improved-capstan n above 1",
        lambda d: _set(d, 1.5, "robot", "pulleys", 0, "n"),
        "robot.pulleys[0].n",
        1.5,
    ),
    (
        "limits reversed",
        lambda d: d.setdefault("limits", {}).update(tension_N=[50.0, 1.0]),
        "limits",
        None,
    ),
    (
        "two load cells on one slave",
        lambda d: _set(d, 1, "sensors", "load_cells", "cells", 2, "slave"),
        "sensors.load_cells.cells[2].slave",
        1,
    ),
    (
        "bool where a number belongs",
        lambda d: _set(d, True, "robot", "cables", 0, "routing_radius_mm"),
        "robot.cables[0].routing_radius_mm",
        True,
    ),
]


@pytest.mark.parametrize("desc,mutate,key,value", CASES, ids=[c[0] for c in CASES])
def test_malformed_config_is_rejected_naming_file_and_key(tmp_path, desc, mutate, key, value):
    data = _base()
    mutate(data)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as info:
        load_rig_config(path)
    errors = info.value.errors if isinstance(info.value, ConfigErrors) else [info.value]
    hits = [e for e in errors if e.key.startswith(key)]
    assert hits, f"{desc}: no error at {key!r} in {info.value}"
    assert all(e.file == str(path) for e in hits)
    if value is not None:
        assert hits[0].value == value
    assert str(path) in str(info.value) and key in str(info.value)


def test_yaml_syntax_error_names_line(tmp_path):
    path = _write(tmp_path, "name: x\nrobot: [unclosed\n")
    with pytest.raises(ConfigError) as info:
        load_rig_config(path)
    assert info.value.file == str(path)
    assert info.value.key.startswith("line ")


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_rig_config(tmp_path / "nope.yaml")


def test_top_level_not_a_mapping(tmp_path):
    with pytest.raises(ConfigError, match="mapping"):
        load_rig_config(_write(tmp_path, "- 1\n- 2\n"))


def test_all_errors_reported_in_one_pass(tmp_path):
    data = _base()
    _set(data, -1.0, "robot", "segments", 0, "length_mm")
    _set(data, "x", "robot", "cables", 0, "hole_angle_rad")
    with pytest.raises(ConfigErrors) as info:
        load_rig_config(_write(tmp_path, data))
    keys = {e.key for e in info.value.errors}
    assert {"robot.segments[0].length_mm", "robot.cables[0].hole_angle_rad"} <= keys


def test_overlay_merges_by_name_and_errors_name_the_overlay(tmp_path):
    data = _base()
    data["overlays"] = ["identified.yaml"]
    main = _write(tmp_path, data)
    overlay = {"robot": {"cables": [{"name": "c2", "mu_disk": 0.123}]}}
    _write(tmp_path, overlay, "identified.yaml")
    cfg = load_rig_config(main)
    assert [c.mu_disk for c in cfg.robot.cables] == [0.26, 0.123, 0.28]

    overlay["robot"]["cables"][0]["mu_disk"] = -0.5
    over_path = _write(tmp_path, overlay, "identified.yaml")
    with pytest.raises(ConfigError) as info:
        load_rig_config(main)
    assert info.value.file == str(over_path.resolve())
    assert info.value.key == "robot.cables[1].mu_disk"


def test_extends_merges_child_over_parent_and_blames_the_right_file(tmp_path):
    parent = _write(tmp_path, _base(), "parent.yaml")
    child = {
        "extends": "parent.yaml",
        "can": {"interface": "slcan", "channel": "/tmp/x/can"},
        "robot": {"cables": [{"name": "c3", "pretension_N": 3.5}]},
    }
    child_path = _write(tmp_path, child, "child.yaml")
    cfg = load_rig_config(child_path)
    assert (cfg.can.interface, cfg.can.channel, cfg.can.bitrate) == (
        "slcan",
        "/tmp/x/can",
        1_000_000,
    )
    assert [c.pretension_N for c in cfg.robot.cables] == [2.0, 2.0, 3.5]

    child["can"]["bitrate"] = 7  # a bad key written in the child is the child's
    _write(tmp_path, child, "child.yaml")
    with pytest.raises(ConfigError) as info:
        load_rig_config(child_path)
    assert (info.value.file, info.value.key) == (str(child_path), "can.bitrate")

    data = _base()
    data["drives"][0]["node_id"] = 0  # a bad key inherited from the parent is the parent's
    _write(tmp_path, data, "parent.yaml")
    del child["can"]["bitrate"]
    _write(tmp_path, child, "child.yaml")
    with pytest.raises(ConfigError) as info:
        load_rig_config(child_path)
    assert (info.value.file, info.value.key) == (str(parent.resolve()), "drives[0].node_id")


def test_extends_cycle_is_an_error_not_a_hang(tmp_path):
    _write(tmp_path, "extends: b.yaml\nname: a\n", "a.yaml")
    _write(tmp_path, "extends: a.yaml\nname: b\n", "b.yaml")
    with pytest.raises(ConfigError, match="chain deeper"):
        load_rig_config(tmp_path / "a.yaml")
