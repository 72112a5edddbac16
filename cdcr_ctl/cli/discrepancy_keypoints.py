"""``cdcr-ctl discrepancy`` on keypoint logs (:mod:`cdcr_ctl.discrepancy.keypoint_path`): every
option of the command is honoured or refused with a message, the report is written to
``--out`` (``report.txt``, ``report.json``, ``candidates.png`` unless ``--no-plots``), and
``--apply`` writes the named effect's overlay or exits non-zero saying why.

The named effect goes into the overlay under the rig config's own keys: ``routing`` as the
cables' ``hole_angle_rad`` and ``routing_radius_mm``, ``hysteresis`` as the cables'
``backlash_mm``, ``gravity`` as the segments' disk ``mass_g`` and the tip mass as
``tip_load.payload_kg``. ``curvature`` (the cc_disk model
is constant curvature per segment) and ``registration`` (a tracker alignment, which belongs in
``sensors.tracker.base_from_tracker`` of the rig with the tracker) have no key the model reads:
``--apply`` refuses them with exit status 1 and the values to use.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from cdcr_ctl.cli.app import Ctx
from cdcr_ctl.errors import RigError


def keypoint_discrepancy(
    obj: Ctx,
    run_dirs: tuple[str, ...],
    *,
    rig_config: str | None,
    out: str | None,
    effects: str | None,
    switches: dict[str, bool] | None,
    folds: int | None,
    pairs: bool | None,
    max_points: int | None,
    jobs: int,
    apply_to: Path | None,
    plots: bool,
    progress: bool,
) -> None:
    """Run :func:`~cdcr_ctl.discrepancy.keypoint_path.analyse_keypoints` (module docstring)."""
    import dataclasses
    import time

    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.discrepancy.keypoint_effects import EFFECTS
    from cdcr_ctl.discrepancy.keypoint_path import analyse_keypoints
    from cdcr_ctl.model.cc_disk.params import Effects

    if folds is not None:
        raise click.UsageError(
            "--folds: keypoint logs are judged on their held-out end (the last 30 % of each "
            "run by time), not by cross-validation folds; drop --folds"
        )
    if pairs:
        raise click.UsageError(
            "--pairs: on keypoint logs each effect is fitted alone (a pair would double the "
            "replayed fits); drop --pairs or give --no-pairs"
        )
    names = tuple(EFFECTS)
    if effects:
        names = tuple(n.strip() for n in effects.split(",") if n.strip())
        bad = [n for n in names if n not in EFFECTS]
        if bad:
            raise click.BadParameter(
                f"{', '.join(bad)}: keypoint logs search {', '.join(EFFECTS)}",
                param_hint="--effects",
            )
    if switches:
        known = {f.name for f in dataclasses.fields(Effects) if isinstance(f.default, bool)}
        bad = sorted(set(switches) - known)
        if bad:
            raise click.BadParameter(
                f"{', '.join(bad)}: the model's switches are {', '.join(sorted(known))}",
                param_hint="--model-effects",
            )
    cfg_path = rig_config or obj.config
    if cfg_path is None:
        cfg_file = Path(run_dirs[0]) / "config.yaml"
        if not cfg_file.is_file():
            raise click.UsageError("keypoint logs carry no config: give -c RIG (or --rig-config)")
        cfg_path = str(cfg_file)
    cfg = load_rig_config(cfg_path)
    t0 = time.monotonic()

    def say(line: str) -> None:
        if progress and time.monotonic() - t0 > 5.0:
            click.echo(f"[{time.monotonic() - t0:5.1f} s] {line}", err=True)

    res = analyse_keypoints(
        cfg,
        list(run_dirs),
        max_points=max_points,
        effects=names,
        jobs=jobs,
        progress=say,
        model_switches=switches,
    )
    dest = Path(out) if out else Path(run_dirs[0]) / "discrepancy"
    dest.mkdir(parents=True, exist_ok=True)
    result = res.as_dict()
    lines = res.lines()
    (dest / "report.txt").write_text("\n".join(lines) + "\n")
    files = {"report": str(dest / "report.txt"), "json": str(dest / "report.json")}
    if plots:
        files["candidates"] = str(_plot(res, dest / "candidates.png"))
    result["files"] = files
    lines.append(f"report: {dest / 'report.txt'}")
    if apply_to is not None:
        text, why = _overlay(cfg, res)
        if text is None:
            (dest / "report.json").write_text(json.dumps(result, indent=2, default=float))
            obj.emit(result, "\n".join(lines))
            raise RigError(f"--apply: {why}: nothing written to {apply_to}")
        apply_overlay(text, Path(run_dirs[0]), apply_to)
        result["overlay"] = str(apply_to)
        lines.append(f"applied: {apply_to} (add it to the rig config's `overlays:` list)")
    (dest / "report.json").write_text(json.dumps(result, indent=2, default=float))
    obj.emit(result, "\n".join(lines))


def _overlay(cfg, res) -> tuple[str | None, str]:
    """(overlay text, '') for a named effect the config can carry, else (None, why)."""
    e = res.effect
    if e is None:
        return None, f"no effect was named ({res.verdict})"
    if e.params is None:
        vals = ", ".join(f"{n} = {v:.4g}" for n, v in zip(e.names, e.values, strict=True))
        where = (
            "sensors.tracker.base_from_tracker of the rig with the tracker"
            if e.name == "registration"
            else "no key: the cc_disk model is constant curvature per segment"
        )
        return (
            None,
            f"the named effect {e.name} ({vals}) has no rig-config key the model reads ({where})",
        )
    from cdcr_ctl.identify.lablogs import overlay_from_params

    kinds = {"routing": {"hole_offset", "routing_radius"}, "hysteresis": {"backlash"}}
    head = [f"Fitted by `cdcr-ctl discrepancy` on keypoint logs: {res.verdict}"]
    text = overlay_from_params(cfg, e.params, kinds.get(e.name, {e.name}), head)
    if e.name == "gravity":  # the tip mass goes in as the payload (kg)
        kg = round(e.params.tip_mass_g / 1000.0, 6)
        text += f"  tip_load:\n    payload_kg: {kg}\n"
    return text, ""


def _plot(res, path: Path) -> Path:
    """Bar chart: held-out tip RMSE of the config and of every candidate."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fits = sorted(res.fits, key=lambda f: f.rmse_heldout)
    fig = Figure(figsize=(7, 3.5), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    names = ["config", *(f.name for f in fits)]
    vals = [res.rmse_config, *(f.rmse_heldout for f in fits)]
    colors = ["tab:gray"] + [
        "tab:green" if res.effect is not None and f.name == res.effect.name else "tab:blue"
        for f in fits
    ]
    ax.bar(names, vals, color=colors)
    ax.set_ylabel("held-out tip RMSE (mm)")
    ax.set_title("keypoint log: each candidate effect fitted alone")
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=100)
    return path


def apply_overlay(fragment: str, run_dir: Path, dest: Path) -> None:
    """Write ``fragment`` to ``dest`` after checking it loads over the run's effective config
    (``config_effective.yaml`` in the run directory; a ConfigError names the key)."""
    import tempfile

    import yaml

    from cdcr_ctl.config import load_rig_config

    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(fragment, encoding="utf-8")
    effective = run_dir / "config_effective.yaml"
    if not effective.is_file():
        return
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "probe.yaml"
        doc = {"extends": str(effective.resolve()), "overlays": [str(dest.resolve())]}
        probe.write_text(yaml.safe_dump(doc))
        try:
            load_rig_config(probe)
        except RigError:
            dest.unlink(missing_ok=True)
            raise
