"""``cdcr-ctl joystick``: a live joystick end-following session through the daemon.

Asks the daemon for a ``joystick`` run (the vertebra arm's end-following from the rig's
``sensors.joystick``: an evdev device or a ``tcp://`` network joystick), then shows its progress
(stick, planner mode, distal target, steps) until the run ends. Ctrl-C sends ``stop`` (halt: the
arm holds where it is, drives stay enabled); a second Ctrl-C sends a quick stop. The exit code is
0 when the session was stopped or ran its ``--seconds``, 1 when it tripped (e.g. the joystick was
lost: the arm holds and the trip is latched until ``cdcr-ctl reset-fault``).
"""

from __future__ import annotations

import sys
import time
from typing import Any

import click

from cdcr_ctl.cli.app import Ctx
from cdcr_ctl.daemon.client import ControlClient

#: How often the progress is refreshed (s).
PROGRESS_PERIOD_S = 0.25


def progress_line(st: dict[str, Any]) -> str:
    """One line of session progress from a ``status`` reply."""
    run = st.get("run") or {}
    js = st.get("joystick") or {}
    psi = (st.get("loop") or {}).get("psi_cmd_rad") or []
    distal = psi[-1] if psi else [float("nan"), float("nan")]
    target = js.get("distal_target_rad") or [float("nan"), float("nan")]
    buttons = ",".join(js.get("buttons") or []) or "-"
    elapsed = run.get("elapsed_s") or 0.0
    limit = run.get("duration_s")
    t = f"{elapsed:6.1f} s" + (f"/{limit:.1f} s" if limit is not None else "")
    link = "connected" if js.get("connected") else "LOST"
    return (
        f"{t}  stick x {js.get('x', 0.0):+.2f} y {js.get('y', 0.0):+.2f} [{buttons}] {link}"
        f"  {js.get('mode', '?'):6s} distal theta {distal[0]:.3f} phi {distal[1]:+.3f} rad"
        f" (target {target[0]:.3f}, {target[1]:+.3f})  steps {js.get('steps', 0)}"
    )


def _ended(st: dict[str, Any], run_id: str) -> dict[str, Any] | None:
    return next((r for r in st.get("runs", []) if r["id"] == run_id), None)


def follow_session(obj: Ctx, run_id: str, show: bool) -> dict[str, Any]:
    """Poll ``status`` until run ``run_id`` ends, printing progress when ``show``; Ctrl-C sends
    ``stop`` (halt), a second one a quick stop. Returns the ended run's entry.

    A Ctrl-C may land between a request and its reply: the connection is then dropped and the
    stop goes over a new one, so no reply is ever taken for another request's.
    """
    tty = sys.stderr.isatty()
    stops = 0
    last_print = 0.0
    elapsed = 0.0  # the run's time as last seen running (a stopped run's entry restarts it)
    client = ControlClient(obj.socket)
    try:
        while True:
            try:
                st = client.call("status")
                done = _ended(st, run_id)
                if done is not None:
                    if show and tty:
                        click.echo("", err=True)
                    if done["state"] == "completed":
                        elapsed = done.get("elapsed_s") or elapsed
                    return {
                        **done,
                        "elapsed_s": round(elapsed, 2),
                        "joystick": st.get("joystick"),
                        "fault": st.get("fault"),
                    }
                run = st.get("run") or {}
                if run.get("id") == run_id:
                    elapsed = run.get("elapsed_s") or elapsed
                now = time.monotonic()
                if show and (tty or now - last_print >= 1.0):
                    line = progress_line(st)
                    click.echo(f"\r{line}" if tty else line, err=True, nl=not tty)
                    last_print = now
                time.sleep(PROGRESS_PERIOD_S)
            except KeyboardInterrupt:
                stops += 1
                mode = "halt" if stops == 1 else "quick_stop"
                if show:
                    click.echo(f"\nCtrl-C: sending stop ({mode})", err=True)
                client.close()
                client = ControlClient(obj.socket)
                client.call("stop", mode=mode)
    finally:
        client.close()


@click.command("joystick")
@click.option(
    "--seconds",
    type=click.FloatRange(min=0, min_open=True, max=24 * 3600),
    default=None,
    help="End the session after this long (default: until Ctrl-C / `cdcr-ctl stop`).",
)
@click.option(
    "--compensation",
    type=click.Choice(["off", "model", "measured"]),
    default=None,
    help="Compensation mode of the session (default: the daemon's).",
)
@click.option("--name", default="joystick", show_default=True, help="Run name for the log.")
@click.option("--log/--no-log", default=True, show_default=True, help="Log the run.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON (no progress).")
@click.pass_obj
def joystick(
    obj: Ctx,
    seconds: float | None,
    compensation: str | None,
    name: str,
    log: bool,
    as_json: bool,
) -> None:
    """Live joystick end-following (vertebra arm) from the rig's configured joystick.

    The distal joint follows the stick, the forward button makes the proximal joints follow
    (fuel-tank paper, Fig. 12). Ctrl-C stops (the arm holds).
    """
    if as_json:
        obj.as_json = True
    res = obj.call("joystick", seconds=seconds, compensation=compensation, name=name, log=log)
    show = not obj.as_json
    if show:
        limit = "" if seconds is None else f" for {seconds:g} s"
        click.echo(
            f"joystick session {res['run']} from {res['device']}{limit}"
            f" (compensation {res['compensation']}); Ctrl-C stops",
            err=True,
        )
    done = follow_session(obj, res["run"], show)
    js = done.get("joystick") or {}
    out = {
        "run": res["run"],
        "state": done["state"],
        "end_reason": done["end_reason"],
        "elapsed_s": done.get("elapsed_s"),
        "log_dir": res.get("log_dir") or None,
        "compensation": res["compensation"],
        "device": res["device"],
        "steps": js.get("steps"),
        "distal_target_rad": js.get("distal_target_rad"),
        "fault": done.get("fault"),
    }
    obj.emit(out)
    if done["state"] not in ("completed", "stopped"):
        raise SystemExit(1)
