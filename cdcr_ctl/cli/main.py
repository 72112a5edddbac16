"""``cdcr-ctl``: start the daemon or the simulated rig, and talk to a running daemon.

``main(argv)`` runs a command in-process (tests) and turns errors into exit codes. The command
group and the small daemon commands are in :mod:`cdcr_ctl.cli.app`; importing the command modules
here registers the rest on it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import click

from cdcr_ctl.cli import (
    commands,  # noqa: F401  registers the heavier commands (daemon, sim, trajectory, plot, demo)
    discrepancy,  # noqa: F401  registers discrepancy
    identify,  # noqa: F401  registers identify, experiments
    joystick,  # noqa: F401  registers joystick
    runlogs,  # noqa: F401  registers export
    scan,  # noqa: F401  registers scan
    watch,  # noqa: F401  registers watch
)
from cdcr_ctl.cli.app import Ctx, cli, wait_for_run
from cdcr_ctl.daemon.client import DaemonError
from cdcr_ctl.errors import RigError


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


__all__ = ["Ctx", "cli", "main", "wait_for_run"]
