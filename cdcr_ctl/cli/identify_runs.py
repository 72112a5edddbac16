"""Helpers of ``cdcr-ctl identify`` and ``experiments``: run trajectories and the calibration
sweep through a running daemon, and fit and write the identified overlay.

No click commands here (they are :mod:`cdcr_ctl.cli.identify` and
:mod:`cdcr_ctl.cli.experiments`); the sweep is Qi et al. 2023 section 5 (eq. 38).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from cdcr_ctl.cli.runwait import follow_run
from cdcr_ctl.daemon.client import ControlClient
from cdcr_ctl.errors import RigError

if TYPE_CHECKING:
    from cdcr_ctl.identify.estimator import FitOptions

ROOT_CONFIG = Path(__file__).resolve().parents[2] / "config"
#: Compensation modes of the experiments, in table order.
MODES = ("off", "model", "measured")
#: Default controller setting for the experiments: cable-material travel over which friction
#: reverses in the compensation (control.reversal_band_mm; see cdcr_ctl.model.cc_disk.compensation).
REVERSAL_BAND_MM = 0.01
#: Tries per experiment run (a trip on a loaded machine is retried after recovery).
ATTEMPTS = 5


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
    ident = identify_runs(cfg, run_dirs, options, fit_pulleys, source=str(cfg_path))
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


def _run_recovering(
    sock: Path, name: str, rows: list[list[float]], comp: str, log: bool = True
) -> dict[str, Any]:
    """:func:`~cdcr_ctl.cli.runwait.follow_run`; if the daemon refuses it because of a latched
    trip (one that happened between runs), recover first and try again."""
    from cdcr_ctl.cli.demo import recover
    from cdcr_ctl.daemon.client import DaemonError

    for attempt in range(ATTEMPTS):
        try:
            return follow_run(sock, name, rows, comp, log)
        except DaemonError as exc:
            if attempt == ATTEMPTS - 1 or not any(w in str(exc) for w in ("tripped", "disabled")):
                raise
            click.echo(f"  {name}: {exc}; recovering", err=True)
            recover(sock)
    raise AssertionError("unreachable")
