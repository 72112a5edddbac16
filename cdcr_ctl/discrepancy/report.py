"""Report of a discrepancy analysis: text, plots and a config fragment.

* ``report.txt``: the verdict (a tie names both effects), the named effect with its fitted
  parameters and 95 % confidence intervals, the tip gap before/after (the RMS of the tip error
  averaged over :data:`~cdcr_ctl.discrepancy.gap.GAP_WINDOW_S`, and per sample: measured RMS and
  the part above the tracker noise), the
  model comparison table (held-out mean square, AIC, BIC) and the localisation tables.
* ``residuals.png`` (tip error before/after over time), ``localisation.png`` (tip RMS by motion
  phase, bend, tension level), ``candidates.png`` (held-out mean square per model).
* ``fragment.yaml``: YAML to overlay on the rig config (``overlays:``): the fitted values under
  the rig config's own keys (cable ``E_MPa``/``EA_N``, ``mu_disk``, pulley ``alpha``, disk
  ``mass_g``, drive ``counts_per_mm``, tracker ``base_from_tracker``, the disk friction's law
  ``robot.friction_law``). Quantities the rig config
  has no key for yet (backlash, the model's effect switches, a coupling gain) are written as YAML
  comments with the value, so the fragment always validates.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from cdcr_ctl.discrepancy.gap import GAP_WINDOW_S
from cdcr_ctl.discrepancy.workflow import DiscrepancyResult
from cdcr_ctl.errors import RigError
from cdcr_ctl.model.cc_disk.effects import rotation_from_rotvec, rotvec_from_rotation

VERDICT_TEXT = {
    "named": "MISSING EFFECT: {name}",
    "nothing_missing": "NOTHING SIGNIFICANT IS MISSING",
    "unexplained": "NO EFFECT IN THE LIBRARY EXPLAINS THIS",
}


def summary_lines(res: DiscrepancyResult) -> list[str]:
    """The headline: verdict, parameters with CIs, gap before/after."""
    sel = res.selection
    name = res.named or ""
    titles = ", ".join(t.title for t in sel.chosen.terms) if sel.chosen else ""
    head = VERDICT_TEXT[sel.verdict].format(name=f"{name} ({titles})")
    if sel.tie:
        head += f" -- TIE with {', '.join(sel.tie[1:])}: this run cannot tell them apart"
    out = [head]
    out += [f"  {r}" for r in sel.reasons]
    if res.refit is not None:
        out.append("fitted parameters (nonlinear refit, 95 % CI, autocorrelation-corrected):")
        for n, u, v, c in zip(
            res.refit.names, res.refit.units, res.refit.values, res.refit.ci95, strict=True
        ):
            out.append(f"  {n} = {v:.5g} +- {c:.2g}  [{u}]")
    b, a = res.systematic_gap_mm
    gb, ga, gf = res.tip_gap_mm
    out.append(
        f"tip gap (RMS of the tip error averaged over {GAP_WINDOW_S:g} s): {gb:.3f} mm ->"
        f" {ga:.3f} mm (shrink {100 * res.tip_gap_shrink:.1f} %); its tracker noise floor"
        f" {gf:.3f} mm"
    )
    out.append(
        f"tip RMS gap per sample: {res.tip_rms_before_mm:.3f} mm -> {res.tip_rms_after_mm:.3f} mm"
        f" (shrink {100 * res.gap_shrink:.1f} %); tracker noise floor"
        f" {res.tip_noise_floor_mm:.3f} mm; above the noise: {b:.3f} -> {a:.3f} mm"
        f" (shrink {100 * res.systematic_gap_shrink:.1f} %)"
    )
    for o in res.outcomes:
        if math.isfinite(o.tension_rms_before_N):
            out.append(
                f"  {o.name}: tension RMS gap {o.tension_rms_before_N:.3f} N ->"
                f" {o.tension_rms_after_N:.3f} N; tracker lag {1e3 * o.lag_s:.1f} ms"
            )
        else:
            out.append(f"  {o.name}: tracker lag {1e3 * o.lag_s:.1f} ms")
        if o.lag_suspect:
            out.append(f"  {o.name}: SUSPECT LAG: {o.lag_suspect}")
    return out


def text_report(res: DiscrepancyResult) -> str:
    """The whole text report (see module doc)."""
    sel = res.selection
    L = ["model-discrepancy report", "=" * 24, ""]
    L += summary_lines(res)
    L += ["", "runs:"]
    for r in res.runs:
        L.append(
            f"  {r.run_dir}: input {r.q_source}, noise sigma tip {r.sigma_tip_mm:.3f} mm,"
            f" tension {r.sigma_tension_N:.3f} N"
        )
    L += ["", "notes:"] + [f"  {n}" for n in res.notes]
    L += [
        "",
        f"model comparison (linearised fits; {sel.n_entries} residuals, effective sample size"
        f" {sel.n_eff:.0f}; held-out = blocked {len(sel.baseline.cv_fold_sse)}-fold CV):",
        f"  {'model':42s} {'params':>6s} {'held-out MS':>12s} {'fit MS':>9s} {'dAIC':>10s}"
        f" {'dBIC':>10s}",
    ]
    N = sel.n_entries
    a0, b0 = sel.baseline.aic, sel.baseline.bic
    for f in sorted(sel.fits, key=lambda f: f.cv_sse)[:20]:
        L.append(
            f"  {f.name:42s} {f.n_params:6d} {f.cv_sse / N:12.3f} {f.sse / N:9.3f}"
            f" {f.aic - a0:10.1f} {f.bic - b0:10.1f}"
        )
    L += ["", "candidate library:"]
    for t in res.terms:
        L.append(f"  {t.name}: {t.title}; signature: {t.signature} [{t.reference}]")
    for o in res.outcomes:
        L += ["", f"where the gap is ({o.name}, before the refit, tip RMS):"]
        for tab in o.tables:
            cells = ", ".join(
                f"{lab}: {v:.3f} ({n})" if math.isfinite(v) else f"{lab}: - ({n})"
                for lab, v, n in zip(tab.labels, tab.rms, tab.count, strict=True)
            )
            L.append(f"  {tab.title} [{tab.unit}]: {cells}")
    L += ["", f"{res.simulations} forward simulations, {res.elapsed_s:.1f} s", ""]
    return "\n".join(L)


def config_fragment(res: DiscrepancyResult, for_apply: bool = False) -> str:
    """YAML overlay for the rig config with the fitted effect (see module doc). ``for_apply``:
    a fitted value the controller cannot apply is an error, not a comment."""
    if res.refit is None:
        return "# nothing fitted: no effect was named\n{}\n"
    run = res.runs[0]
    cfg = run.cfg
    doc: dict = {}
    comments: list[str] = []
    from cdcr_ctl.discrepancy.selection import split_values

    parts = split_values(res.refit.terms, run.spec, res.refit.values)
    for term, vals in zip(res.refit.terms, parts, strict=True):
        for fv in term.fitted(run.spec, vals):
            put_fitted(doc, comments, fv, cfg, res, for_apply)
    head = [
        f"# Fitted by `cdcr-ctl discrepancy` ({res.named}); overlay on {cfg.name}'s rig config.",
    ]
    if res.refit is not None:
        head += [
            f"# {n} = {v:.5g} +- {c:.2g} (95 % CI) [{u}]"
            for n, u, v, c in zip(
                res.refit.names, res.refit.units, res.refit.values, res.refit.ci95, strict=True
            )
        ]
    head += [f"# {c}" for c in comments]
    # an overlay is a mapping even when every value went into comments
    body = yaml.safe_dump(doc, sort_keys=False)
    return "\n".join(head) + "\n" + body


def put_fitted(
    doc: dict, comments: list[str], fv, cfg, res: DiscrepancyResult | None, for_apply=True
) -> None:
    """Write one fitted value into the overlay ``doc`` under the rig-config key the controller's
    model reads (``res``: the result, for the tracker alignment only). Raises
    :class:`RigError` for a value with no key (a term that could be named but not applied)."""
    cables = {c.name: c for c in cfg.robot.cables}
    if fv.what == "cable":
        c = cables[fv.item]
        entry = {"name": fv.item}
        if fv.key == "EA_N":
            if c.E_MPa is not None:
                entry["E_MPa"] = round(float(fv.value) / (math.pi * c.diameter_mm**2 / 4), 3)
            else:
                entry["EA_N"] = round(float(fv.value), 3)
        else:
            entry[fv.key] = round(float(fv.value), 5)
        _merge_named(doc.setdefault("robot", {}).setdefault("cables", []), entry)
    elif fv.what == "pulley":
        _merge_named(
            doc.setdefault("robot", {}).setdefault("pulleys", []),
            {"name": fv.item, fv.key: round(float(fv.value), 5)},
        )
    elif fv.what == "segment":
        seg = next(s for s in cfg.robot.segments if s.name == fv.item)
        disks = seg.disks.model_dump()
        disks[fv.key.replace("disk_", "")] = round(float(fv.value), 4)
        _merge_named(
            doc.setdefault("robot", {}).setdefault("segments", []),
            {"name": fv.item, "disks": disks},
        )
    elif fv.what == "robot" and fv.key == "gravity_mm_s2":
        doc.setdefault("robot", {})["gravity_mm_s2"] = list(fv.value)  # type: ignore[arg-type]
    elif fv.what == "drive_of_cable":
        d = next(d for d in cfg.drives if d.cable == fv.item)
        _merge_named(
            doc.setdefault("drives", []),
            {"name": d.name, "counts_per_mm": round(d.counts_per_mm * float(fv.value), 4)},
        )
    elif fv.what == "tracker" and fv.key == "model_to_measured_rotvec_rad":
        pass
    elif fv.what == "tracker" and cfg.sensors.tracker is None:
        fix = _tracker_fix(res, cfg)["base_from_tracker"]
        comments.append(
            f"sensors.tracker.base_from_tracker = {fix} (the rig config has no tracker"
            " section: the logged tips were in the base frame; put it with the tracker)"
        )
    elif fv.what == "tracker":
        doc.setdefault("sensors", {})["tracker"] = _tracker_fix(res, cfg)
    elif fv.what == "model_effects":
        # the controller's model reads its switches and coupling gain here
        v = fv.value if isinstance(fv.value, bool) else round(float(fv.value), 4)
        me = doc.setdefault("control", {}).setdefault("model_effects", {})
        me[fv.key] = v
    elif fv.what == "robot" and fv.key in ("tip_payload_kg", "tip_force_N"):
        tl = doc.setdefault("robot", {}).setdefault("tip_load", {})
        if fv.key == "tip_payload_kg":
            tl["payload_kg"] = round(float(fv.value), 6)
        else:
            tl["force_N"] = [round(float(v), 5) for v in fv.value]  # type: ignore[union-attr]
    elif fv.what == "friction_law":
        # the disk friction's law, read by the compensation and the discrepancy model alike
        law = doc.setdefault("robot", {}).setdefault("friction_law", {})
        law[fv.key] = round(float(fv.value), 5)
    else:
        raise RigError(f"discrepancy: no rig-config key for {fv.what}.{fv.key}")


def _tracker_fix(res: DiscrepancyResult, cfg) -> dict:
    """base_from_tracker corrected by the fitted model -> measured map T: B_new = T^-1 B."""
    spec = res.refit.terms and _applied(res)
    R_t = rotation_from_rotvec(spec.tip_rotvec_rad)
    t_t = np.asarray(spec.tip_translation_mm)
    tr = cfg.sensors.tracker
    if tr is None:  # no tracker section: the logged tips were taken as base-frame points
        R_b, t_b = np.eye(3), np.zeros(3)
    else:
        R_b = rotation_from_rotvec(tr.base_from_tracker.rotvec_rad)
        t_b = np.asarray(tr.base_from_tracker.translation_mm)
    R_new = R_t.T @ R_b
    t_new = R_t.T @ (t_b - t_t)
    return {
        "base_from_tracker": {
            "rotvec_rad": [round(float(v), 6) for v in rotvec_from_rotation(R_new)],
            "translation_mm": [round(float(v), 4) for v in t_new],
        }
    }


def _applied(res: DiscrepancyResult):
    from cdcr_ctl.discrepancy.selection import apply_all

    return apply_all(res.refit.terms, res.runs[0].spec, res.refit.values)


def _merge_named(items: list, entry: dict) -> None:
    for it in items:
        if it["name"] == entry["name"]:
            it.update(entry)
            return
    items.append(entry)


def plots(res: DiscrepancyResult, out: Path) -> list[Path]:
    """The three figures (see module doc); returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    fig, axes = plt.subplots(
        len(res.outcomes), 1, figsize=(10, 3 * len(res.outcomes)), squeeze=False
    )
    for ax, o in zip(axes[:, 0], res.outcomes, strict=True):
        ax.plot(
            o.t_s, o.tip_err_before_mm, lw=0.7, label=f"before (RMS {o.tip_rms_before_mm:.3f} mm)"
        )
        ax.plot(o.t_s, o.tip_err_after_mm, lw=0.7, label=f"after (RMS {o.tip_rms_after_mm:.3f} mm)")
        ax.axhline(o.tip_noise_floor_mm, color="k", ls=":", lw=0.8, label="tracker noise floor")
        ax.set_ylabel("|tip error| (mm)")
        ax.set_title(o.name)
        ax.legend(fontsize=8)
    axes[-1, 0].set_xlabel("t (s)")
    fig.tight_layout()
    files.append(out / "residuals.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)

    o = res.outcomes[0]
    keep = [t for t in o.tables if t.unit == "mm"][1:]
    fig, axes = plt.subplots(1, len(keep), figsize=(4 * len(keep), 3.2), squeeze=False)
    for ax, tab in zip(axes[0], keep, strict=True):
        ax.bar(range(len(tab.labels)), np.nan_to_num(tab.rms))
        ax.set_xticks(range(len(tab.labels)), tab.labels, rotation=45, ha="right", fontsize=7)
        ax.set_title(tab.title, fontsize=9)
        ax.set_ylabel("tip RMS (mm)")
    fig.tight_layout()
    files.append(out / "localisation.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)

    sel = res.selection
    fits = sorted(sel.fits, key=lambda f: f.cv_sse)[:15]
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.barh(range(len(fits)), [f.cv_sse / sel.n_entries for f in fits])
    ax.axvline(sel.baseline.cv_sse / sel.n_entries, color="r", ls="--", label="baseline")
    ax.axvline(1.0, color="k", ls=":", label="noise")
    ax.set_yticks(range(len(fits)), [f.name for f in fits], fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("held-out mean square (noise variances)")
    ax.invert_yaxis()
    ax.legend(fontsize=8)
    fig.tight_layout()
    files.append(out / "candidates.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    return files


def write_report(res: DiscrepancyResult, out: str | Path, with_plots: bool = True) -> dict:
    """Write report.txt, fragment.yaml and the plots into ``out``; return the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"report": out / "report.txt", "fragment": out / "fragment.yaml"}
    paths["report"].write_text(text_report(res), encoding="utf-8")
    paths["fragment"].write_text(config_fragment(res), encoding="utf-8")
    if with_plots:
        for p in plots(res, out):
            paths[p.stem] = p
    return paths
