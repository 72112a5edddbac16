"""Options where people type them: ``-c/--config``, ``--json`` and ``--socket`` are taken before
and after the subcommand, by every command (``cdcr_ctl.cli.app.shared_options``); the run-log
directory's default (``logging.directory``, ``$STATE_DIRECTORY/runs``, ``./runs``) and the
daemon's refusal to start when it cannot write there."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import click
import pytest

from cdcr_ctl.cli.main import COMMANDS, cli, main
from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.control import LoggingConfig, run_log_dir

ROOT = Path(__file__).resolve().parents[2]
SIM_RIG = ROOT / "config" / "qi2023-sim.yaml"
EXE = Path(sys.executable).parent / "cdcr-ctl"


def _commands(group: click.Group, ctx: click.Context):
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        yield name, cmd
        if isinstance(cmd, click.Group):
            for sub in cmd.list_commands(ctx):
                yield f"{name} {sub}", cmd.get_command(ctx, sub)


def test_every_command_takes_the_shared_options_after_it():
    ctx = click.Context(cli)
    seen = dict(_commands(cli, ctx))
    assert set(COMMANDS) <= set(seen)
    for name, cmd in seen.items():
        opts = {o for p in cmd.params for o in p.opts}
        assert {"-c", "--config", "--json", "--socket"} <= opts, (name, sorted(opts))
        if name != "log":  # a group: its subcommands do the work
            assert "--rig-config" not in {
                o for p in cmd.params if not getattr(p, "hidden", False) for o in p.opts
            }, name


@pytest.mark.parametrize(
    "argv",
    [
        ["-c", "{cfg}", "--json", "check-config"],
        ["check-config", "-c", "{cfg}", "--json"],
        ["--json", "check-config", "--config", "{cfg}"],
        ["--json", "-c", "{cfg}", "check-config"],
    ],
)
def test_config_and_json_before_or_after_the_command(argv, capsys):
    assert main([a.format(cfg=SIM_RIG) for a in argv]) == 0
    assert json.loads(capsys.readouterr().out)["name"] == "qi2023-sim"


def test_a_config_after_the_command_names_the_daemon_to_call(tmp_path, capsys):
    """``status -c RIG``: the socket comes from RIG (no daemon there: the error names it)."""
    rig = tmp_path / "rig.yaml"
    sock = tmp_path / "nobody.sock"
    rig.write_text(f"extends: {SIM_RIG}\ndaemon: {{socket_path: {sock}}}\n")
    assert main(["status", "-c", str(rig), "--json"]) == 1
    assert f"{sock}: cannot connect to the daemon" in capsys.readouterr().err
    assert main(["status", "--socket", str(tmp_path / "other.sock")]) == 1
    assert "other.sock" in capsys.readouterr().err


def test_run_log_directory_default_and_relative_to_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    env: dict[str, str] = {}
    assert run_log_dir(LoggingConfig(), env) == tmp_path / "runs"
    assert run_log_dir(LoggingConfig(), {"STATE_DIRECTORY": "/var/lib/cdcr-ctl"}) == Path(
        "/var/lib/cdcr-ctl/runs"
    )
    assert run_log_dir(LoggingConfig(directory="logs/a"), {"STATE_DIRECTORY": "/x"}) == (
        tmp_path / "logs" / "a"
    )
    assert load_rig_config(SIM_RIG).logging.directory is None  # the shipped configs: default


def test_daemon_refuses_to_start_when_it_cannot_write_its_logs(tmp_path):
    """Named at once, before the bus is opened (its channel does not even exist)."""
    rig = tmp_path / "rig.yaml"
    rig.write_text(
        f"extends: {SIM_RIG}\ncan: {{channel: {tmp_path / 'no-such-can'}}}\n"
        f"daemon: {{socket_path: {tmp_path / 'c.sock'}}}\n"
        "logging: {directory: /dev/null/runs}\n"
    )
    t0 = time.monotonic()
    res = subprocess.run(
        [str(EXE), "daemon", "-c", str(rig)], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 1, res.stderr[-1500:]
    assert "/dev/null/runs: the run-log directory is not writable" in res.stderr
    assert "no-such-can" not in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "c.sock").exists()
    print(f"refused in {time.monotonic() - t0:.2f} s")


def test_status_text_is_a_summary_with_one_line_per_drive():
    from cdcr_ctl.cli.app import status_text

    drives = [
        {"cable": f"c{k}", "state": "FAULT" if k == 1 else "SWITCH ON DISABLED",
         "position_counts": 100 * k, "fault": "node 1: boot-up message" if k == 1 else ""}
        for k in (1, 2, 3)
    ]  # fmt: skip
    st = {
        "rig": "qi2023-sim", "design": "cc_disk", "state": "ready", "enabled": False,
        "homed": True, "compensation": "model", "config": "/etc/cdcr-ctl/rig.yaml",
        "drives": drives, "tension_N": [5.0, None, 4.25], "tip_mm": [1.0, 2.0, 88.5],
        "tip_age_s": 0.004, "logging": True, "log_dir": "/var/lib/cdcr-ctl/runs/r1",
        "fault": {"cause": "nmt:node1", "reaction": "QUICK_STOP", "detail": "drive restarted"},
        "trips": [], "run": None, "runs": [],
        "loop": {"cycles": 10, "missed_cycles": 0, "long_cycles": 0, "timing": {"p99_us": 412.5},
                 "last": {f"x{i}": i for i in range(150)}},
    }  # fmt: skip
    lines = status_text(st).splitlines()
    assert lines[0] == "qi2023-sim (cc_disk): ready, disabled, homed, compensation model"
    assert "logging  /var/lib/cdcr-ctl/runs/r1" in lines
    assert any(x.startswith("FAULT    nmt:node1 (QUICK_STOP)") for x in lines)
    rows = [x for x in lines if x.startswith("  c")]
    assert len(rows) == 3 and rows[0].endswith("fault: node 1: boot-up message")
    assert "fault" not in rows[1] and "fault" not in rows[2] and " - N" in rows[1]
    assert len(lines) < 20  # the loop's last row (150 fields) is in --json only
