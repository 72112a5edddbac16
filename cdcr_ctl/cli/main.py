"""``cdcr-ctl``: start the daemon or the simulated rig, and talk to a running daemon.

:data:`cli` is the command group: its options and the table of its commands (:data:`COMMANDS`),
each imported only when it is used (:class:`~cdcr_ctl.cli.lazy.LazyGroup`), so that a process
started for one command imports what that command needs (``cdcr-ctl status`` no scipy, no rig).
``main(argv)`` runs a command in-process (tests) and turns errors into exit codes.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import click

from cdcr_ctl.cli.app import Ctx, add_shared_options
from cdcr_ctl.cli.lazy import LazyGroup
from cdcr_ctl.daemon.client import DaemonError
from cdcr_ctl.errors import RigError

#: Every command of ``cdcr-ctl``: name -> ``"module.attribute"`` of its :class:`click.Command`.
COMMANDS: dict[str, str] = {
    # the small commands that talk to a running daemon
    "check-config": "cdcr_ctl.cli.app.check_config",
    "compensation": "cdcr_ctl.cli.app.compensation",
    "disable": "cdcr_ctl.cli.app.disable",
    "enable": "cdcr_ctl.cli.app.enable",
    "home": "cdcr_ctl.cli.app.home",
    "jog": "cdcr_ctl.cli.app.jog",
    "log": "cdcr_ctl.cli.app.log",
    "reset-fault": "cdcr_ctl.cli.app.reset_fault",
    "shutdown": "cdcr_ctl.cli.app.shutdown",
    "status": "cdcr_ctl.cli.app.status",
    "stop": "cdcr_ctl.cli.app.stop",
    # the daemon, the simulated rig, runs and their logs
    "daemon": "cdcr_ctl.cli.commands.daemon",
    "sim": "cdcr_ctl.cli.commands.sim",
    "trajectory": "cdcr_ctl.cli.commands.trajectory_cmd",
    "plot": "cdcr_ctl.cli.commands.plot",
    "demo": "cdcr_ctl.cli.demo.demo",
    "export": "cdcr_ctl.cli.runlogs.export_cmd",
    "watch": "cdcr_ctl.cli.watch.watch",
    "joystick": "cdcr_ctl.cli.joystick.joystick",
    "scan": "cdcr_ctl.cli.scan.scan",
    # calibration, the paper's experiments, the discrepancy analysis
    "identify": "cdcr_ctl.cli.identify.identify_cmd",
    "experiments": "cdcr_ctl.cli.experiments.experiments_cmd",
    "discrepancy": "cdcr_ctl.cli.discrepancy.discrepancy",
}


@click.group(
    cls=LazyGroup,
    lazy_subcommands=COMMANDS,
    shared_options=add_shared_options,
    context_settings={"help_option_names": ["-h", "--help"]},
)
@click.option("--socket", envvar="CDCR_CTL_SOCKET", help="Control socket of the daemon.")
@click.option(
    "--config",
    "-c",
    type=click.Path(dir_okay=False),
    help="Rig config (YAML); gives the socket path when --socket is not set.",
)
@click.option("--json", "as_json", is_flag=True, help="Print machine-readable JSON.")
# -c/--config, --json and --socket are taken after the subcommand too (cli.app.shared_options).
@click.version_option(package_name="cdcr-ctl")
@click.pass_context
def cli(ctx: click.Context, socket: str | None, config: str | None, as_json: bool) -> None:
    """Controller for cable-driven continuum robot rigs."""
    ctx.obj = Ctx(socket, config, as_json)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (2 for usage/config errors, 1 for rig errors)."""
    try:
        rv = cli.main(
            args=list(argv) if argv is not None else None,
            prog_name="cdcr-ctl",
            standalone_mode=False,
        )
        if isinstance(rv, int) and not isinstance(rv, bool):
            return rv  # a command's click.exceptions.Exit(code) (click returns the code here)
    except click.exceptions.Exit as exc:
        return int(exc.exit_code or 0)
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 130
    except DaemonError as exc:
        click.echo(f"error: {exc}", err=True)
        return 1
    except RigError as exc:
        click.echo(f"error: {exc}", err=True)
        return 2 if exc.__class__.__name__.startswith("Config") else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["COMMANDS", "cli", "main"]
