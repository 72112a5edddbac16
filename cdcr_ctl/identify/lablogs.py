"""``identify --from-run`` for the logs labs have: pick the path by log kind, write the results.

* ``loadcell`` runs (the daemon's sweep): :func:`cdcr_ctl.identify.pipeline.identify_runs`;
* ``tip`` and ``keypoint`` runs: :func:`cdcr_ctl.identify.keypoints.identify_keypoint_runs`
  (observability, fit of what is identifiable, reduced chi^2, held-out tip RMSE);
* ``pulls`` runs (one cable pulled at a time): hole offsets per segment
  (:mod:`cdcr_ctl.identify.geometry`).

The overlay (``identified.yaml``) is written only when the gate passes: for keypoint and tip runs
the held-out rows improve beyond their noise (:mod:`cdcr_ctl.identify.keypoint_gate`; a misfit
that still improves them is written with the misfit in its header), for pull runs the azimuths
scatter within 5 x the tracker noise about one offset per segment. Otherwise the report
(``identification.json``) is written, no overlay, and :class:`~cdcr_ctl.identify.gate.MisfitError`
names ``--accept-misfit``.
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
from cdcr_ctl.identify.gate import MisfitError
from cdcr_ctl.identify.geometry import hole_offsets_from_pulls, is_pull_log, offsets_lines
from cdcr_ctl.identify.keypoint_gate import MISFIT_FACTOR, OVERRIDE
from cdcr_ctl.identify.keypoint_report import keypoint_report, report_lines
from cdcr_ctl.identify.keypoints import KeypointOptions, identify_keypoint_runs
from cdcr_ctl.identify.logkind import KINDS, detect_kind
from cdcr_ctl.model.cc_disk.params import RobotParams
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
    if "gravity" in kinds:
        for seg, sp in zip(robot.segments, fitted.segments, strict=True):
            segs.append({"name": seg.name, "disks": {"mass_g": round(sp.disk_mass_g, 4)}})
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
        if "backlash" in kinds:
            d["backlash_mm"] = round(cp.backlash_mm, 4)
        if len(d) > 1:
            cabs.append(d)
    rob: dict[str, Any] = {}
    if segs:
        rob["segments"] = segs
    if cabs:
        rob["cables"] = cabs
    head = "".join(f"# {h}\n" for h in header)
    return head + yaml.safe_dump({"robot": rob}, sort_keys=False, default_flow_style=None)


def fit_lab_logs(
    cfg: RigConfig,
    run_dirs: Sequence[Path],
    out: Path,
    kinds: Sequence[str],
    options: KeypointOptions,
    sources: Sequence[str],
    accept_misfit: bool = False,
    forced: bool = False,
) -> tuple[Path | None, list[str]]:
    """Fit tip/keypoint runs or pull runs of ``cfg``; write the report (always) and the overlay
    when the gate passes (:mod:`.keypoint_gate`) or ``accept_misfit``.

    Returns the overlay path and the report lines; raises
    :class:`~cdcr_ctl.identify.gate.MisfitError` (after writing the report) when the gate
    refuses and ``accept_misfit`` is off. ``forced``: the kinds came from ``--log-kind``."""
    out.mkdir(parents=True, exist_ok=True)
    overlay_path = out / "identified.yaml"
    overlay_path.unlink(missing_ok=True)  # never leave a stale overlay beside a new report
    lines: list[str] = []
    refusals: list[str] = []
    pulls = [r for r, k in zip(run_dirs, kinds, strict=True) if k == "pulls"]
    others = [r for r, k in zip(run_dirs, kinds, strict=True) if k != "pulls"]
    report: dict[str, Any] = {"runs": [str(r) for r in run_dirs]}
    text: str | None = None
    params = robot_params(cfg.robot)
    if pulls:
        offs, w = hole_offsets_from_pulls(params, pulls)
        lines += offsets_lines(offs) + [f"warning: {x}" for x in w]
        bad = [h for h in offs if not h.misfit_ratio <= MISFIT_FACTOR]
        for h in bad:
            refusals.append(
                f"{h.segment}: the pull azimuths scatter {h.misfit_ratio:.3g} x the tracker "
                f"noise about one offset (more than {MISFIT_FACTOR:g} x): model error, not noise"
            )
        report["hole_offsets"] = [
            {
                "segment": h.segment,
                "offset_rad": h.offset_rad,
                "ci95_rad": list(h.ci95_rad),
                "misfit_ratio": h.misfit_ratio,
            }
            for h in offs
        ]
        report["warnings"] = list(w) + refusals
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
            head = ["Hole offsets fitted by `cdcr-ctl identify` from tendon pulls: "]
            head += [ln.strip() for ln in offsets_lines(offs)[1:]]
            head.append("sources: " + ", ".join(sources))
            text = overlay_from_params(cfg, fitted, {"hole_offset"}, head)
    if others:
        opt = options
        fk = {k for r, k in zip(run_dirs, kinds, strict=True) if k != "pulls"}
        if forced and len(fk) == 1:
            from dataclasses import replace

            opt = replace(options, kind=fk.pop())
        if opt.kind == "loadcell":
            raise RigError("internal: load-cell runs go through the dwell pipeline")
        res = identify_keypoint_runs(cfg, others, opt)
        lines += report_lines(res)
        report["keypoint_fit"] = keypoint_report(res)
        h = res.heldout
        v = res.verdict
        assert v is not None
        if not v.write:
            refusals.append(
                f"the held-out rows did not improve beyond their noise ({h.rmse_nominal:.4g} -> "
                f"{h.rmse_fitted:.4g} mm)"
            )
        head = [
            f"Fitted by `cdcr-ctl identify` ({', '.join(sorted(set(kinds)))} logs) from: "
            + ", ".join(sources),
            f"reduced chi^2 {res.ident.chi2_reduced:.4g}; held-out tip RMSE "
            f"{h.rmse_nominal:.4g} -> {h.rmse_fitted:.4g} mm over {h.n_rows} rows",
        ]
        if v.misfit:
            head.insert(
                0,
                f"MISFIT: residual {v.misfit_ratio:.3g} x the tracker noise (model error); "
                "the held-out rows improved, so the parameters are written",
            )
        for e in res.ident.estimates:
            lo, hi = e.ci95
            tag = " (ON ITS BOUND)" if e.at_bound else (" (clipped)" if e.ci_at_bound else "")
            head.append(f"{e.name} {e.value:.6g}: 95 % CI [{lo:.6g}, {hi:.6g}]{tag}")
        for f in res.ident.fixed:
            head.append(f"not fitted {f.name} = {f.nominal:.5g}: {f.reason}")
        kinds_fit = {e.parameter.kind for e in res.ident.estimates}
        text = overlay_from_params(cfg, res.ident.fitted, kinds_fit, head)
    report["refused"] = refusals
    report["accept_misfit"] = accept_misfit
    overlay: Path | None = None
    if text is not None and (not refusals or accept_misfit):
        if refusals:
            text = f"# MISFIT ACCEPTED BY THE OPERATOR ({OVERRIDE}): {'; '.join(refusals)}\n" + text
            lines.append(f"warning: MISFIT ACCEPTED ({OVERRIDE}), overlay written")
        overlay_path.write_text(text)
        overlay = overlay_path
    report["overlay"] = None if overlay is None else str(overlay)
    (out / "identification.json").write_text(json.dumps(report, indent=2, default=float))
    if refusals and not accept_misfit:
        err = MisfitError(
            "NOT WRITTEN: " + "; ".join(refusals) + f". No overlay (report: "
            f"{out / 'identification.json'}); {OVERRIDE} writes it all the same, marked"
        )
        err.lines = lines  # type: ignore[attr-defined]  # the report, for the command to print
        raise err
    return overlay, lines
