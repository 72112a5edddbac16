"""``cdcr-ctl discrepancy RUN_DIR...``: which physical effect the model is missing.

Simulates the logged drive positions with the controller's model, compares with the tracked tip
and the load cells, fits every candidate effect of :data:`cdcr_ctl.model.cc_disk.effects.CANDIDATES`
(and pairs), selects by blocked cross-validation, refits the winner and writes a report, plots and
a config fragment (:mod:`cdcr_ctl.discrepancy.report`). Works offline: no daemon needed.
"""

from __future__ import annotations

from pathlib import Path

import click

from cdcr_ctl.cli.app import Ctx
from cdcr_ctl.cli.discrepancy_keypoints import apply_overlay
from cdcr_ctl.errors import RigError


def _switches(items: tuple[str, ...]) -> dict[str, bool] | None:
    if not items:
        return None
    out = {}
    for it in items:
        key, sep, val = it.partition("=")
        if not sep or val.lower() not in ("on", "off", "true", "false"):
            raise click.BadParameter(f"{it!r}: use SWITCH=on|off", param_hint="--model-effects")
        out[key.strip()] = val.lower() in ("on", "true")
    return out


@click.command("discrepancy")
@click.argument("run_dirs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@click.option(
    "--rig-config",
    type=click.Path(exists=True, dir_okay=False),
    default=None,
    hidden=True,  # the old spelling of -c/--config, kept for scripts
    help="Same as -c/--config.",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    default=None,
    help="Report directory [default: FIRST_RUN_DIR/discrepancy].",
)
@click.option(
    "--effects", default=None, help="Comma-separated subset of the candidate effects (default all)."
)
@click.option(
    "--model-effects",
    multiple=True,
    help="Switch of the controller's model the run does not record, e.g. coupling=off.",
)
@click.option(
    "--folds",
    type=click.IntRange(2, 20),
    default=None,
    help="Cross-validation folds of loop logs [default: 5]; keypoint logs refuse it (they "
    "are judged on their held-out end).",
)
@click.option(
    "--pairs/--no-pairs",
    default=None,
    help="Also fit pairs of effects (loop logs) [default: on]; keypoint logs refuse --pairs.",
)
@click.option(
    "--max-points",
    type=click.IntRange(10, 100000),
    default=None,
    help="Loop logs: largest number of simulated samples per run, the rest interpolated "
    "[default: 700]. Keypoint logs: rows fitted by each replayed candidate, chosen to span "
    "the log [default: as many as 20 s per candidate allows].",
)
@click.option("--jobs", type=click.IntRange(1, 64), default=2, show_default=True)
@click.option(
    "--apply",
    "apply_to",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Write the named effect's fitted values as a rig-config overlay to this file "
    "(checked against the run's effective config); exit 1 when no effect was named.",
)
@click.option("--plots/--no-plots", default=True, show_default=True)
@click.option("--progress/--no-progress", default=True, show_default=True)
@click.pass_obj
def discrepancy(
    obj: Ctx,
    run_dirs: tuple[str, ...],
    rig_config: str | None,
    out: str | None,
    effects: str | None,
    model_effects: tuple[str, ...],
    folds: int | None,
    pairs: bool | None,
    max_points: int | None,
    jobs: int,
    apply_to: Path | None,
    plots: bool,
    progress: bool,
) -> None:
    """Find where model and measurement disagree, name the missing effect, refit.

    Exit code 0 whatever the verdict; the verdict is the first line of the output. With
    ``--apply OVERLAY`` the fitted effect is written as an overlay for the rig config's
    ``overlays:`` list (the daemon loads it at start); no effect named: nothing written, exit 1.
    The controller's rig config is -c/--config (default: the copy in each run directory).
    """
    from cdcr_ctl.discrepancy import analyse
    from cdcr_ctl.discrepancy.gap import GAP_WINDOW_S
    from cdcr_ctl.discrepancy.keypoint_path import is_keypoint_log
    from cdcr_ctl.discrepancy.report import config_fragment, summary_lines, write_report

    rig_config = rig_config or obj.config
    if all(is_keypoint_log(r) for r in run_dirs):
        from cdcr_ctl.cli.discrepancy_keypoints import keypoint_discrepancy

        keypoint_discrepancy(
            obj,
            run_dirs,
            rig_config=rig_config,
            out=out,
            effects=effects,
            switches=_switches(model_effects),
            folds=folds,
            pairs=pairs,
            max_points=max_points,
            jobs=jobs,
            apply_to=apply_to,
            plots=plots,
            progress=progress,
        )
        return
    folds = 5 if folds is None else folds
    pairs = True if pairs is None else pairs
    max_points = 700 if max_points is None else max_points
    from cdcr_ctl.model.cc_disk.effects import CANDIDATES, candidate

    terms = CANDIDATES
    if effects:
        try:
            terms = tuple(candidate(n.strip()) for n in effects.split(",") if n.strip())
        except KeyError as exc:
            raise click.BadParameter(str(exc), param_hint="--effects") from None
    res = analyse(
        list(run_dirs),
        rig_config=rig_config,
        candidates=terms,
        model_effects=_switches(model_effects),
        folds=folds,
        pairs=pairs,
        max_points=max_points,
        jobs=jobs,
        progress=progress,
    )
    dest = Path(out) if out else Path(run_dirs[0]) / "discrepancy"
    paths = write_report(res, dest, with_plots=plots)
    b, a = res.systematic_gap_mm
    result = {
        "verdict": res.selection.verdict,
        "effect": res.named,
        "parameters": (
            {
                n: {"value": float(v), "ci95": float(c), "unit": u}
                for n, u, v, c in zip(
                    res.refit.names, res.refit.units, res.refit.values, res.refit.ci95, strict=True
                )
            }
            if res.refit
            else {}
        ),
        "tip_rms_before_mm": res.tip_rms_before_mm,
        "tip_rms_after_mm": res.tip_rms_after_mm,
        # per run, the tension RMS gap (N) before and after the refit (logs without a tracker)
        "tension_rms_N": [[o.tension_rms_before_N, o.tension_rms_after_N] for o in res.outcomes],
        "gap_shrink_percent": 100 * res.gap_shrink,
        "tip_gap_above_noise_mm": [b, a],
        "gap_above_noise_shrink_percent": 100 * res.systematic_gap_shrink,
        # the tip error averaged over tip_gap_window_s (the tracker's noise / sqrt(rows)):
        # before, after and its noise floor (mm)
        "tip_gap_mm": list(res.tip_gap_mm),
        "tip_gap_shrink_percent": 100 * res.tip_gap_shrink,
        "tip_gap_window_s": GAP_WINDOW_S,
        "tie": list(res.selection.tie),
        "elapsed_s": res.elapsed_s,
        "files": {k: str(v) for k, v in paths.items()},
    }
    lines = [*summary_lines(res), f"report: {paths['report']}"]
    if apply_to is not None:
        if res.refit is None or res.named is None:
            obj.emit(result, "\n".join(lines))
            raise RigError(
                f"--apply: no effect was named ({res.selection.verdict}): nothing written"
            )
        apply_overlay(config_fragment(res, for_apply=True), Path(run_dirs[0]), apply_to)
        result["overlay"] = str(apply_to)
        lines.append(
            f"applied: {apply_to} (add it to the rig config's `overlays:` list, then restart the"
            " daemon and re-run the experiment)"
        )
    obj.emit(result, "\n".join(lines))
