"""``scripts/install-service`` staged into a directory (``--root``): the user and group, the
config with what it extends, the unit, the CAN bring-up files, as a lab's root would get them;
the staged config loads, and the staged unit passes ``systemd-analyze verify``."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cdcr_ctl.config import load_rig_config

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "install-service"


def install(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(SCRIPT), *args], capture_output=True, text=True, timeout=120)


@pytest.mark.skipif(shutil.which("systemd-sysusers") is None, reason="no systemd-sysusers")
def test_staged_install_has_user_config_unit_and_can_bring_up(tmp_path):
    stage = tmp_path / "stage"
    prefix = Path(sys.executable).parents[2]  # this checkout's venv stands in for PREFIX/.venv
    res = install(
        "--root", str(stage), "--no-venv", "--prefix", str(prefix),
        "--config", str(ROOT / "config" / "qi2023-sim.yaml"),
        "--can-bitrate", "500000", "--slcan", "ad50:60c4",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    etc = stage / "etc"
    assert "cdcr:x:" in (etc / "passwd").read_text() and "cdcr:x:" in (etc / "group").read_text()
    # The config and the file it extends, side by side; it loads as the daemon would load it.
    assert {p.name for p in (etc / "cdcr-ctl").iterdir()} == {"rig.yaml", "qi2023.yaml"}
    assert oct((etc / "cdcr-ctl" / "rig.yaml").stat().st_mode & 0o777) == "0o640"
    cfg = load_rig_config(etc / "cdcr-ctl" / "rig.yaml")
    assert cfg.name == "qi2023-sim" and cfg.logging.directory is None  # logs: StateDirectory
    unit = etc / "systemd" / "system" / "cdcr-ctl.service"
    text = unit.read_text()
    assert f"ExecStart={prefix}/.venv/bin/cdcr-ctl daemon --config /etc/cdcr-ctl/rig.yaml" in text
    assert "StateDirectory=cdcr-ctl" in text and "WorkingDirectory=/var/lib/cdcr-ctl" in text
    network = (etc / "systemd" / "network" / "80-cdcr-can0.network").read_text()
    assert "Name=can0" in network and "\nBitRate=500000\n" in network
    rules = (etc / "udev" / "rules.d" / "90-cdcr-slcan.rules").read_text()
    assert 'ATTRS{idVendor}=="ad50", ATTRS{idProduct}=="60c4", SYMLINK+="cdcr-can"' in rules
    if shutil.which("systemd-analyze") and (prefix / ".venv" / "bin" / "cdcr-ctl").exists():
        verify = subprocess.run(
            ["systemd-analyze", "verify", str(unit)], capture_output=True, text=True
        )
        assert verify.returncode == 0, verify.stderr


def test_bad_options_are_named_before_anything_is_done(tmp_path):
    stage = tmp_path / "stage"
    res = install("--root", str(stage), "--no-venv", "--config", str(tmp_path / "none.yaml"))
    assert res.returncode == 1 and "none.yaml: no such file" in res.stderr
    res = install("--root", str(stage), "--no-venv", "--can-bitrate", "fast")
    assert res.returncode == 1 and "--can-bitrate fast" in res.stderr
    assert not stage.exists()


def test_dry_run_lists_the_commands(tmp_path):
    res = install("--dry-run", "--config", str(ROOT / "config" / "qi2023.yaml"), "--operator", "al")
    assert res.returncode == 0, res.stderr
    for step in ("systemd-sysusers", "usermod -a -G cdcr al", "-m venv", "requirements.lock",
                 "check-config -c /etc/cdcr-ctl/rig.yaml", "systemctl daemon-reload"):  # fmt: skip
        assert step in res.stdout, (step, res.stdout)
