"""The CLI imports what the command it runs needs (every ``cdcr-ctl`` process the tests
and the demo start pays its imports).

The command group (:data:`cdcr_ctl.cli.main.cli`) imports a command's module when the command is
used; ``cdcr-ctl --help`` imports them all for their short help, so the command modules keep
their heavy imports (the identification, the run logs, the rig, the terminal page) inside the
commands. A light command, or the help, in a fresh interpreter must not load them.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import click
import pytest

from cdcr_ctl.cli.main import COMMANDS, cli, main

#: What ``--help`` and a command that only talks to the daemon must not import: the layers below
#: the daemon's client (``cdcr_ctl.daemon.protocol`` itself is needed: requests are validated
#: before they are sent) and the heavy libraries only some commands use.
HEAVY = (
    "cdcr_ctl.config",
    "cdcr_ctl.control",
    "cdcr_ctl.discrepancy",
    "cdcr_ctl.drives",
    "cdcr_ctl.identify",
    "cdcr_ctl.model",
    "cdcr_ctl.runlog",
    "cdcr_ctl.sensors",
    "cdcr_ctl.sim",
    "matplotlib",
    "rich",
    "scipy.optimize",
    "scipy.stats",
    "tqdm",
)


def test_every_command_loads_under_its_name():
    ctx = click.Context(cli)
    for name in COMMANDS:
        command = cli.get_command(ctx, name)
        assert isinstance(command, click.Command)
        assert command.name == name


def test_help_lists_every_command_with_its_short_help(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    ctx = click.Context(cli)
    for name in COMMANDS:
        short = cli.get_command(ctx, name).get_short_help_str(limit=45)
        line = next((ln for ln in out.splitlines() if ln.split()[:1] == [name]), "")
        assert short[:20] in line, f"{name}: {line!r}"


@pytest.mark.parametrize(
    "argv", [["--help"], ["--socket", "/nonexistent/cdcr-ctl.sock", "status"]], ids=str
)
def test_a_light_command_imports_nothing_heavy(argv):
    code = (
        "import contextlib, io, sys\n"
        "from cdcr_ctl.cli.main import main\n"
        "out, err = io.StringIO(), io.StringIO()\n"
        "with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):\n"
        f"    main({argv!r})\n"
        "print(' '.join(sorted(sys.modules)))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    ).stdout
    loaded = out.split()
    heavy = sorted(m for m in loaded if any(m == h or m.startswith(h + ".") for h in HEAVY))
    assert heavy == []


def test_loading_a_rig_config_imports_no_solver():
    """`cdcr-ctl check-config RIG` (and every `cdcr-ctl -c RIG COMMAND`, which loads the config
    the same way) loads and validates the config without the model's solvers: scipy is for the
    processes that build the model (the daemon, the simulator)."""
    rig = Path(__file__).resolve().parents[2] / "config" / "qi2023-sim.yaml"
    code = (
        "import contextlib, io, sys\n"
        "from cdcr_ctl.cli.main import main\n"
        "out = io.StringIO()\n"
        "with contextlib.redirect_stdout(out):\n"
        f"    code = main(['check-config', {str(rig)!r}])\n"
        "assert code in (0, None), (code, out.getvalue())\n"
        "assert 'qi2023-sim' in out.getvalue(), out.getvalue()\n"
        "print(' '.join(sorted(sys.modules)))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    ).stdout
    assert "cdcr_ctl.config.loader" in out.split()
    assert [m for m in out.split() if m == "scipy" or m.startswith("scipy.")] == []
