"""``cdcr-ctl demo``: the simulated rig, the daemon and a paper's experiments, end to end.

Three processes, as on a lab PC: ``cdcr-ctl sim`` (the simulated rig: EPOS nodes behind an slcan
pty, load cells / attitude sensors on ptys, tracker on 127.0.0.1), ``cdcr-ctl daemon`` (the
controller, with the simulator's rig config) and this process talking to the daemon through its
control socket like any CLI call. Each experiment runs without and with compensation; the tip
errors come from the logged runs. ``--design`` picks the rig:

- ``cc_disk``: Qi et al. 2023 section 5, planar bend and spatial circle;
- ``ujoint``: Yang et al. 2022 section 4.2, go-and-return 0 -> 6 deg -> 0 of every sub-joint
  (both segments, one plane), ideal geometric model (off) vs section 3's algorithm (model);
- ``vertebra``: the fuel-tank paper's joystick end-following session (Fig. 12), planned offline
  from a scripted stick (:func:`cdcr_ctl.model.vertebra.follow.plan_session`) and run as a timed
  trajectory, kinematic control (off) vs sag compensation (model).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import click
import yaml

from cdcr_ctl.cli.runwait import follow_run
from cdcr_ctl.daemon.client import ControlClient
from cdcr_ctl.errors import CommError, RigError

ROOT_CONFIG = Path(__file__).resolve().parents[2] / "config"
#: How long to wait for the simulator and the daemon to come up (s).
START_TIMEOUT_S = 60.0
#: Past START_TIMEOUT_S, a starting daemon whose processes used no CPU for this long is stuck (s).
START_STALL_S = 30.0


def free_port() -> int:
    """An unused TCP/UDP port number on 127.0.0.1 (asked of the kernel)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_session(
    sim_yaml: Path, work: Path, runs: Path, tcp_links: bool = False
) -> tuple[Path, Path]:
    """Write a rig config and a simulator config for one demo session in ``work``.

    The rig config extends the simulator config's rig and moves every connection point into
    ``work`` (pty links, control socket) and onto free loopback ports (tracker, a network
    joystick), so sessions never collide. ``tcp_links``: the simulated slcan adapter and load
    cells on free loopback TCP ports (``socket://127.0.0.1:PORT``) instead of ptys (their bytes
    then reach the daemon without the kernel's tty worker thread, which a loaded machine delays:
    :mod:`cdcr_ctl.sim.slcan_device`).
    Returns (rig config, simulator config).
    """
    sim_doc = yaml.safe_load(sim_yaml.read_text())
    base_rig = (sim_yaml.parent / sim_doc["rig"]).resolve()
    base = yaml.safe_load(base_rig.read_text())
    channel = f"socket://127.0.0.1:{free_port()}" if tcp_links else str(work / "can")
    rig_doc: dict[str, Any] = {
        "extends": str(base_rig),
        "can": {"channel": channel},
        "daemon": {"socket_path": str(work / "control.sock")},
        "logging": {"directory": str(runs)},
    }
    sensors = base.get("sensors") or {}
    if "load_cells" in sensors or "load_cells" in _parent_sensors(base_rig):
        port = f"socket://127.0.0.1:{free_port()}" if tcp_links else str(work / "loadcells")
        rig_doc.setdefault("sensors", {})["load_cells"] = {"serial": {"port": port}}
    rig_doc.setdefault("sensors", {})["tracker"] = {
        "host": "127.0.0.1",
        "port": free_port(),
        "command_port": free_port(),
    }
    attitude = sensors.get("attitude") or _parent_sensors(base_rig).get("attitude")
    if attitude:
        rig_doc["sensors"]["attitude"] = {
            "sensors": [
                {**port, "port": str(work / f"attitude{i + 1}")}
                for i, port in enumerate(attitude["sensors"])
            ]
        }
    joystick = sensors.get("joystick") or _parent_sensors(base_rig).get("joystick") or {}
    if str(joystick.get("device") or "").startswith("tcp://"):
        # The simulator's network joystick, on a free loopback port of its own.
        rig_doc["sensors"]["joystick"] = {"device": f"tcp://127.0.0.1:{free_port()}"}
    rig_path = work / "rig.yaml"
    rig_path.write_text(yaml.safe_dump(rig_doc, sort_keys=False))
    sim_doc["rig"] = str(rig_path)
    sim_path = work / "sim.yaml"
    sim_path.write_text(yaml.safe_dump(sim_doc, sort_keys=False))
    return rig_path, sim_path


def _parent_sensors(rig: Path) -> dict[str, Any]:
    doc = yaml.safe_load(rig.read_text()) or {}
    if "extends" in doc:
        parent = yaml.safe_load((rig.parent / doc["extends"]).read_text()) or {}
        return {**(parent.get("sensors") or {}), **(doc.get("sensors") or {})}
    return doc.get("sensors") or {}


#: Nice level of the simulated rig's process when it runs beside the daemon. The simulator stands
#: in for drives and sensors that have processors of their own: on a busy PC the daemon under test
#: may be delayed, the stand-in hardware should not be (at nice 0 under `stress-ng --cpu 2`, a
#: starved simulator missed its drives' 100 ms heartbeats). Needs root or CAP_SYS_NICE; without it
#: the simulator runs at nice 0.
SIM_NICE = -5


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "cdcr_ctl", *args]


def set_session_nice(pid: int, nice: int) -> None:
    """Give process ``pid``, the leader of a session of its own, the nice level ``nice`` (threads
    it starts later inherit it) and its session's autogroup the caller's autogroup level plus
    ``nice`` (a session of its own starts at 0 and would escape a caller running lower).

    With the kernel's autogroup on (``/proc/sys/kernel/sched_autogroup_enabled``, the default
    of desktop and many server kernels, and of this machine), the scheduler first shares the CPU
    between sessions, each with the weight of its autogroup's nice level, and a thread's own nice
    weighs only against threads of its session. A simulator at nice -5 in a session at autogroup
    nice 0 still got one session's share: beside two helpers' jobs (load average 3-5) its
    threads woke 50-150 ms late and a gen-0 garbage collection took 28 ms of wall time, the
    drives' TPDOs and heartbeats stopped for 0.25-0.33 s, and the daemon tripped ("heartbeat
    lost", "no TPDO from any drive"). Each step is skipped where not permitted (a nice level
    below 0 needs root or CAP_SYS_NICE) or not there (no autogroup)."""
    if nice:
        with contextlib.suppress(PermissionError, ProcessLookupError):
            os.setpriority(os.PRIO_PROCESS, pid, nice)
    group = autogroup_nice() + nice
    if group:
        with contextlib.suppress(OSError):
            Path(f"/proc/{pid}/autogroup").write_text(f"{group}\n")


def autogroup_nice(pid: int | str = "self") -> int:
    """The nice level of process ``pid``'s autogroup (0 where the kernel has none)."""
    try:
        return int(Path(f"/proc/{pid}/autogroup").read_text().split()[-1])
    except (OSError, ValueError, IndexError):
        return 0


@contextlib.contextmanager
def running(
    cmd: Sequence[str], log_path: Path, ready: str | None = None, nice: int = 0
) -> Iterator[subprocess.Popen]:
    """Start ``cmd`` with output to ``log_path``; on exit SIGTERM it (then SIGKILL after 10 s).

    With ``ready``, wait until a line containing it appears on stdout (the sim's JSON line).
    ``nice``: the process's nice level, and its session's relative to this one's
    (:func:`set_session_nice`), set before it is waited for (ignored where not permitted).
    """
    log = log_path.open("w")
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE if ready else log,
        stderr=log,
        text=True,
        start_new_session=True,
    )
    set_session_nice(proc.pid, nice)
    try:
        if ready:
            assert proc.stdout is not None
            deadline = time.monotonic() + START_TIMEOUT_S
            while True:
                line = proc.stdout.readline()
                if line:
                    log.write(line)
                    log.flush()
                    if ready in line:
                        break
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RigError(f"{cmd[3]} did not start; see {log_path}")
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()


@contextlib.contextmanager
def rig_running(
    sim_path: Path, rig_path: Path, sock: Path, logs: Path, lockstep: bool = False
) -> Iterator[None]:
    """``cdcr-ctl sim`` and ``cdcr-ctl daemon`` as processes (logs ``sim.log``, ``daemon.log`` in
    ``logs``), the drives enabled and homed; both stopped on exit. ``lockstep``: one process,
    ``cdcr-ctl sim --lockstep`` (log ``lockstep.log``), the daemon on simulated time."""
    with contextlib.ExitStack() as procs:
        if lockstep:
            log = logs / "lockstep.log"
            cmd = _cli("--config", str(rig_path), "sim", str(sim_path), "--lockstep")
            d = procs.enter_context(running(cmd, log, ready='"ready"'))
        else:
            log = logs / "daemon.log"
            procs.enter_context(
                running(
                    _cli("sim", str(sim_path)), logs / "sim.log", ready='"ready"', nice=SIM_NICE
                )
            )
            d = procs.enter_context(running(_cli("--config", str(rig_path), "daemon"), log))
        wait_for_socket(sock, d, log)
        with ControlClient(sock) as c:
            c.call("enable")
            c.call("home")
        yield


def wait_for_socket(path: Path, proc: subprocess.Popen, log_path: Path) -> None:
    """Until the daemon ``proc`` answers ``status`` on ``path``: :data:`START_TIMEOUT_S`, and
    past it as long as the daemon's processes keep using CPU (a loaded machine slows a start,
    it does not stop it; on a 2-core VM at load average 26 one took over 60 s), until they have
    used none for :data:`START_STALL_S` (stuck, not slow). RigError naming ``log_path``."""
    t0 = last_progress = time.monotonic()
    cpu = -1.0
    while True:
        if proc.poll() is not None:
            raise RigError(f"daemon exited with {proc.returncode}; see {log_path}")
        with contextlib.suppress(CommError), ControlClient(path, timeout_s=5) as c:
            c.call("status")
            return
        now = time.monotonic()
        if now - t0 > START_TIMEOUT_S:
            used = tree_cpu_s(proc.pid)
            if used > cpu:
                cpu, last_progress = used, now
            elif now - last_progress > START_STALL_S:
                raise RigError(f"daemon did not open {path}; see {log_path}")
        time.sleep(0.2)


def tree_cpu_s(pid: int) -> float:
    """CPU time (user + system, s) used so far by process ``pid`` and its descendants, from
    ``/proc`` (Linux; 0 elsewhere or once gone)."""
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = Path(f"/proc/{p}/stat").read_bytes().rsplit(b")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])  # utime, stime (proc(5) 14, 15)
            for task in Path(f"/proc/{p}/task").iterdir():
                with contextlib.suppress(OSError, ValueError):
                    todo.extend(int(c) for c in (task / "children").read_text().split())
    return total / tick


def recover(sock: Path, attempts: int = 3) -> None:
    """After a trip: acknowledge it, re-enable, and check the drives stay enabled for a moment."""
    st: dict[str, Any] = {}
    for _ in range(attempts):
        with ControlClient(sock) as c:
            c.call("reset_fault", confirm=True)
            c.call("enable")
            time.sleep(0.5)
            st = c.call("status")
            if st["enabled"] and st["fault"] is None:
                return
    raise RigError(f"could not recover from {st.get('fault')}")


def sim_config_of(design: str) -> Path:
    """The simulator config a design's demo runs on by default (the design registry's
    ``sim_config``, in the checkout's ``config/``)."""
    from cdcr_ctl.config.registry import design_of

    return ROOT_CONFIG / design_of(design).sim_config


def experiments_for(design: str, rig_cfg: Any, quick: bool) -> dict[str, Any]:
    """The timed trajectories of a design's demo (name -> Trajectory): its registered ``demo``."""
    from cdcr_ctl.config.registry import design_of, resolve

    return resolve(design_of(design).demo)(rig_cfg, quick)


@click.command("demo")
@click.option(
    "--design",
    default="cc_disk",
    show_default=True,
    help="Which rig to simulate: a registered design (cc_disk, ujoint, vertebra); its "
    "simulator config unless --sim-config is given.",
)
@click.option(
    "--sim-config",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="Simulator config [default: config/sim/<the design's>-truth.yaml].",
)
@click.option(
    "--out", type=click.Path(file_okay=False, path_type=Path), default=Path("demo-output")
)
@click.option("--quick", is_flag=True, help="Shorter experiments (for tests).")
@click.option(
    "--plots/--no-plots",
    default=True,
    show_default=True,
    help="Draw each run's PNG plots into its run directory (about 2 s of CPU per run).",
)
@click.option(
    "--lockstep",
    is_flag=True,
    help="Run the simulated rig and the daemon in one process on simulated time, as fast as "
    "the CPU allows (default: real time, the rig at its real pace).",
)
@click.pass_obj
def demo(
    obj: Any,
    design: str,
    sim_config: Path | None,
    out: Path,
    quick: bool,
    plots: bool,
    lockstep: bool,
) -> None:
    """Simulated rig + daemon: a paper's experiments, without and with compensation."""
    from cdcr_ctl.analysis import tip_errors
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.config.registry import DESIGNS

    if design not in DESIGNS:
        raise click.BadParameter(
            f"{design!r} is not a registered design ({', '.join(sorted(DESIGNS))})",
            param_hint="--design",
        )
    sim_config = sim_config or sim_config_of(design)
    if not sim_config.is_file():
        # The shipped configs are the checkout's config/, not part of an installed package.
        raise click.UsageError(
            f"{sim_config}: no such simulator config; the shipped ones are in a checkout's "
            "config/sim/ (run cdcr-ctl from the checkout's .venv, or give --sim-config)"
        )
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    session = (out / stamp).resolve()
    work = Path(f"/tmp/cdcr-demo-{os.getpid()}")
    runs = session / "runs"
    for d in (session, work, runs):
        d.mkdir(parents=True, exist_ok=True)
    rig_path, sim_path = make_session(sim_config.resolve(), work, runs)
    sock = work / "control.sock"
    rig_cfg = load_rig_config(rig_path)
    if rig_cfg.design != design:
        raise click.UsageError(f"{sim_config} is a {rig_cfg.design} rig, not {design}")
    experiments = experiments_for(design, rig_cfg, quick)
    rows: list[dict[str, Any]] = []
    click.echo(f"demo session: {session}", err=True)
    with rig_running(sim_path, rig_path, sock, session, lockstep):
        for exp, traj in experiments.items():
            for comp in ("off", "model"):
                for _attempt in range(2):
                    res = follow_run(sock, f"{exp}-{comp}", traj.rows(), comp)
                    if res["state"] != "completed":
                        # Keep the log of the tripped run, clear the trip, go on.
                        click.echo(f"  {exp}-{comp}: {res['end_reason']}", err=True)
                        recover(sock)
                    if res["state"] == "completed":
                        break
                summ = tip_errors(res["log_dir"], settle_s=0.0).summary()
                rows.append({"experiment": exp, **summ, "state": res["state"]})
                click.echo(
                    f"  {exp:12s} compensation={comp:6s} mean {summ['mean_mm']:.3f} mm"
                    f"  max {summ['max_mm']:.3f} mm  ({res['state']})",
                    err=True,
                )
        with ControlClient(sock) as c:
            c.call("disable")
    table = format_table(rows)
    (session / "results.md").write_text(table)
    (session / "results.json").write_text(json.dumps(rows, indent=2))
    if plots:
        _plots(runs)
    shutil.rmtree(work, ignore_errors=True)
    click.echo(table)
    click.echo(f"logs, plots and results in {session}")


def format_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table: mean/max tip error per experiment and mode, reduction against 'off'."""
    lines = [
        "| experiment | compensation | mean tip error (mm) | max (mm) | mean reduction vs off |",
        "| --- | --- | --- | --- | --- |",
    ]
    base = {r["experiment"]: r["mean_mm"] for r in rows if r["compensation"] == "off"}
    for r in rows:
        red = ""
        if r["compensation"] != "off" and base.get(r["experiment"]):
            red = f"{100.0 * (1.0 - r['mean_mm'] / base[r['experiment']]):.1f} %"
        lines.append(
            f"| {r['experiment']} | {r['compensation']} | {r['mean_mm']:.3f}"
            f" | {r['max_mm']:.3f} | {red} |"
        )
    return "\n".join(lines) + "\n"


def _plots(runs: Path) -> None:
    from cdcr_ctl.analysis import tip_from_psi_for_run
    from cdcr_ctl.runlog.plots import plot_run
    from cdcr_ctl.runlog.reader import load_run

    for run_dir in sorted(p for p in runs.iterdir() if p.is_dir()):
        run = load_run(run_dir)
        plot_run(run, run_dir / "plots", tip_from_psi=tip_from_psi_for_run(run))
