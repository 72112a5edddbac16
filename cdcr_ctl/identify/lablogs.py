"""``identify --from-run`` for the logs labs have: pick the path by log kind, write the results.

* ``loadcell`` runs (the daemon's sweep): :func:`cdcr_ctl.identify.pipeline.identify_runs`;
* ``tip`` and ``keypoint`` runs: :func:`cdcr_ctl.identify.keypoints.identify_keypoint_runs`
  (observability, fit of what is identifiable, reduced chi^2, held-out tip RMSE);
* ``pulls`` runs (one cable pulled at a time): hole offsets per segment
  (:mod:`cdcr_ctl.identify.geometry`).

The overlay (``identified.yaml``) is written only when the fit explains the log better than the
config does on the held-out rows; otherwise the report says so and nothing is written.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from cdcr_ctl.config.build_model import robot_params
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import RigError
from cdcr_ctl.identify.geometry import hole_offsets_from_pulls, is_pull_log, offsets_lines
from cdcr_ctl.identify.keypoints import (
    KeypointIdentification,
    KeypointOptions,
    identify_keypoint_runs,
    report_lines,
)
from cdcr_ctl.identify.logkind import KINDS, detect_kind
from cdcr_ctl.model.params import RobotParams
from cdcr_ctl.runlog.reader import load_run

LOG_KINDS = ("auto", *KINDS, "pulls")


def run_kinds(run_dirs: Sequence[Path], forced: str) -> list[str]:
    """The kind of every run: ``forced`` unless ``auto`` (then pulls first, else detected)."""
    if forced != "auto":
        return [forced] * len(run_dirs)
    out = []
    for rd in run_dirs:
        run = load_run(rd)
        out.append("pulls" if is_pull_log(run) else detect_kind(run)[0])
    return out


def overlay_from_params(
    cfg: RigConfig, fitted: RobotParams, kinds: set[str], header: Sequence[str]
) -> str:
    """YAML overlay with the fitted fields of ``kinds`` in the config's own keys and units."""
    robot = cfg.robot
    segs: list[dict[str, Any]] = []
    if "EI" in kinds:
        for seg, sp in zip(robot.segments, fitted.segments, strict=True):
            bb = seg.backbone
            if bb.EI_Nmm2 is not None or bb.diameter_mm is None:
                segs.append({"name": seg.name, "backbone": {"EI_Nmm2": round(sp.EI_Nmm2, 3)}})
            else:
                E = sp.EI_Nmm2 * 64.0 / (math.pi * bb.diameter_mm**4)
                segs.append({"name": seg.name, "backbone": {"E_MPa": round(E, 2)}})
    cabs: list[dict[str, Any]] = []
    for c, cp in zip(robot.cables, fitted.cables, strict=True):
        d: dict[str, Any] = {"name": c.name}
        if "EA" in kinds:
            if c.EA_N is not None:
                d["EA_N"] = round(cp.EA_N, 2)
            else:
                d["E_MPa"] = round(cp.EA_N * 4.0 / (math.pi * c.diameter_mm**2), 2)
        if "pretension" in kinds:
            d["pretension_N"] = round(cp.pretension_N, 4)
        if "mu" in kinds:
            d["mu_disk"] = round(cp.mu_disk, 5)
        if "routing_radius" in kinds:
            d["routing_radius_mm"] = round(cp.routing_radius_mm, 4)
        if "hole_offset" in kinds:
            d["hole_angle_rad"] = round(cp.hole_angle_rad, 6)
        if len(d) > 1:
            cabs.append(d)
    rob: dict[str, Any] = {}
    if segs:
        rob["segments"] = segs
    if cabs:
        rob["cables"] = cabs
    head = "".join(f"# {h}\n" for h in header)
    return head + yaml.safe_dump({"robot": rob}, sort_keys=False, default_flow_style=None)


def keypoint_report(res: KeypointIdentification) -> dict[str, Any]:
    """JSON-ready report of a keypoint/tip fit."""
    ob = res.observability
    return {
        "log_kinds": res.kinds,
        "observability": {
            "singular_values": list(ob.singular_values),
            "directions": [list(d) for d in ob.directions],
            "halfwidth_over_tolerance": dict(zip(ob.names, ob.halfwidth, strict=True)),
            "tolerance": dict(zip(ob.names, ob.tolerance, strict=True)),
        },
        "fitted": [
            {"name": e.name, "value": e.value, "ci95": list(e.ci95), "nominal": e.nominal}
            for e in res.ident.estimates
        ],
        "fixed": [
            {"name": f.name, "nominal": f.nominal, "reason": f.reason} for f in res.ident.fixed
        ],
        "chi2_reduced": res.ident.chi2_reduced,
        "n_residuals": res.ident.n_residuals,
        "heldout": vars(res.heldout),
        "n_points": res.n_points,
        "n_fit": res.n_fit,
        "fit_time_s": res.fit_time_s,
        "warnings": res.warnings,
    }


def fit_lab_logs(
    cfg: RigConfig,
    run_dirs: Sequence[Path],
    out: Path,
    kinds: Sequence[str],
    options: KeypointOptions,
    sources: Sequence[str],
) -> tuple[Path | None, list[str]]:
    """Fit tip/keypoint runs or pull runs of ``cfg``; write report (and overlay when it helps).

    Returns the overlay path (None when nothing was written) and the report lines."""
    out.mkdir(parents=True, exist_ok=True)
    lines: list[str] = []
    pulls = [r for r, k in zip(run_dirs, kinds, strict=True) if k == "pulls"]
    others = [r for r, k in zip(run_dirs, kinds, strict=True) if k != "pulls"]
    report: dict[str, Any] = {"runs": [str(r) for r in run_dirs]}
    overlay: Path | None = None
    params = robot_params(cfg.robot)
    if pulls:
        offs, w = hole_offsets_from_pulls(params, pulls)
        lines += offsets_lines(offs) + [f"warning: {x}" for x in w]
        report["hole_offsets"] = [
            {"segment": h.segment, "offset_rad": h.offset_rad, "ci95_rad": list(h.ci95_rad)}
            for h in offs
        ]
        if offs and not others:
            import dataclasses

            by_seg = {h.segment: h.offset_rad for h in offs}
            cab = tuple(
                dataclasses.replace(
                    c,
                    hole_angle_rad=c.hole_angle_rad
                    + by_seg.get(params.segments[c.segment].name, 0.0),
                )
                for c in params.cables
            )
            fitted = dataclasses.replace(params, cables=cab)
            overlay = out / "identified.yaml"
            head = ["Hole offsets fitted by `cdcr-ctl identify` from tendon pulls: "]
            head += [ln.strip() for ln in offsets_lines(offs)[1:]]
            head.append("sources: " + ", ".join(sources))
            overlay.write_text(overlay_from_params(cfg, fitted, {"hole_offset"}, head))
    if others:
        opt = options
        forced = {k for r, k in zip(run_dirs, kinds, strict=True) if k != "pulls"}
        if len(forced) == 1:
            from dataclasses import replace

            opt = replace(options, kind=forced.pop())
        if opt.kind == "loadcell":
            raise RigError("internal: load-cell runs go through the dwell pipeline")
        res = identify_keypoint_runs(cfg, others, opt)
        lines += report_lines(res)
        report["keypoint_fit"] = keypoint_report(res)
        h = res.heldout
        if h.rmse_fitted <= h.rmse_nominal:
            overlay = out / "identified.yaml"
            head = [
                f"Fitted by `cdcr-ctl identify` ({', '.join(sorted(set(kinds)))} logs) from: "
                + ", ".join(sources),
                f"reduced chi^2 {res.ident.chi2_reduced:.4g}; held-out tip RMSE "
                f"{h.rmse_nominal:.4g} -> {h.rmse_fitted:.4g} mm over {h.n_rows} rows",
            ]
            for e in res.ident.estimates:
                lo, hi = e.ci95
                head.append(f"{e.name} {e.value:.6g}: 95 % CI [{lo:.6g}, {hi:.6g}]")
            for f in res.ident.fixed:
                head.append(f"not fitted {f.name} = {f.nominal:.5g}: {f.reason}")
            kinds_fit = {e.parameter.kind for e in res.ident.estimates}
            overlay.write_text(overlay_from_params(cfg, res.ident.fitted, kinds_fit, head))
        else:
            lines.append(
                "NOT WRITTEN: the fitted parameters predict the held-out rows worse than the "
                "config; no overlay"
            )
    (out / "identification.json").write_text(json.dumps(report, indent=2, default=float))
    return overlay, lines
