"""From logged calibration runs to fitted parameters and a config overlay (Qi et al. 2023 eq. 38).

:func:`identify_runs` is the offline half of ``cdcr-ctl identify``: it reads run directories
(:func:`cdcr_ctl.runlog.load_run`), cuts them into quasi-static dwells (:mod:`.dwell`), decides
which parameters the data can identify (:mod:`.parameters`) and fits them
(:mod:`.estimator`). It sees only the controller's rig config (the nominal parameters, the
effects of its model, where the load cells sit) and the logs: never the simulator's truth.

:func:`overlay_document` turns the result into a YAML overlay for the rig config's ``overlays:``
list: the fitted values in the config's own keys and units (``mu_disk``, ``E_MPa`` or ``EA_N``,
``pretension_N``, backbone ``E_MPa`` or ``EI_Nmm2``, pulley ``alpha``/``n``), each with its 95 %
confidence interval and nominal value as a comment (the config schema forbids unknown keys, so
the intervals live in comments and in the JSON report of :func:`report_dict`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cdcr_ctl.config.build_model import build_model, friction_law, loadcell_locations
from cdcr_ctl.config.registry import design_of
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import ConfigError, RigError
from cdcr_ctl.identify.dwell import DwellPoint, extract_dwells
from cdcr_ctl.identify.estimator import Estimate, FitOptions, Identification, identify
from cdcr_ctl.identify.parameters import plan_parameters
from cdcr_ctl.runlog.reader import load_run


def dwell_points(run_dirs: Sequence[str | Path]) -> tuple[list[DwellPoint], list[str]]:
    """Dwell points of every run, in order, with the readers' and extractor's warnings."""
    points: list[DwellPoint] = []
    warnings: list[str] = []
    for rd in run_dirs:
        run = load_run(rd)
        warnings += run.warnings
        pts, w = extract_dwells(run)
        warnings += w
        points += pts
    if not points:
        raise RigError("identification: the runs hold no dwell")
    return points, warnings


def identify_runs(
    cfg: RigConfig,
    run_dirs: Sequence[str | Path],
    options: FitOptions | None = None,
    fit_pulleys: str = "auto",
    source: str = "the rig config",
) -> Identification:
    """Fit the identifiable parameters of ``cfg``'s robot to the logged ``run_dirs``.

    The start values and everything not fitted come from ``cfg`` (the controller's nominal
    config); the model effects (geometry, friction, gravity) are the controller's, the disk
    friction's law too (``robot.friction_law`` through
    :func:`~cdcr_ctl.config.build_model.friction_law`, the function the controller's model is
    built with), so the fitted mu_disk is the coefficient of the law the controller applies.
    ``source`` names the config in the report. Raises
    :class:`RigError` when the logs hold no usable dwell, :class:`ConfigError` for a design
    other than ``cc_disk``.
    """
    if not design_of(cfg.design).identify:
        raise ConfigError(
            "rig config",
            "design",
            "identification fits a design registered with identify=True (cc_disk, Qi 2023)",
            cfg.design,
        )
    model = build_model(cfg)
    locs = loadcell_locations(cfg)
    points, warnings = dwell_points(run_dirs)
    fps, fixed = plan_parameters(model.params, points, locs, fit_pulleys, model.effects)
    if not fps:
        raise RigError(
            "identification: nothing identifiable in these runs: "
            + "; ".join(f"{f.name}: {f.reason}" for f in fixed)
        )
    law = friction_law(cfg.robot)
    res = identify(model.params, model.effects, points, locs, fps, fixed, options, law)
    res.friction_law_source = source
    res.warnings[:0] = warnings
    return res


def _fmt_ci(e: Estimate, scale: float = 1.0) -> str:
    lo, hi = e.ci95
    return f"95 % CI [{lo * scale:.5g}, {hi * scale:.5g}], nominal {e.nominal * scale:.5g}"


def overlay_document(
    cfg: RigConfig, ident: Identification, sources: Sequence[str] = ()
) -> tuple[dict[str, Any], list[str]]:
    """The overlay mapping (config keys) and one comment line per fitted value.

    EA and EI are written in the unit the config uses for them: a cable given by ``E_MPa`` gets
    E = EA / (pi d^2 / 4), a backbone given by ``E_MPa`` gets E = EI / (pi d^4 / 64).
    """
    robot = cfg.robot
    seg_doc: dict[str, dict[str, Any]] = {}
    cab_doc: dict[str, dict[str, Any]] = {}
    pul_doc: dict[str, dict[str, Any]] = {}
    notes: list[str] = []
    for e in ident.estimates:
        fp = e.parameter
        if fp.kind == "EI":
            seg = robot.segments[fp.index]
            bb = seg.backbone
            d = seg_doc.setdefault(seg.name, {"name": seg.name})
            if bb.EI_Nmm2 is not None:
                d["backbone"] = {"EI_Nmm2": round(e.value, 3)}
                notes.append(f"{seg.name} backbone EI_Nmm2 {e.value:.5g}: {_fmt_ci(e)}")
            else:
                assert bb.diameter_mm is not None
                f = 64.0 / (math.pi * bb.diameter_mm**4)
                d["backbone"] = {"E_MPa": round(e.value * f, 2)}
                notes.append(
                    f"{seg.name} backbone E_MPa {e.value * f:.6g} (EI {e.value:.5g} N mm^2): "
                    + _fmt_ci(e, f)
                )
        elif fp.kind in ("mu", "EA", "pretension", "backlash"):
            cab = robot.cables[fp.index]
            d = cab_doc.setdefault(cab.name, {"name": cab.name})
            if fp.kind == "backlash":
                d["backlash_mm"] = round(e.value, 6)
                notes.append(f"{cab.name} backlash_mm {e.value:.4g}: {_fmt_ci(e)}")
            elif fp.kind == "mu":
                d["mu_disk"] = round(e.value, 5)
                notes.append(f"{cab.name} mu_disk {e.value:.5g}: {_fmt_ci(e)}")
            elif fp.kind == "pretension":
                d["pretension_N"] = round(e.value, 4)
                notes.append(f"{cab.name} pretension_N {e.value:.5g}: {_fmt_ci(e)}")
            elif cab.EA_N is not None:
                d["EA_N"] = round(e.value, 2)
                notes.append(f"{cab.name} EA_N {e.value:.6g}: {_fmt_ci(e)}")
            else:
                f = 4.0 / (math.pi * cab.diameter_mm**2)
                d["E_MPa"] = round(e.value * f, 2)
                notes.append(
                    f"{cab.name} E_MPa {e.value * f:.6g} (EA {e.value:.5g} N): " + _fmt_ci(e, f)
                )
        elif fp.kind in ("pulley_alpha", "pulley_n"):
            key = "alpha" if fp.kind == "pulley_alpha" else "n"
            for ref, sc in zip(fp.refs, fp.scales, strict=True):
                name = str(ref.index)
                pul_doc.setdefault(name, {"name": name})[key] = round(e.value * sc, 5)
            notes.append(f"pulleys {key} {e.value:.5g} (shared): {_fmt_ci(e)}")
    tilts = {e.parameter.index: e for e in ident.estimates if e.parameter.kind == "gravity_tilt"}
    rob: dict[str, Any] = {}
    if tilts:
        g = ident.fitted.gravity_mm_s2
        rob["gravity_mm_s2"] = [round(float(v), 2) for v in g]
        for axis, e in sorted(tilts.items()):
            notes.append(
                f"mount tilt about base {'xy'[axis]} {e.value:.3g} deg "
                f"(gravity_mm_s2 turned from the config's {list(robot.gravity_mm_s2)}): "
                + _fmt_ci(e)
            )
    if seg_doc:
        rob["segments"] = list(seg_doc.values())
    if pul_doc:
        rob["pulleys"] = list(pul_doc.values())
    if cab_doc:
        rob["cables"] = list(cab_doc.values())
    header = [
        f"Fitted by `cdcr-ctl identify` on {datetime.now(UTC).isoformat(timespec='seconds')}",
        f"rig {cfg.name}; {len(ident.points)} dwells from: " + ", ".join(sources),
        f"reduced chi^2 {ident.chi2_reduced:.3g} over {ident.n_residuals} residuals",
    ]
    if ident.friction_law_text is not None:
        header.append(ident.friction_law_text)
    for f in ident.fixed:
        notes.append(f"not fitted {f.name} = {f.nominal:.5g}: {f.reason}")
    return {"robot": rob}, header + notes


def overlay_text(cfg: RigConfig, ident: Identification, sources: Sequence[str] = ()) -> str:
    """The overlay as YAML text, intervals and provenance as comments at the top."""
    import yaml

    doc, comments = overlay_document(cfg, ident, sources)
    head = "".join(f"# {c}\n" for c in comments)
    return head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)


def report_dict(ident: Identification) -> dict[str, Any]:
    """JSON-ready summary: estimates with intervals, fixed parameters, residual RMS, stages."""
    law = ident.friction_law
    return {
        "friction_law": None
        if law is None or law.capstan
        else {
            "wrap_exponent": law.exponent,
            "viscous_s_per_mm": law.viscous_s_per_mm,
            "breakaway": law.breakaway,
            "stribeck_mm_s": law.breakaway_mm_s,
            "source": ident.friction_law_source,
            "text": ident.friction_law_text,
        },
        "estimates": [
            {
                "name": e.name,
                "value": e.value,
                "std": e.std,
                "ci95": list(e.ci95),
                "nominal": e.nominal,
                "change_pct": e.change_pct,
                "at_bound": e.at_bound,
            }
            for e in ident.estimates
        ],
        "not_fitted": [
            {"name": f.name, "nominal": f.nominal, "reason": f.reason} for f in ident.fixed
        ],
        "rms_before": ident.rms_before,
        "rms_after": ident.rms_after,
        "chi2_reduced": ident.chi2_reduced,
        "n_residuals": ident.n_residuals,
        "n_unknowns": ident.n_unknowns,
        "n_dwells": len(ident.points),
        "stages": ident.stages,
        "warnings": ident.warnings,
    }


def summary_table(ident: Identification) -> str:
    """Plain-text table: parameter, nominal, fitted, change, 95 % interval; then residuals."""
    lines = [] if ident.friction_law_text is None else [ident.friction_law_text]
    lines.append(f"{'parameter':<22}{'nominal':>12}{'fitted':>12}{'change':>9}   95 % CI")
    for e in ident.estimates:
        lo, hi = e.ci95
        lines.append(
            f"{e.name:<22}{e.nominal:>12.5g}{e.value:>12.5g}{e.change_text:>9}"
            f"   [{lo:.5g}, {hi:.5g}]"
        )
    for f in ident.fixed:
        lines.append(f"{f.name:<22}{f.nominal:>12.5g}{'(fixed)':>12}   {f.reason}")
    units = {"tip": "mm", "cell": "N", "moment": "N mm", "compat": "mm"}
    lines.append("residual RMS, nominal -> fitted parameters:")
    for k, u in units.items():
        b, a = ident.rms_before.get(k, math.nan), ident.rms_after.get(k, math.nan)
        lines.append(f"  {k:<8}{b:>10.4g} -> {a:<10.4g}{u}")
    return "\n".join(lines)
