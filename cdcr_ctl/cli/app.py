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


def _set(attr: str) -> Any:
    """A click callback that stores an option given after the subcommand into :class:`Ctx`."""

    def callback(ctx: click.Context, param: click.Parameter, value: Any) -> None:
        if value is None or value is False:
            return  # not given here: what the group got (or its default) stays
        obj = ctx.find_object(Ctx)
        if obj is not None:
            setattr(obj, attr, value)

    return callback


def shared_options() -> list[click.Option]:
    """``-c/--config``, ``--json`` and ``--socket`` for a subcommand: the same options as the
    command group's, so each works before or after the subcommand (``cdcr-ctl -c RIG status``,
    ``cdcr-ctl status -c RIG``). Given after it, a value overrides the group's. Fresh objects
    each call (one set per command)."""
    return [
        click.Option(
            ["--config", "-c"],
            type=click.Path(dir_okay=False),
            expose_value=False,
            callback=_set("config"),
            help="Rig config (YAML); the same as before the command.",
        ),
        click.Option(
            ["--json"],
            is_flag=True,
            default=False,
            expose_value=False,
            callback=_set("as_json"),
            help="Print machine-readable JSON.",
        ),
        click.Option(
            ["--socket"],
            envvar=None,
            expose_value=False,
            callback=_set("_socket"),
            help="Control socket of the daemon.",
        ),
    ]


def add_shared_options(command: click.Command) -> click.Command:
    """Give ``command`` (and every subcommand of a group) the :func:`shared_options` it does
    not define itself (an option of its own with the same name wins: ``joystick --json``)."""
    taken = {o for p in command.params for o in (*p.opts, *p.secondary_opts)}
    for option in shared_options():
        if not taken.intersection(option.opts):
            command.params.append(option)
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            add_shared_options(sub)
    return command


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
@click.argument("path", type=click.Path(dir_okay=False), required=False)
@click.pass_obj
def check_config(obj: Ctx, path: str | None) -> None:
    """Validate a rig config (PATH, else -c/--config) and print a summary (nothing is opened or
    moved). Every SDO write the drives' configuration plans is checked against their device
    descriptions too."""
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.drives.plan import check_plans

    path = path or obj.config
    if not path:
        raise click.UsageError("check-config needs a rig config: PATH or -c/--config")
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
    """Daemon state, drives, sensors, supervisor trips, loop timing (a summary; --json: all)."""
    st = obj.call("status")
    obj.emit(st, None if obj.as_json else status_text(st))


def _num(v: Any, digits: int = 3) -> str:
    return "-" if v is None else f"{v:.{digits}f}" if isinstance(v, float) else str(v)


def status_text(st: dict[str, Any]) -> str:
    """The ``status`` reply in a screenful: the rig's state, one line per drive, sensors, the
    fault, the run and the loop's timing (``--json`` gives every field)."""
    lines = [
        f"{st.get('rig')} ({st.get('design')}): {st.get('state')}, "
        + ("enabled" if st.get("enabled") else "disabled")
        + (", homed" if st.get("homed") else ", not homed")
        + f", compensation {st.get('compensation')}",
        f"config   {st.get('config')}",
        "logging  " + (str(st.get("log_dir") or "yes") if st.get("logging") else "no"),
    ]
    fault = st.get("fault")
    if fault:
        lines.append(
            f"FAULT    {fault.get('cause')} ({fault.get('reaction')}): {fault.get('detail')}"
        )
    lines.append("drives")
    tensions = st.get("tension_N") or []
    for k, d in enumerate(st.get("drives") or []):
        row = f"  {d.get('cable')!s:6s} {d.get('state')!s:24s}"
        row += f" {d.get('position_counts')!s:>10s} counts"
        if k < len(tensions):
            row += f"  {_num(tensions[k], 2):>8s} N"
        if d.get("state") == "STALE":
            row += f"  (last {d.get('last_state')}, {d.get('age_s')} s old)"
        if d.get("fault"):
            row += f"  fault: {d['fault']}"
        lines.append(row)
    tip = st.get("tip_mm")
    if tip is not None:
        lines.append(
            "tip      "
            + " ".join(_num(v, 2) for v in tip)
            + f" mm (age {_num(st.get('tip_age_s'))} s)"
        )
    run = st.get("run")
    if run:
        lines.append(
            f"run      {run.get('name')} [{run.get('state')}] {_num(run.get('elapsed_s'), 1)}"
            f"/{_num(run.get('duration_s'), 1)} s  log {run.get('log_dir') or '-'}"
        )
    for r in (st.get("runs") or [])[-3:]:
        lines.append(
            f"  ran    {r.get('name')} [{r.get('state')}] {r.get('end_reason') or ''}  "
            f"log {r.get('log_dir') or '-'}"
        )
    loop = st.get("loop") or {}
    timing = loop.get("timing") or {}
    stats = ", ".join(f"{k} {_num(v, 1)}" for k, v in timing.items() if isinstance(v, int | float))
    lines.append(
        f"loop     {loop.get('cycles')} cycles, {loop.get('missed_cycles')} missed, "
        f"{loop.get('long_cycles')} long" + (f"; {stats}" if stats else "")
    )
    trips = st.get("trips") or []
    if trips:
        last = trips[-1]
        lines.append(f"trips    {len(trips)}, last {last.get('cause')}: {last.get('detail')}")
    return "\n".join(lines)


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
    """Move one segment to (theta, phi) or one cable by delta, bounded by the rig's limits.

    The daemon checks every bound (segment and cable numbers, bend, displacement, speed) and
    refuses naming the allowed range and its unit (exit status 1)."""
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
