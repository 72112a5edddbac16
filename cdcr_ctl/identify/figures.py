"""Result table and figures of the compensation experiments (after Qi et al. 2023 Fig. 12-13).

Each row of the experiments is one logged run (an experiment with one compensation mode):
``{"experiment", "compensation", "mode", "params", "mean_mm", "max_mm", "log_dir", ...}``. The
tip error of a sample is |tracked tip - FK(commanded pose)| (mm, robot base frame), the paper's
measure (:func:`cdcr_ctl.analysis.tip_errors`). The reduction of a mode is
100 (1 - mean / mean of ``off``) %, against the ``off`` run of the same experiment.

Figures (PNG, matplotlib object API, Agg canvas): per experiment, the tip path commanded and
tracked for every mode (the planar bend in the xz plane like Fig. 12b, the circle in 3D and xy
like Fig. 13a-b) and the tip error over time per mode (Fig. 12c, 13c).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

DPI = 110
_COLORS = {"off": "tab:red", "model": "tab:green", "measured": "tab:purple"}


def reductions(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` with ``reduction_pct`` (mean tip error vs the experiment's ``off`` row)."""
    base = {r["experiment"]: r["mean_mm"] for r in rows if r["mode"] == "off"}
    out = []
    for r in rows:
        b = base.get(r["experiment"])
        red = (
            100.0 * (1.0 - r["mean_mm"] / b)
            if r["mode"] != "off" and b and math.isfinite(b)
            else math.nan
        )
        out.append({**r, "reduction_pct": red})
    return out


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown table: experiment, compensation, mean and max tip error, reduction vs off."""
    lines = [
        "| experiment | compensation | mean tip error (mm) | max (mm) | mean reduction vs off |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in reductions(rows):
        red = "" if math.isnan(r["reduction_pct"]) else f"{r['reduction_pct']:.1f} %"
        state = "" if r.get("state", "completed") == "completed" else f" ({r['state']})"
        lines.append(
            f"| {r['experiment']} | {r['compensation']}{state} | {r['mean_mm']:.3f}"
            f" | {r['max_mm']:.3f} | {red} |"
        )
    return "\n".join(lines) + "\n"


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    return path


def _load(log_dir: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_s, tracked tip (N, 3), commanded tip (N, 3)) of one run."""
    from cdcr_ctl.analysis import tip_from_psi_for_run
    from cdcr_ctl.runlog.reader import load_run

    run = load_run(log_dir)
    cmd = tip_from_psi_for_run(run)(run.psi_cmd())
    return run.t_s - run.t_s[0], run.tip(), cmd


def plot_experiments(rows: Sequence[dict[str, Any]], out_dir: Path) -> dict[str, Path]:
    """One figure per experiment (paths and errors of every mode); returns {name: path}."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    for exp in dict.fromkeys(r["experiment"] for r in rows):
        runs = [r for r in reductions(rows) if r["experiment"] == exp]
        data = {r["compensation"]: (r, *_load(r["log_dir"])) for r in runs}
        planar = exp.startswith("planar")
        fig = Figure(figsize=(13, 5.2), layout="constrained")
        fig.suptitle(
            f"{exp}: tip path and error per compensation mode (after Qi et al. 2023 "
            f"Fig. {12 if planar else 13})"
        )
        if planar:
            ax_p = fig.add_subplot(1, 2, 1)
            ia, ib, la, lb = 0, 2, "x", "z"
        else:
            ax_p = fig.add_subplot(1, 2, 1, projection="3d")
        ax_e = fig.add_subplot(1, 2, 2)
        first = True
        for label, (r, t, tip, cmd) in data.items():
            color = _COLORS.get(r["mode"]) if r["params"] == "identified" else "tab:orange"
            if first:
                if planar:
                    ax_p.plot(cmd[:, ia], cmd[:, ib], "k--", lw=1.5, label="desired")
                else:
                    ax_p.plot(cmd[:, 0], cmd[:, 1], cmd[:, 2], "k--", lw=1.5, label="desired")
                first = False
            if planar:
                ax_p.plot(tip[:, ia], tip[:, ib], "-", color=color, lw=1.0, label=label)
            else:
                ax_p.plot(tip[:, 0], tip[:, 1], tip[:, 2], "-", color=color, lw=1.0, label=label)
            err = np.linalg.norm(tip - cmd, axis=1)
            red = "" if math.isnan(r["reduction_pct"]) else f", {r['reduction_pct']:.0f} % less"
            ax_e.plot(
                t, err, "-", color=color, lw=1.0, label=f"{label}: mean {r['mean_mm']:.2f} mm{red}"
            )
        if planar:
            ax_p.set_xlabel(f"{la} (mm)")
            ax_p.set_ylabel(f"{lb} (mm)")
            ax_p.set_aspect("equal", adjustable="datalim")
            ax_p.grid(True, alpha=0.3)
            ax_p.set_title("tip path in the oxz plane")
        else:
            ax_p.set_xlabel("x (mm)")
            ax_p.set_ylabel("y (mm)")
            ax_p.set_zlabel("z (mm)")
            ax_p.set_title("tip path")
        ax_p.legend(fontsize="small")
        ax_e.set_xlabel("t (s)")
        ax_e.set_ylabel("tip position error (mm)")
        ax_e.set_title("|tracked - desired tip|")
        ax_e.grid(True, alpha=0.3)
        ax_e.legend(fontsize="small")
        written[exp] = _save(fig, out_dir / f"{exp}.png")
    return written
