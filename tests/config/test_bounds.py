"""Absurd limits are refused at load, naming file and key (issue #21, acceptance 5)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.errors import ConfigError, ConfigErrors

ROOT = Path(__file__).resolve().parents[2]
QI = ROOT / "config" / "qi2023.yaml"

#: (YAML text appended as an overlay-free override, key path the error must name)
ABSURD = [
    ("limits: {cable_velocity_mm_s: 1.0e6}", "limits.cable_velocity_mm_s"),
    ("limits: {cable_velocity_mm_s: .inf}", "limits.cable_velocity_mm_s"),
    ("limits: {cable_displacement_mm: [-1.0e6, 1.0e6]}", "limits.cable_displacement_mm[0]"),
    ("limits: {tension_N: [0.2, 1.0e9]}", "limits.tension_N[1]"),
    ("limits: {sensor_timeout_s: 1.0e9}", "limits.sensor_timeout_s"),
    ("limits: {bend_rad: 100.0}", "limits.bend_rad"),
    ("logging: {fsync_every_s: 1.0e9}", "logging.fsync_every_s"),
    ("daemon: {socket_mode: 0777}", "daemon.socket_mode"),
    ("daemon: {socket_mode: 0666}", "daemon.socket_mode"),
    ("daemon: {socket_mode: 0060}", "daemon.socket_mode"),
    ("can: {master_heartbeat_ms: 0}", "can.master_heartbeat_ms"),
    ("drives: [{name: m1, heartbeat_consumer_ms: 0}]", "drives[0].heartbeat_consumer_ms"),
    ("drives: [{name: m1, heartbeat_consumer_ms: 150}]", "drives[0].heartbeat_consumer_ms"),
    (
        "sensors: {load_cells: {serial: {timeout_s: 1.0e9}}}",
        "sensors.load_cells.serial.timeout_s",
    ),
    ("sensors: {load_cells: {stale_after_s: 1.0e9}}", "sensors.load_cells.stale_after_s"),
    ("sensors: {tracker: {lost_after_s: 1.0e9}}", "sensors.tracker.lost_after_s"),
]


def _child(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "rig.yaml"
    p.write_text(f"extends: {QI}\n{text}\n")
    return p


@pytest.mark.parametrize(("text", "key"), ABSURD, ids=[k for _, k in ABSURD])
def test_absurd_value_refused_naming_file_and_key(tmp_path, text, key):
    path = _child(tmp_path, text)
    with pytest.raises((ConfigError, ConfigErrors)) as info:
        load_rig_config(path)
    errors = info.value.errors if isinstance(info.value, ConfigErrors) else [info.value]
    hit = [e for e in errors if e.key == key]
    assert hit, f"no error names {key}: {[str(e) for e in errors]}"
    assert hit[0].file == str(path)


def test_exponent_without_dot_or_sign_is_a_number(tmp_path):
    # YAML 1.1 reads 1.0e6 as a string; the loader reads it as the number everyone means.
    path = _child(tmp_path, "limits: {cable_velocity_mm_s: 4.0e1, tracker_divergence_mm: 3e1}")
    cfg = load_rig_config(path)
    assert cfg.limits.cable_velocity_mm_s == 40.0
    assert cfg.limits.tracker_divergence_mm == 30.0


def test_sane_values_at_the_bounds_load(tmp_path):
    path = _child(
        tmp_path,
        "limits: {cable_velocity_mm_s: 1000.0, sensor_timeout_s: 10.0}\n"
        "daemon: {socket_mode: 0600}",
    )
    cfg = load_rig_config(path)
    assert cfg.daemon.socket_mode == 0o600


def test_socket_mode_dumps_as_octal_and_loads_back(tmp_path):
    """The effective config a run keeps says ``0o640``, not the integer 416, and loads again."""
    import yaml

    cfg = load_rig_config(_child(tmp_path, "daemon: {socket_mode: 0640}"))
    dumped = yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)
    assert "socket_mode: 0o640\n" in dumped
    again = tmp_path / "again.yaml"
    again.write_text(dumped)
    assert load_rig_config(again).daemon.socket_mode == 0o640
    assert cfg.model_dump()["daemon"]["socket_mode"] == 0o640  # Python dumps keep the number
