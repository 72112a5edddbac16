"""``cdcr-ctl watch``: a live status page in the terminal, for a rig PC without a browser.

Polls the daemon's ``status`` a few times a second (``--hz``, default 4) and redraws one page
with rich: daemon state and run, drives (state, fault, position), the latched fault and the last
trips, tensions, tracked tip, the tip error and the loop's lateness. The tip error is the distance
between the tracked tip and the model tip of the commanded pose of the same cycle (the rig
config named by the daemon's status, built once), without the supervisor's lag model: a view, not
the limit check. Ctrl-C ends it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import click

from cdcr_ctl.cli.app import Ctx
from cdcr_ctl.daemon.client import ControlClient
from cdcr_ctl.errors import RigError

if TYPE_CHECKING:
    import numpy as np
    from rich.console import Group

#: The model tip (mm) of the loop's commanded configuration ``psi_cmd_rad``.
TipModel = Callable[["np.ndarray"], "np.ndarray"]


def _fmt(v: Any, digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def tip_error_mm(st: dict[str, Any], tip_model: TipModel | None) -> float | None:
    """|tracked - model tip| of the last cycle (mm), or None without tracker, model or command."""
    import numpy as np

    last = (st.get("loop") or {}).get("last") or {}
    tracked = [last.get(f"tip_{a}_mm") for a in "xyz"]
    psi = st.get("loop", {}).get("psi_cmd_rad")
    if tip_model is None or psi is None or any(v is None for v in tracked):
        return None
    try:
        tip = np.asarray(tip_model(np.asarray(psi, dtype=float)), dtype=float).reshape(3)
    except Exception:
        return None
    return float(np.linalg.norm(np.asarray(tracked, dtype=float) - tip))


def status_page(st: dict[str, Any], tip_err: float | None, polled: str = "") -> Group:
    """The page for one ``status`` reply."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    run = st.get("run") or {}
    head = Text()
    head.append(f"{st.get('rig', '?')} ({st.get('design', '?')})  ", style="bold")
    state = st.get("state", "?")
    head.append(f"state {state}", style="bold green" if state == "ready" else "bold yellow")
    head.append(
        f"  enabled {st.get('enabled')}  homed {st.get('homed')}"
        f"  compensation {st.get('compensation')}  logging {st.get('logging')}"
    )
    if run:
        head.append(
            f"\nrun {run.get('name')} [{run.get('state')}] "
            f"{_fmt(run.get('elapsed_s'), 1)}/{_fmt(run.get('duration_s'), 1)} s"
            f"  log {run.get('log_dir') or '-'}"
        )
    drives = Table(title="drives", expand=False)
    for col in ("cable", "state", "fault", "position (counts)", "tension (N)"):
        drives.add_column(col)
    tensions = st.get("tension_N") or []
    for k, d in enumerate(st.get("drives") or []):
        fault = d.get("fault")
        drives.add_row(
            str(d.get("cable")),
            str(d.get("state")),
            Text(str(fault or "-"), style="red" if fault else ""),
            str(d.get("position_counts")),
            _fmt(tensions[k] if k < len(tensions) else None),
        )
    loop = st.get("loop") or {}
    last = loop.get("last") or {}
    timing = loop.get("timing") or {}
    tip = st.get("tip_mm") or [None, None, None]
    meas = Table.grid(padding=(0, 2))
    meas.add_row("tip (mm)", " ".join(_fmt(v) for v in tip), "tip error (mm)", _fmt(tip_err))
    meas.add_row(
        "lateness (µs)",
        _fmt(last.get("lateness_us"), 1),
        "cycles",
        str(loop.get("cycles", "-")),
    )
    if timing:
        meas.add_row("timing", " ".join(f"{k} {_fmt(v, 1)}" for k, v in timing.items() if
                                        isinstance(v, int | float))[:90], "", "")  # fmt: skip
    trips = Table(title="trips", expand=False)
    for col in ("cause", "reaction", "detail"):
        trips.add_column(col)
    fault = st.get("fault")
    rows = list(st.get("trips") or [])[-5:]
    for t in rows:
        trips.add_row(str(t.get("cause")), str(t.get("reaction")), str(t.get("detail"))[:60])
    parts: list[Any] = [head, drives, meas]
    parts.append(Text(f"FAULT {fault.get('cause')}: {fault.get('detail')}", style="bold red")
                 if fault else Text("no fault latched", style="green"))  # fmt: skip
    if rows:
        parts.append(trips)
    parts.append(Text(f"polled {polled}  (Ctrl-C to quit)", style="dim"))
    return Group(*parts)


def _tip_model(config_path: str | None) -> TipModel | None:
    """The model tip of the rig config the daemon runs (None if it cannot be built here)."""
    if not config_path:
        return None
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.config.build_model import build_model

    try:
        return build_model(load_rig_config(config_path), source=config_path).tip
    except (RigError, OSError):
        return None


@click.command()
@click.option("--hz", type=click.FloatRange(0.5, 20), default=4.0, show_default=True)
@click.option("--count", type=click.IntRange(min=1), default=None, help="Stop after N pages.")
@click.pass_obj
def watch(obj: Ctx, hz: float, count: int | None) -> None:
    """Live status page: state, drives, trips, tip error, loop lateness (Ctrl-C quits)."""
    from rich.console import Console
    from rich.live import Live

    console = Console()
    period = 1.0 / hz
    n = 0
    tip_model: TipModel | None = None
    model_for: str | None = None
    with (
        ControlClient(obj.socket) as client,
        Live(console=console, auto_refresh=False, transient=False) as live,
    ):
        try:
            while count is None or n < count:
                t0 = time.monotonic()
                st = client.call("status")
                if st.get("config") != model_for:
                    model_for = st.get("config")
                    tip_model = _tip_model(model_for)
                page = status_page(st, tip_error_mm(st, tip_model), time.strftime("%H:%M:%S"))
                live.update(page, refresh=True)
                n += 1
                time.sleep(max(0.0, period - (time.monotonic() - t0)))
        except KeyboardInterrupt:
            pass
