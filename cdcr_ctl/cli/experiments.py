"""``cdcr-ctl experiments``: the whole story on the simulated rig in one command.

Starts ``cdcr-ctl sim`` and ``cdcr-ctl daemon`` with the controller's nominal config, identifies,
restarts both with the identified overlay, runs the planar bend (Qi et al. 2023 section 5.1) and
the spatial circle (section 5.2) with every compensation mode, and prints the table of mean/max
tip error and reduction. Importing this module registers the command on
:data:`cdcr_ctl.cli.app.cli`.
"""

from __future__ import annotations

import json
import math
import os
import queue
import shutil
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import click
import yaml

from cdcr_ctl.cli.app import Ctx
from cdcr_ctl.cli.identify_runs import (
    ATTEMPTS,
    MODES,
    REVERSAL_BAND_MM,
    ROOT_CONFIG,
    _run_recovering,
    fit_and_write,
    run_sweep,
)
from cdcr_ctl.daemon.client import ControlClient


def _experiments(quick: bool) -> dict[str, Any]:
    from cdcr_ctl.control import trajectory as tj

    return {
        "planar_bend": tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10),
        "circle": tj.spatial_circle(
            theta_rad=math.pi / 4, phi_rate_rad_s=0.6 if quick else math.pi / 10
        ),
    }


def _session(
    sim_path: Path,
    rig_path: Path,
    log_dir: Path,
    tag: str,
    lockstep: bool = False,
    cpus: str = "auto",
):
    """Context manager: simulator + daemon subprocesses for one config, enabled and homed
    (``lockstep``: one process, the daemon on the simulator's simulated clock, its loop thread
    and truth worker placed by ``cpus``: ``sim --cpus``)."""
    import contextlib

    from cdcr_ctl.cli.demo import _cli, running, wait_for_socket

    @contextlib.contextmanager
    def cm():
        from cdcr_ctl.config import load_rig_config

        sock = Path(load_rig_config(rig_path).daemon.socket_path)
        with contextlib.ExitStack() as procs:
            if lockstep:
                log = log_dir / f"lockstep-{tag}.log"
                cmd = _cli(
                    "--config", str(rig_path), "sim", str(sim_path), "--lockstep", "--cpus", cpus
                )
                d = procs.enter_context(running(cmd, log, ready='"ready"'))
            else:
                log = log_dir / f"daemon-{tag}.log"
                procs.enter_context(
                    running(_cli("sim", str(sim_path)), log_dir / f"sim-{tag}.log", ready='"ready"')
                )
                d = procs.enter_context(running(_cli("--config", str(rig_path), "daemon"), log))
            wait_for_socket(sock, d, log)
            with ControlClient(sock) as c:
                c.call("enable")
                c.call("home")
            yield sock
            with ControlClient(sock) as c:
                c.call("disable")

    return cm()


def _run_modes(
    sock: Path,
    n_segments: int,
    tag: str,
    modes: tuple[str, ...],
    quick: bool,
    rows: list[dict[str, Any]],
    only: tuple[str, ...] | None = None,
) -> None:
    """Run every experiment (of ``only``, default all) in every mode of ``modes``; append one
    result row per run."""
    from cdcr_ctl.analysis import tip_errors
    from cdcr_ctl.cli.demo import recover

    straight = [[t] + [0.0] * (2 * n_segments) for t in (0.0, 0.5)]
    for exp, traj in _experiments(quick).items():
        if only is not None and exp not in only:
            continue
        for comp in modes:
            label = comp if tag == "identified" else f"{comp} ({tag})"
            res: dict[str, Any] = {}
            for _attempt in range(ATTEMPTS):
                res = _run_recovering(sock, f"{exp}-{comp}-{tag}", traj.rows(), comp)
                if res["state"] == "completed":
                    break
                # A trip (e.g. a stale sensor on a loaded machine): keep its log, recover,
                # return to straight and run again.
                click.echo(f"  {exp} {label}: {res['end_reason']}", err=True)
                recover(sock)
                _run_recovering(sock, "return", straight, comp, log=False)
            # Back to straight in the same mode (not logged), so that every run starts there and
            # switching modes between runs steps nothing (delta = 0 at the straight pose).
            _run_recovering(sock, "return", straight, comp, log=False)
            summ = tip_errors(res["log_dir"], settle_s=0.0).summary()
            rows.append(
                {
                    "experiment": exp,
                    "compensation": label,
                    "mode": comp,
                    "params": tag,
                    "mean_mm": summ["mean_mm"],
                    "max_mm": summ["max_mm"],
                    "rms_mm": summ["rms_mm"],
                    "samples": summ["samples"],
                    "state": res["state"],
                    "log_dir": res["log_dir"],
                }
            )
            click.echo(
                f"  {exp:12s} {label:18s} mean {summ['mean_mm']:.3f} mm"
                f"  max {summ['max_mm']:.3f} mm  ({res['state']})",
                err=True,
            )


def _parallel(jobs: int, in_session: Any, tasks: list[tuple[str, Any, Any]]) -> list[Any]:
    """Run ``in_session(tag, overlay, body)`` for every task, ``jobs`` at a time (a thread per
    task, each driving its own simulator process); results in task order, first error raised."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(in_session, tag, ovl, body) for tag, ovl, body in tasks]
        return [f.result() for f in futures]


def _controller_config(work: Path, name: str, rig: Path, band_mm: float, overlay: Path | None):
    """A controller config over the session rig: the reversal band, and the fitted overlay."""
    doc: dict[str, Any] = {"extends": str(rig)}
    if overlay is not None:
        doc["overlays"] = [str(overlay.resolve())]
    doc["control"] = {"reversal_band_mm": band_mm}
    path = work / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@click.command("experiments")
@click.option(
    "--sim-config",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=ROOT_CONFIG / "sim" / "qi2023-truth.yaml",
    show_default=True,
    help="Simulator YAML (the truth); the controller only sees the rig config it names.",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("experiments-output"),
    show_default=True,
)
@click.option(
    "--nominal/--no-nominal",
    default=True,
    show_default=True,
    help="Also run the model mode with the nominal (unidentified) parameters.",
)
@click.option(
    "--overlay",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Use this identified overlay instead of running the calibration sweep.",
)
@click.option(
    "--reversal-band-mm",
    type=float,
    default=REVERSAL_BAND_MM,
    show_default=True,
    help="control.reversal_band_mm of the controller in these experiments.",
)
@click.option("--quick", is_flag=True, help="Coarser sweep and a faster circle (for tests).")
@click.option(
    "--realtime",
    is_flag=True,
    help="Run the simulated rig in real time (separate simulator and daemon processes) instead "
    "of lock-step (one process on simulated time, as fast as the CPU allows; the default).",
)
@click.option(
    "--jobs",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Independent sessions side by side: each sweep plane and each (experiment, mode) on "
    "its own simulated rig, N at a time (each starts straight instead of after the previous).",
)
@click.pass_obj
def experiments_cmd(
    obj: Ctx,
    sim_config: Path,
    out: Path,
    nominal: bool,
    overlay: Path | None,
    reversal_band_mm: float,
    quick: bool,
    realtime: bool,
    jobs: int,
) -> None:
    """Simulated rig: identify, then planar bend and circle with every compensation mode."""
    from cdcr_ctl.cli.demo import make_session
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.identify.figures import format_table, plot_experiments

    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    session = (out / stamp).resolve()
    work = Path(f"/tmp/cdcr-exp-{os.getpid()}")
    runs = session / "runs"
    for d in (session, work, runs):
        d.mkdir(parents=True, exist_ok=True)
    rig_path, sim_path = make_session(sim_config.resolve(), work, runs)
    ctl_nominal = _controller_config(work, "ctl-nominal.yaml", rig_path, reversal_band_mm, None)
    S = len(load_rig_config(ctl_nominal).robot.segments)
    click.echo(f"experiments session: {session}", err=True)
    click.echo(
        f"clock: {'real time' if realtime else 'lock-step (simulated time)'}, jobs {jobs}", err=True
    )
    lockstep = not realtime
    rows: list[dict[str, Any]] = []
    t_start = time.monotonic()

    # Each of the ``jobs`` sessions running at once holds a slot: its lock-step loop and truth
    # worker go on the slot's pair of CPUs (sim --cpus job:SLOT), so the loops spread out.
    slots: queue.SimpleQueue[int] = queue.SimpleQueue()
    for slot in range(jobs):
        slots.put(slot)

    def in_session(tag: str, ovl: Path | None, body):
        """``body(sock)`` on a fresh simulated rig of its own (work dir, ports, socket)."""
        w = work / tag
        w.mkdir(parents=True, exist_ok=True)
        rig_i, sim_i = make_session(sim_config.resolve(), w, runs)
        ctl_i = _controller_config(w, "ctl.yaml", rig_i, reversal_band_mm, ovl)
        slot = slots.get()
        try:
            with _session(sim_i, ctl_i, session, tag, lockstep, f"job:{slot}") as sock:
                return body(sock)
        finally:
            slots.put(slot)

    try:
        # 1. nominal controller: calibration sweep (and, optionally, nominal compensation)
        if overlay is None or nominal:
            limit = load_rig_config(ctl_nominal).limits.bend_rad
            if jobs == 1:
                with _session(sim_path, ctl_nominal, session, "nominal", lockstep) as sock:
                    if overlay is None:
                        sweep_dirs = run_sweep(sock, S, limit, quick)
                    if nominal:
                        _run_modes(sock, S, "nominal", ("model",), quick, rows)
            else:
                from cdcr_ctl.identify.sweep import SweepSpec

                tasks = []
                if overlay is None:
                    for beta in SweepSpec().betas_deg:
                        tasks.append(
                            (
                                f"sweep-beta{beta:g}",
                                None,
                                lambda sock, b=beta: run_sweep(sock, S, limit, quick, (b,)),
                            )
                        )
                if nominal:
                    for exp in _experiments(quick):
                        tasks.append(
                            (
                                f"nominal-{exp}",
                                None,
                                lambda sock, e=exp: _run_modes(
                                    sock, S, "nominal", ("model",), quick, rows, (e,)
                                ),
                            )
                        )
                results = _parallel(jobs, in_session, tasks)
                sweep_dirs = [d for r in results if isinstance(r, list) for d in r]
        # 2. fit offline (nothing else running)
        t_first = time.monotonic() - t_start
        t_fit = time.monotonic()
        if overlay is None:
            overlay = fit_and_write(ctl_nominal, sweep_dirs, session / "identification")
        t_fit = time.monotonic() - t_fit
        t_third = time.monotonic()
        ctl_ident = _controller_config(
            work, "ctl-identified.yaml", rig_path, reversal_band_mm, overlay
        )
        shutil.copy(ctl_ident, session / "ctl-identified.yaml")
        # 3. identified controller: every mode
        if jobs == 1:
            with _session(sim_path, ctl_ident, session, "identified", lockstep) as sock:
                _run_modes(sock, S, "identified", MODES, quick, rows)
        else:
            tasks = [
                (
                    f"identified-{exp}-{comp}",
                    overlay,
                    lambda sock, e=exp, m=comp: _run_modes(
                        sock, S, "identified", (m,), quick, rows, (e,)
                    ),
                )
                for exp in _experiments(quick)
                for comp in MODES
            ]
            _parallel(jobs, in_session, tasks)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    order = {
        (e, m): i for i, (e, m) in enumerate((e, m) for e in _experiments(quick) for m in MODES)
    }
    rows.sort(key=lambda r: (r["params"] != "nominal", order.get((r["experiment"], r["mode"]), 0)))
    wall = time.monotonic() - t_start
    t_third = time.monotonic() - t_third
    click.echo(
        f"experiments: {wall:.0f} s wall ({'real time' if realtime else 'lock-step'}, "
        f"jobs {jobs}; sweep and nominal sessions {t_first:.0f} s, fit {t_fit:.0f} s, "
        f"identified sessions {t_third:.0f} s)",
        err=True,
    )
    table = format_table(rows)
    (session / "results.md").write_text(table)
    (session / "results.json").write_text(json.dumps(rows, indent=2, default=str))
    plot_experiments(rows, session / "figures")
    click.echo(table)
    click.echo(f"logs, figures and results in {session}")
