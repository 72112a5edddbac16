"""Fit-quality plots of an identification: residuals per kind, nominal vs fitted parameters.

One PNG per residual kind (tip mm, load-cell N, moment balance N mm, cable compatibility mm)
against the dwell index, with the nominal and the fitted parameters (poses and tensions of the
dwells re-estimated for each), and one of the fitted parameters relative to nominal with their
95 % intervals. Matplotlib object API on an Agg canvas (no pyplot, no display).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from cdcr_ctl.identify.estimator import RESIDUAL_KINDS, Identification

DPI = 110
_UNITS = {"tip": "mm", "cell": "N", "moment": "N mm", "compat": "mm"}
_TITLES = {
    "tip": "tracker tip - model tip",
    "cell": "model - load-cell tension",
    "moment": "moment balance (eq. 9-15)",
    "compat": "model - drive cable displacement (eq. 37)",
}


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    return path


def plot_identification(ident: Identification, out_dir: Path) -> dict[str, Path]:
    """Write ``residuals.png`` and ``parameters.png`` into ``out_dir``; returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=(12, 8), layout="constrained")
    fig.suptitle("Identification residuals per dwell: nominal vs fitted parameters")
    for n, kind in enumerate(RESIDUAL_KINDS, start=1):
        ax = fig.add_subplot(2, 2, n)
        for res, label, color in (
            (ident.residuals_before, "nominal", "tab:red"),
            (ident.residuals_after, "fitted", "tab:blue"),
        ):
            idx, val = res.get(kind, (np.array([]), np.array([])))
            if val.size:
                rms = float(np.sqrt(np.mean(val**2)))
                ax.plot(idx, val, ".", ms=3, color=color, label=f"{label} (RMS {rms:.3g})")
        ax.set_title(_TITLES[kind])
        ax.set_xlabel("dwell")
        ax.set_ylabel(_UNITS[kind])
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    out = {"residuals": _save(fig, out_dir / "residuals.png")}

    fig = Figure(figsize=(10, 4.5), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    names = [e.name for e in ident.estimates]
    rel = np.array([e.value / e.nominal if e.nominal else np.nan for e in ident.estimates])
    lo = np.array([e.ci95[0] / e.nominal if e.nominal else np.nan for e in ident.estimates])
    hi = np.array([e.ci95[1] / e.nominal if e.nominal else np.nan for e in ident.estimates])
    x = np.arange(len(names))
    ax.errorbar(x, rel, yerr=[rel - lo, hi - rel], fmt="o", capsize=4)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xticks(x, names, rotation=30, ha="right")
    ax.set_ylabel("fitted / nominal (95 % CI)")
    ax.set_title("Fitted parameters relative to the nominal config")
    ax.grid(True, alpha=0.3)
    out["parameters"] = _save(fig, out_dir / "parameters.png")
    return out
