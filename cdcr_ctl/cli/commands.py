"""The heavier ``cdcr-ctl`` commands: daemon, sim, trajectory, plot (``demo`` is
:mod:`cdcr_ctl.cli.demo`).

Imported by the command group (:mod:`cdcr_ctl.cli.main`) when one of them runs or ``--help``
lists them; each command imports what it needs when it runs, so listing them stays fast.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import math
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

import click

from cdcr_ctl.cli.app import Ctx, wait_for_run

#: How long ``trajectory`` waits for the run's log to be closed by its writer (s, wall clock).
LOG_CLOSE_TIMEOUT_S = 60.0


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )


@click.command()
@click.option("--verbose", "-v", is_flag=True)
@click.option(
    "--one-process",
    is_flag=True,
    help="Run the loop in this process, beside the control socket (for comparison: the socket "
    "threads then share the loop's interpreter lock). Default: the rig side in a process of "
    "its own.",
)
@click.pass_obj
def daemon(obj: Ctx, verbose: bool, one_process: bool) -> None:
    """Run the controller daemon in the foreground (systemd: Type=notify).

    The config is validated before anything is opened; drives stay disabled until `enable`.
    This process serves the control socket; the loop, its supervisor and the drive bus run in
    a child process of their own (cdcr_ctl.daemon.front).
    """
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.config.control import run_log_dir
    from cdcr_ctl.ownership import Ownership, bus_key

    _setup_logging(verbose)
    if not obj.config:
        raise click.UsageError("cdcr-ctl daemon needs -c/--config RIG.yaml")
    path = Path(obj.config)
    cfg = load_rig_config(path)  # a bad config stops here: nothing opened, nothing enabled
    if obj._socket:
        cfg = cfg.model_copy(
            update={"daemon": cfg.daemon.model_copy(update={"socket_path": obj._socket})}
        )
    # One daemon per bus and per control socket, before any frame is sent or socket replaced;
    # held until this process exits (the rig process it spawns runs under it).
    owner = Ownership().take_all(
        [
            bus_key(cfg.can.interface, cfg.can.channel),
            f"socket:{os.path.abspath(cfg.daemon.socket_path)}",
        ]
    )
    from cdcr_ctl.daemon.front import FrontDaemon
    from cdcr_ctl.runlog.writer.files import check_log_dir

    logs = check_log_dir(run_log_dir(cfg.logging))  # refuse now, not at the first run
    logging.getLogger(__name__).info("run logs in %s (locks %s)", logs, owner.paths())
    if one_process:
        reason = _one_process_daemon(cfg, path)
        click.echo(f"daemon stopped: {reason}", err=True)
        return
    front = FrontDaemon(cfg, path, socket_path=obj._socket, verbose=verbose)
    try:
        front.start()
    except BaseException:
        front.shutdown("start-up failed")
        raise
    reason, status = front.serve()
    click.echo(f"daemon stopped: {reason}", err=True)
    if status:
        raise SystemExit(status)


def _one_process_daemon(cfg: Any, path: Path) -> str:
    """The daemon with its loop in this process (``--one-process``)."""
    from cdcr_ctl.config.build_model import build_model
    from cdcr_ctl.control import trajectory
    from cdcr_ctl.control.io import open_rig_io
    from cdcr_ctl.control.timing import try_realtime
    from cdcr_ctl.daemon.service import Daemon
    from cdcr_ctl.runlog.writer.factory import RunLogFactory

    model = build_model(cfg, source=str(path))
    # The run log's /tip/model: a model instance of its own (the writer thread's, not the loop's).
    sinks = RunLogFactory.from_config(
        cfg, path, tip_from_psi=build_model(cfg, source=str(path)).tip
    )
    # Before any thread exists: every thread of the daemon inherits the policy.
    try_realtime(cfg.control.realtime_priority, cfg.control.lock_memory)
    io = open_rig_io(cfg, path, traffic_dir=sinks.base_dir)
    attach = getattr(model, "attach_attitude", None)  # models that close a loop on attitudes
    if attach is not None and io.attitude is not None:
        attach(io.attitude)
    d = Daemon(cfg, path, io, model, sinks, trajectory)
    try:
        d.start()
    except BaseException:
        d.shutdown("start-up failed")
        raise
    return d.serve()


@click.command()
@click.argument("sim_config", type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--duration-s",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="Stop after this long (default: run).",
)
@click.option(
    "--faults",
    "faults_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Serve the fault-injection channel (cdcr_ctl.sim.faults) on this Unix socket.",
)
@click.option(
    "--lockstep",
    is_flag=True,
    help="Lock-step: run the daemon (--config, default the simulator's rig) in this process on "
    "simulated time, as fast as the CPU allows (cdcr_ctl.sim.lockstep). Default: real time.",
)
@click.option(
    "--cpus",
    default="auto",
    show_default=True,
    help="With --lockstep: the CPUs of the loop thread and the truth worker: auto (the first "
    "two allowed), none, LOOP,WORKER, or job:I (the I-th pair, for sessions side by side).",
)
@click.option("--verbose", "-v", is_flag=True)
@click.pass_obj
def sim(
    obj: Ctx,
    sim_config: str,
    duration_s: float | None,
    faults_path: str | None,
    lockstep: bool,
    cpus: str,
    verbose: bool,
) -> None:
    """Run the simulated rig of SIM_CONFIG in this process until SIGTERM/SIGINT.

    Prints one JSON line with the connection points, then serves: EPOS nodes behind an slcan
    pseudo-terminal, load cells on a serial pseudo-terminal, tracker on 127.0.0.1, and with
    --faults a Unix socket that injects faults (drive EMCY, heartbeat loss, bus off, adapter
    unplugged, load-cell disconnect/garbage, tracker dropout, tension spike).

    With --lockstep the rig and the daemon run together on simulated time (one SYNC period per
    loop cycle, seeded noise: the same commands give the same logs byte for byte); the daemon's
    socket is that of --config (or --socket).
    """
    from cdcr_ctl.ownership import Ownership
    from cdcr_ctl.sim.simconfig import load_sim_config, sim_owned_keys

    _setup_logging(verbose)
    if lockstep:
        if faults_path or duration_s is not None:
            raise click.UsageError("--lockstep runs until shutdown; --faults is real time only")
        from cdcr_ctl.cli.lockstep import serve_lockstep
        from cdcr_ctl.sim.lockstep.placement import Placement

        placement = Placement.parse(cpus)
        ctl = obj.config or str(load_sim_config(sim_config).rig_path)
        reason = serve_lockstep(sim_config, ctl, obj._socket, placement)
        click.echo(f"lock-step daemon stopped: {reason}", err=True)
        return
    loaded = load_sim_config(sim_config)
    # A second simulator of the same rig refuses here, before it builds anything.
    owner = Ownership().take_all(sim_owned_keys(loaded.rig))
    from cdcr_ctl.sim.rig import SimRig

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    with (
        SimRig(loaded, truth_worker=True, owner=owner) as rig,
        contextlib.ExitStack() as extras,
    ):
        info = {"ready": True, **rig.connection_info()}
        if faults_path:
            from cdcr_ctl.sim.faults import FaultServer

            extras.enter_context(FaultServer(rig, faults_path))
            info["faults"] = str(faults_path)
        click.echo(json.dumps(info), nl=True)
        sys.stdout.flush()
        # Stand-in hardware should not pause: what start-up made (modules, dictionaries,
        # configs) leaves the collector's generations, so a full pass scans only what the run
        # makes (passes of 54-143 ms of wall time were seen under load without it).
        gc.freeze()
        stop.wait(duration_s)
        click.echo(json.dumps({"stopped": True, "counters": rig.counters.__dict__}), err=True)


@click.command("trajectory")
@click.argument("file", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--builtin",
    type=click.Choice(["planar_bend", "circle", "go_and_return"]),
    help="A built-in trajectory of Qi et al. 2023 section 5 instead of FILE.",
)
@click.option("--theta-deg", type=float, default=None, help="Bend of the circle / top of a bend.")
@click.option("--segments", type=int, default=1, show_default=True, help="Segments (built-ins).")
@click.option("--compensation", type=click.Choice(["off", "model", "measured"]), default=None)
@click.option("--name", default=None, help="Run name for the log (default: file or built-in).")
@click.option("--wait/--no-wait", default=True, show_default=True, help="Wait with a progress bar.")
@click.pass_obj
def trajectory_cmd(
    obj: Ctx,
    file: str | None,
    builtin: str | None,
    theta_deg: float | None,
    segments: int,
    compensation: str | None,
    name: str | None,
    wait: bool,
) -> None:
    """Run a trajectory FILE (CSV or YAML of timed setpoints) or a built-in one."""
    run_name = name or (Path(file).stem if file else str(builtin))
    if file is not None:
        # A file goes as its path: the daemon reads and validates it in its intake process
        # (no size limit of the request line applies).
        source: dict[str, Any] = {"file": str(Path(file).resolve())}
    else:
        source = {"samples": build_trajectory(file, builtin, theta_deg, segments).rows()}
    res = obj.call("trajectory", name=run_name, compensation=compensation, log=True, **source)
    if not wait:
        obj.emit(res)
        return
    st = wait_for_run(obj, res["run"], res["duration_s"])
    done = next((r for r in st.get("runs", []) if r["id"] == res["run"]), None)
    out = {**res, "state": done["state"] if done else "unknown"}
    if done:
        out["end_reason"] = done["end_reason"]
    if res.get("log_dir"):
        from cdcr_ctl.runlog.reader import wait_run_closed

        # The run has ended in the loop; the writer may still be behind (a loaded machine, a
        # lock-step rig's idle-priority writer): its log is read once the writer closed it.
        wait_run_closed(res["log_dir"], LOG_CLOSE_TIMEOUT_S)
        out["tip_error_mm"] = tip_error_summary(res["log_dir"])
    obj.emit(out)
    if done and done["state"] != "completed":
        raise SystemExit(1)


def build_trajectory(file: str | None, builtin: str | None, theta_deg: float | None, S: int):
    from cdcr_ctl.control import trajectory as tj

    if (file is None) == (builtin is None):
        raise click.UsageError("give a trajectory FILE or --builtin NAME (not both)")
    if file is not None:
        return tj.load_trajectory(file)
    if builtin == "planar_bend":
        return tj.planar_bend(n_segments=S, theta_max_rad=math.radians(theta_deg or 90.0))
    if builtin == "circle":
        return tj.spatial_circle(n_segments=S, theta_rad=math.radians(theta_deg or 45.0))
    return tj.go_and_return(n_segments=S, theta_max_rad=math.radians(theta_deg or 60.0))


def tip_error_summary(run_dir: str) -> dict[str, Any]:
    """Mean and max distance between the tracked tip and the commanded tip of a logged run (mm).

    The commanded tip is the forward kinematics of the commanded (theta, phi) with the rig's
    segment lengths from the run's config copy.
    """
    from cdcr_ctl.analysis import tip_errors

    return tip_errors(run_dir).summary()


@click.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--out", type=click.Path(file_okay=False), default=None, help="Default: RUN_DIR/plots"
)
@click.pass_obj
def plot(obj: Ctx, run_dir: str, out: str | None) -> None:
    """Plot a logged run: tip path vs command, tip error, cable displacements, tensions."""
    from cdcr_ctl.analysis import tip_from_psi_for_run
    from cdcr_ctl.runlog.plots import plot_run
    from cdcr_ctl.runlog.reader import load_run

    run = load_run(run_dir)
    where = Path(out or Path(run_dir) / "plots").resolve()
    files = plot_run(run, where, tip_from_psi=tip_from_psi_for_run(run))
    result = {"out_dir": str(where), "plots": {name: str(p) for name, p in files.items()}}
    lines = [f"{len(files)} plot(s) in {where}"]
    lines += [f"  {p}" for p in result["plots"].values()]
    obj.emit(result, "\n".join(lines))
