"""The options every ``cdcr-ctl`` command shares (:class:`Ctx`) and the small commands that only
talk to a running daemon.

The command group is :data:`cdcr_ctl.cli.main.cli`; it imports each command's module when the
command is used (:class:`~cdcr_ctl.cli.lazy.LazyGroup`), and those modules import this one.
Commands that talk to the daemon find its socket from ``--socket``, else ``$CDCR_CTL_SOCKET``,
else the ``daemon.socket_path`` of ``--config``, else ``/run/cdcr-ctl/control.sock``.
"""

from __future__ import annotations

import json
import time
from typing import Any

import click

from cdcr_ctl.daemon.client import ControlClient

DEFAULT_SOCKET = "/run/cdcr-ctl/control.sock"


class Ctx:
    """Options shared by the subcommands."""

    def __init__(self, socket: str | None, config: str | None, as_json: bool) -> None:
        self._socket = socket
        self.config = config
        self.as_json = as_json

    @property
    def socket(self) -> str:
        if self._socket:
            return self._socket
        if self.config:
            from cdcr_ctl.config import load_rig_config

            return load_rig_config(self.config).daemon.socket_path
        return DEFAULT_SOCKET

    def call(self, cmd: str, **args: Any) -> Any:
        with ControlClient(self.socket) as client:
            return client.call(cmd, **args)

    def emit(self, result: Any, text: str | None = None) -> None:
        if self.as_json:
            click.echo(json.dumps(result, indent=2, sort_keys=True, default=str))
        else:
            click.echo(text if text is not None else _as_text(result))


def _as_text(result: Any, indent: str = "") -> str:
    if isinstance(result, dict):
        lines = []
        for key, value in result.items():
            if isinstance(value, dict | list) and value:
                lines.append(f"{indent}{key}:")
                lines.append(_as_text(value, indent + "  "))
            else:
                lines.append(f"{indent}{key}: {value}")
        return "\n".join(lines)
    if isinstance(result, list):
        return "\n".join(
            (_as_text(v, indent + "  ") if isinstance(v, dict | list) else f"{indent}- {v}")
            for v in result
        )
    return f"{indent}{result}"


@click.command("check-config")
@click.argument("path", type=click.Path(dir_okay=False))
@click.pass_obj
def check_config(obj: Ctx, path: str) -> None:
    """Validate a rig config and print a summary (nothing is opened or moved). Every SDO write
    the drives' configuration plans is checked against their device descriptions too."""
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.drives.plan import check_plans

    cfg = load_rig_config(path)
    check_plans(cfg.drives, cfg.can, path)
    summary = {
        "name": cfg.name,
        "design": cfg.design,
        "segments": [s.name for s in cfg.robot.segments],
        "cables": [c.name for c in cfg.robot.cables],
        "drives": {d.name: d.node_id for d in cfg.drives},
        "bus": f"{cfg.can.interface}:{cfg.can.channel} @ {cfg.can.bitrate} bit/s",
    }
    obj.emit(summary)


@click.command()
@click.pass_obj
def status(obj: Ctx) -> None:
    """Daemon state, drives, sensors, supervisor trips, loop timing."""
    obj.emit(obj.call("status"))


@click.command()
@click.pass_obj
def enable(obj: Ctx) -> None:
    """Enable the drives (CiA 402 OPERATION ENABLED) holding the present position."""
    obj.emit(obj.call("enable"))


@click.command()
@click.pass_obj
def disable(obj: Ctx) -> None:
    """Disable the drives (controlword 0x06 -> READY TO SWITCH ON)."""
    obj.emit(obj.call("disable"))


@click.command()
@click.pass_obj
def home(obj: Ctx) -> None:
    """Home every drive with its configured 0x6098 method."""
    obj.emit(obj.call("home"))


@click.command()
@click.option("--segment", type=int, help="Segment number (1 = base).")
@click.option("--theta", "theta_rad", type=float, help="Bend angle (rad).")
@click.option("--phi", "phi_rad", type=float, help="Bending-plane direction (rad).")
@click.option("--cable", type=int, help="Cable number (1-based) for a single-cable jog.")
@click.option("--delta", "delta_mm", type=float, help="Cable displacement change (mm).")
@click.option("--speed", type=float, default=0.3, show_default=True, help="rad/s or mm/s.")
@click.pass_obj
def jog(obj: Ctx, **args: Any) -> None:
    """Move one segment to (theta, phi) or one cable by delta, bounded by the rig's limits."""
    if args.get("segment") is not None and obj.config:
        # The daemon's bound, checked before sending: the refusal names the same limit.
        from cdcr_ctl.config import load_rig_config
        from cdcr_ctl.daemon.protocol import ProtocolError, check_jog_speed

        try:
            check_jog_speed(args["speed"], load_rig_config(obj.config).limits.bend_rad)
        except ProtocolError as exc:
            raise click.UsageError(f"--speed: {exc}") from exc
    obj.emit(obj.call("jog", **args))


@click.command()
@click.option("--mode", type=click.Choice(["quick_stop", "halt"]), default="quick_stop")
@click.pass_obj
def stop(obj: Ctx, mode: str) -> None:
    """Stop now: quick stop (default) or halt the running trajectory."""
    obj.emit(obj.call("stop", mode=mode))


@click.command("reset-fault")
@click.pass_obj
def reset_fault(obj: Ctx) -> None:
    """Acknowledge a latched supervisor trip and reset drive faults."""
    obj.emit(obj.call("reset_fault", confirm=True))


@click.command()
@click.argument("mode", type=click.Choice(["off", "model", "measured"]))
@click.pass_obj
def compensation(obj: Ctx, mode: str) -> None:
    """Set the compensation mode for the next moves."""
    obj.emit(obj.call("compensation", mode=mode))


@click.group()
def log() -> None:
    """Start or stop a run log (samples.csv + CAN traffic) outside a trajectory."""


@log.command("start")
@click.option("--name", default="manual", show_default=True)
@click.pass_obj
def log_start(obj: Ctx, name: str) -> None:
    obj.emit(obj.call("log_start", name=name))


@log.command("stop")
@click.pass_obj
def log_stop(obj: Ctx) -> None:
    obj.emit(obj.call("log_stop"))


@click.command()
@click.pass_obj
def shutdown(obj: Ctx) -> None:
    """Ask the daemon to stop cleanly (as SIGTERM does)."""
    obj.emit(obj.call("shutdown"))


def wait_for_run(obj: Ctx, run_id: str, duration_s: float, progress: bool = True) -> dict:
    """Poll ``status`` until run ``run_id`` has ended, with a progress bar; the final status."""
    from tqdm import tqdm

    bar = tqdm(
        total=round(duration_s, 1),
        unit="s",
        disable=not progress or obj.as_json,
        bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} s",
    )
    try:
        with ControlClient(obj.socket) as client:
            while True:
                st = client.call("status")
                run = st.get("run") or {}
                if run.get("id") == run_id:
                    bar.n = min(bar.total, round(run.get("elapsed_s", 0.0), 1))
                    bar.refresh()
                if run.get("id") != run_id or run.get("state") != "running":
                    return st
                time.sleep(0.1)
    finally:
        bar.close()


__all__ = [
    "DEFAULT_SOCKET",
    "Ctx",
    "check_config",
    "compensation",
    "disable",
    "enable",
    "home",
    "jog",
    "log",
    "reset_fault",
    "shutdown",
    "status",
    "stop",
    "wait_for_run",
]
