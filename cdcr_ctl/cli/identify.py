"""``cdcr-ctl identify`` and ``cdcr-ctl experiments``: calibration and the paper's experiments.

``identify`` runs the calibration sweep of Qi et al. 2023 section 5 (eq. 38: beta = 0, 120,
240 deg; theta = 40-90 deg in 5 deg steps, up and down) on the rig through the running daemon,
then fits the model parameters offline from the logged run (:mod:`cdcr_ctl.identify`) and writes
``identified.yaml`` (an overlay for the rig config's ``overlays:``), ``identification.json`` and
residual plots. ``--from-run`` fits logged runs without moving anything.

``experiments`` (the whole story on the simulated rig in one command) is
:mod:`cdcr_ctl.cli.experiments`, the helpers both share :mod:`cdcr_ctl.cli.identify_runs` (their
public names are importable here too).
"""

from __future__ import annotations

from pathlib import Path

import click

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

__all__ = [
    "ATTEMPTS",
    "MODES",
    "REVERSAL_BAND_MM",
    "ROOT_CONFIG",
    "_run_recovering",
    "fit_and_write",
    "identify_cmd",
    "run_sweep",
]


@click.command("identify")
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
    default=None,
    help="Tracker noise per axis of one keypoint row (weights the tip residuals) "
    "[default: estimated from the log].",
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
    default=None,
    help="Keypoint rows to fit, chosen to span the log, no time limit "
    "[default: as many as --budget-s allows].",
)
@click.option(
    "--budget-s",
    type=click.FloatRange(1.0, 36_000.0),
    default=None,
    help="CPU seconds the keypoint fit's replays may take [default: 20] (rows chosen to fit "
    "it, the cost of a row measured on the config's replay; about the same rows on a loaded "
    "machine, which takes longer; the two whole-log replays of the held-out check come on top).",
)
@click.option(
    "--max-nfev",
    type=click.IntRange(1, 1000),
    default=30,
    show_default=True,
    help="Least-squares evaluations of the keypoint fit (trial points; the Jacobians not counted).",
)
@click.option(
    "--jobs",
    type=click.IntRange(1, 64),
    default=None,
    help="Worker processes of the keypoint fit's replays [default: CPU count, at most 8].",
)
@click.option("--progress/--no-progress", default=True, show_default=True)
@click.pass_obj
def identify_cmd(
    obj: Ctx,
    out: Path,
    from_runs: tuple[Path, ...],
    quick: bool,
    log_kind: str,
    tip_noise_mm: float,
    holdout: float,
    max_points: int | None,
    budget_s: float | None,
    max_nfev: int,
    jobs: int | None,
    progress: bool,
    accept_misfit: bool,
) -> None:
    """Run the calibration sweep of Qi et al. 2023 and fit mu, EA, EI, pretension, lost motion,
    mount tilt (gravity direction), pulleys.

    Needs -c/--config (the controller's rig config: nominal values, geometry, load-cell places).
    Writes OUT/identified.yaml: add it to the rig config's `overlays:` list. A fit that does
    not explain its data (cdcr_ctl.identify.gate; for tip-only and keypoint logs: held-out
    rows not improved beyond their noise, cdcr_ctl.identify.keypoint_gate) writes the report,
    no overlay, and exits 1, unless --accept-misfit.
    """
    if not obj.config:
        raise click.UsageError("identify needs -c/--config RIG (the controller's rig config)")
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
            import time

            t0 = time.monotonic()

            def say(line: str) -> None:  # progress past the first 5 s
                if progress and time.monotonic() - t0 > 5.0:
                    click.echo(f"[{time.monotonic() - t0:5.1f} s] {line}", err=True)

            opt = KeypointOptions(
                holdout=holdout,
                tip_noise_mm=tip_noise_mm,
                max_points=max_points,
                max_nfev=max_nfev,
                **({} if budget_s is None else {"budget_s": budget_s}),
                jobs=jobs,
                progress=say,
            )
            from cdcr_ctl.identify.gate import MisfitError

            try:
                ov, lines = fit_lab_logs(
                    cfg,
                    runs,
                    out,
                    kinds,
                    opt,
                    [str(r) for r in runs],
                    accept_misfit=accept_misfit,
                    forced=log_kind != "auto",
                )
            except MisfitError as exc:
                click.echo("\n".join(getattr(exc, "lines", [])), err=True)
                raise
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
