"""``cdcr-ctl identify`` and ``cdcr-ctl experiments``: calibration and the paper's experiments.

``identify`` runs the calibration sweep of Qi et al. 2023 section 5 (eq. 38: beta = 0, 120,
240 deg; theta = 40-90 deg in 5 deg steps, up and down) on the rig through the running daemon,
then fits the model parameters offline from the logged run (:mod:`cdcr_ctl.identify`) and writes
``identified.yaml`` (an overlay for the rig config's ``overlays:``), ``identification.json`` and
residual plots. ``--from-run`` fits logged runs without moving anything.

``experiments`` is the whole story on the simulated rig in one command: start ``cdcr-ctl sim``
and ``cdcr-ctl daemon`` with the controller's nominal config, identify, restart both with the
identified overlay, run the planar bend (section 5.1) and the spatial circle (section 5.2) with
every compensation mode, and print the table of mean/max tip error and reduction.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import click
import yaml

from cdcr_ctl.cli.app import Ctx, cli
from cdcr_ctl.daemon.client import ControlClient
from cdcr_ctl.errors import RigError
from cdcr_ctl.identify.estimator import FitOptions

ROOT_CONFIG = Path(__file__).resolve().parents[2] / "config"
#: Extra time allowed beyond a run's duration before giving up on it (s).
RUN_SLACK_S = 60.0
#: Compensation modes of the experiments, in table order.
MODES = ("off", "model", "measured")
#: Default controller setting for the experiments: cable-material travel over which friction
#: reverses in the compensation (control.reversal_band_mm; see cdcr_ctl.model.compensation).
REVERSAL_BAND_MM = 0.01
#: Tries per experiment run (a trip on a loaded machine is retried after recovery).
ATTEMPTS = 5


def run_trajectory(
    sock: str | Path, name: str, rows: list[list[float]], comp: str, log: bool = True
) -> dict[str, Any]:
    """Run one trajectory through the daemon, wait for its end; the run's record + log dir."""
    with ControlClient(sock) as c:
        res = c.call("trajectory", name=name, samples=rows, compensation=comp, log=log)
        end = time.monotonic() + res["duration_s"] + RUN_SLACK_S
        while time.monotonic() < end:
            st = c.call("status")
            done = next((r for r in st["runs"] if r["id"] == res["run"]), None)
            if done is not None:
                return {**res, "state": done["state"], "end_reason": done["end_reason"]}
            time.sleep(0.25)
    raise RigError(f"run {name} did not finish within {res['duration_s'] + RUN_SLACK_S:.0f} s")


def run_sweep(
    sock: str | Path,
    n_segments: int,
    bend_limit_rad: float,
    quick: bool,
    betas_deg: tuple[float, ...] | None = None,
) -> list[Path]:
    """Run the calibration sweep (compensation off), one run per bending plane beta; return
    the log directories.

    Each plane starts and ends straight, so its run stands alone: a trip (e.g. a stale sensor
    on a loaded machine) repeats only that plane, and the fit takes the runs together.
    """
    from dataclasses import replace

    from cdcr_ctl.cli.demo import recover
    from cdcr_ctl.identify.sweep import SweepSpec, calibration_sweep

    spec = SweepSpec(dwell_s=0.8, theta_step_deg=10.0) if quick else SweepSpec()
    whole = calibration_sweep(n_segments, spec, bend_limit_rad)
    click.echo(
        f"calibration sweep: {len(whole.dwells)} dwells, {whole.duration_s:.0f} s "
        f"in {len(spec.betas_deg)} runs",
        err=True,
    )
    with ControlClient(sock) as c:
        if not c.call("status").get("enabled"):
            c.call("enable")
    out: list[Path] = []
    for beta in spec.betas_deg if betas_deg is None else betas_deg:
        part = calibration_sweep(n_segments, replace(spec, betas_deg=(beta,)), bend_limit_rad)
        res: dict[str, Any] = {}
        for _attempt in range(ATTEMPTS):
            res = _run_recovering(sock, f"calibration_sweep_beta{beta:g}", part.rows(), "off")
            if res["state"] == "completed":
                out.append(Path(res["log_dir"]))
                break
            click.echo(f"sweep beta={beta:g}: {res['end_reason']}; again", err=True)
            recover(sock)
            straight = [[t] + [0.0] * (2 * n_segments) for t in (0.0, 0.5)]
            _run_recovering(sock, "return", straight, "off", log=False)
        else:
            raise RigError(
                f"calibration sweep beta={beta:g} ended {res['state']}: {res['end_reason']}"
            )
    return out


def fit_and_write(
    cfg_path: Path,
    run_dirs: list[Path],
    out: Path,
    options: FitOptions | None = None,
    fit_pulleys: str = "auto",
    accept_misfit: bool = False,
) -> Path:
    """Fit ``run_dirs`` with the nominal config ``cfg_path``; write overlay, report, plots.

    A fit the misfit gate refuses (:mod:`cdcr_ctl.identify.gate`) writes the report and plots
    but no overlay, and raises :class:`~cdcr_ctl.identify.gate.MisfitError` (exit status 1)
    naming ``cdcr-ctl discrepancy`` as the next step. ``options``/``fit_pulleys``: as
    :func:`~cdcr_ctl.identify.pipeline.identify_runs`. ``accept_misfit``: the operator's
    explicit override: the overlay is written all the same, its first line says it is a misfit.
    """
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.identify.gate import MisfitError, judge_identification
    from cdcr_ctl.identify.pipeline import (
        identify_runs,
        overlay_text,
        report_dict,
        summary_table,
    )
    from cdcr_ctl.identify.plots import plot_identification

    cfg = load_rig_config(cfg_path)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    ident = identify_runs(cfg, run_dirs, options, fit_pulleys)
    dt = time.monotonic() - t0
    verdict = judge_identification(ident, options)
    overlay = out / "identified.yaml"
    rep = report_dict(ident)
    rep["fit_time_s"] = dt
    rep["runs"] = [str(r) for r in run_dirs]
    rep["verdict"] = {"ok": verdict.ok, "misfit_ratio": verdict.misfit_ratio}
    rep["verdict"]["reasons"] = verdict.reasons
    (out / "identification.json").write_text(json.dumps(rep, indent=2, default=float))
    plot_identification(ident, out / "plots")
    click.echo(summary_table(ident), err=True)
    for w in ident.warnings:
        click.echo(f"warning: {w}", err=True)
    text = overlay_text(cfg, ident, [str(r) for r in run_dirs])
    if not verdict.ok and not accept_misfit:
        # The misfit gate (cdcr_ctl.identify.gate): no overlay, not even a stale one.
        overlay.unlink(missing_ok=True)
        raise MisfitError(
            verdict.message(str(run_dirs[0]), str(cfg_path))
            + f" (report: {out / 'identification.json'})"
        )
    if not verdict.ok:
        why = "; ".join(verdict.reasons)
        click.echo(f"warning: MISFIT ACCEPTED (--accept-misfit), overlay written: {why}", err=True)
        text = (
            f"# MISFIT ACCEPTED BY THE OPERATOR (--accept-misfit): {'; '.join(verdict.reasons)}\n"
        )
        text += overlay_text(cfg, ident, [str(r) for r in run_dirs])
    else:
        click.echo(verdict.message(), err=True)
    overlay.write_text(text)
    click.echo(f"fit took {dt:.1f} s; overlay {overlay}", err=True)
    return overlay


@cli.command("identify")
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("identification"),
    show_default=True,
    help="Directory for identified.yaml, identification.json and plots.",
)
@click.option(
    "--from-run",
    "from_runs",
    multiple=True,
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    help="Fit these logged runs instead of running the sweep (repeatable).",
)
@click.option("--quick", is_flag=True, help="Coarser, shorter sweep (10 deg steps).")
@click.option(
    "--accept-misfit",
    is_flag=True,
    help="Write the overlay even when the fit does not explain the data (marked as a misfit).",
)
@click.option(
    "--log-kind",
    type=click.Choice(["auto", "loadcell", "tip", "keypoint", "pulls"]),
    default="auto",
    show_default=True,
    help="Kind of the --from-run logs (auto: from the columns and the row timing).",
)
@click.option(
    "--tip-noise-mm",
    type=float,
    default=0.05,
    show_default=True,
    help="Tracker noise per axis of one keypoint row (weights the tip residuals).",
)
@click.option(
    "--holdout",
    type=float,
    default=0.3,
    show_default=True,
    help="Fraction of each keypoint run (its end, by time) held out of the fit.",
)
@click.option(
    "--max-points",
    type=click.IntRange(10, 100_000),
    default=60,
    show_default=True,
    help="Most keypoint rows fitted (evenly spread over the fitted part).",
)
@click.option(
    "--max-nfev",
    type=click.IntRange(1, 1000),
    default=20,
    show_default=True,
    help="Least-squares evaluations of the keypoint fit.",
)
@click.pass_obj
def identify_cmd(
    obj: Ctx,
    out: Path,
    from_runs: tuple[Path, ...],
    quick: bool,
    log_kind: str,
    tip_noise_mm: float,
    holdout: float,
    max_points: int,
    max_nfev: int,
    accept_misfit: bool,
) -> None:
    """Run the calibration sweep of Qi et al. 2023 and fit mu, EA, EI, pretension, pulleys.

    Needs --config (the controller's rig config: nominal values, geometry, load-cell places).
    Writes OUT/identified.yaml: add it to the rig config's `overlays:` list. A fit that does
    not explain its data (cdcr_ctl.identify.gate) writes no overlay and exits 1, unless
    --accept-misfit.
    """
    if not obj.config:
        raise click.UsageError("identify needs --config RIG (the controller's rig config)")
    from cdcr_ctl.config import load_rig_config

    cfg_path = Path(obj.config)
    cfg = load_rig_config(cfg_path)
    runs = list(from_runs)
    if runs:
        from cdcr_ctl.identify.keypoints import KeypointOptions
        from cdcr_ctl.identify.lablogs import fit_lab_logs, run_kinds

        kinds = run_kinds(runs, log_kind)
        if any(k != "loadcell" for k in kinds):
            if "loadcell" in kinds:
                raise click.UsageError(
                    "mixed log kinds: "
                    + ", ".join(f"{r}: {k}" for r, k in zip(runs, kinds, strict=True))
                )
            opt = KeypointOptions(
                holdout=holdout, tip_noise_mm=tip_noise_mm, max_points=max_points, max_nfev=max_nfev
            )
            ov, lines = fit_lab_logs(cfg, runs, out, kinds, opt, [str(r) for r in runs])
            click.echo("\n".join(lines), err=True)
            obj.emit(
                {"overlay": None if ov is None else str(ov), "runs": [str(r) for r in runs]},
                text=str(ov) if ov else "no overlay written (see the report)",
            )
            return
    else:
        runs = run_sweep(obj.socket, len(cfg.robot.segments), cfg.limits.bend_rad, quick)
    overlay = fit_and_write(cfg_path, runs, out, accept_misfit=accept_misfit)
    obj.emit({"overlay": str(overlay), "runs": [str(r) for r in runs]}, text=str(overlay))


# --------------------------------------------------------------------------- experiments
def _experiments(quick: bool) -> dict[str, Any]:
    from cdcr_ctl.control import trajectory as tj

    return {
        "planar_bend": tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10),
        "circle": tj.spatial_circle(
            theta_rad=math.pi / 4, phi_rate_rad_s=0.6 if quick else math.pi / 10
        ),
    }


def _session(sim_path: Path, rig_path: Path, log_dir: Path, tag: str, lockstep: bool = False):
    """Context manager: simulator + daemon subprocesses for one config, enabled and homed
    (``lockstep``: one process, the daemon on the simulator's simulated clock)."""
    import contextlib

    from cdcr_ctl.cli.demo import _cli, running, wait_for_socket

    @contextlib.contextmanager
    def cm():
        from cdcr_ctl.config import load_rig_config

        sock = Path(load_rig_config(rig_path).daemon.socket_path)
        with contextlib.ExitStack() as procs:
            if lockstep:
                log = log_dir / f"lockstep-{tag}.log"
                cmd = _cli("--config", str(rig_path), "sim", str(sim_path), "--lockstep")
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


def _run_recovering(
    sock: Path, name: str, rows: list[list[float]], comp: str, log: bool = True
) -> dict[str, Any]:
    """:func:`run_trajectory`; if the daemon refuses it because of a latched trip (one that
    happened between runs), recover first and try again."""
    from cdcr_ctl.cli.demo import recover
    from cdcr_ctl.daemon.client import DaemonError

    for attempt in range(ATTEMPTS):
        try:
            return run_trajectory(sock, name, rows, comp, log)
        except DaemonError as exc:
            if attempt == ATTEMPTS - 1 or not any(w in str(exc) for w in ("tripped", "disabled")):
                raise
            click.echo(f"  {name}: {exc}; recovering", err=True)
            recover(sock)
    raise AssertionError("unreachable")


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


@cli.command("experiments")
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

    def in_session(tag: str, ovl: Path | None, body):
        """``body(sock)`` on a fresh simulated rig of its own (work dir, ports, socket)."""
        w = work / tag
        w.mkdir(parents=True, exist_ok=True)
        rig_i, sim_i = make_session(sim_config.resolve(), w, runs)
        ctl_i = _controller_config(w, "ctl.yaml", rig_i, reversal_band_mm, ovl)
        with _session(sim_i, ctl_i, session, tag, lockstep) as sock:
            return body(sock)

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
        t_fit = time.monotonic()
        if overlay is None:
            overlay = fit_and_write(ctl_nominal, sweep_dirs, session / "identification")
        t_fit = time.monotonic() - t_fit
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
    click.echo(
        f"experiments: {wall:.0f} s wall ({'real time' if realtime else 'lock-step'}, "
        f"jobs {jobs}; fit {t_fit:.0f} s)",
        err=True,
    )
    table = format_table(rows)
    (session / "results.md").write_text(table)
    (session / "results.json").write_text(json.dumps(rows, indent=2, default=str))
    plot_experiments(rows, session / "figures")
    click.echo(table)
    click.echo(f"logs, figures and results in {session}")
