"""PNG plots of a run log: tip path vs command, tip error, cable displacements, tensions, bends.

Drawn with matplotlib's object API on an Agg canvas: no pyplot, no display, no global backend
change. The commanded tip needs the design's forward kinematics, which this module does not
import: pass ``tip_from_psi``, a callable taking commanded (θ, φ) per segment, shape (N, S, 2) in
rad, and returning the tip in the robot base frame, shape (N, 3) in mm.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from cdcr_ctl.runlog.columns import (
    GROUP_PSI_CMD,
    GROUP_Q_ACT,
    GROUP_Q_CMD,
    GROUP_Q_NOMINAL,
    GROUP_TENSION,
    GROUP_TIP,
)
from cdcr_ctl.runlog.reader import Run

log = logging.getLogger(__name__)

TipFromPsi = Callable[[np.ndarray], np.ndarray]

#: Points per curve above which a run is decimated (every n-th cycle) for plotting.
MAX_POINTS = 20_000
DPI = 110


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    return path


def _any_finite(a: np.ndarray) -> bool:
    return bool(np.isfinite(a).any())


def plot_run(
    run: Run,
    out_dir: str | Path | None = None,
    tip_from_psi: TipFromPsi | None = None,
    max_points: int = MAX_POINTS,
) -> dict[str, Path]:
    """Write the PNGs of ``run`` into ``out_dir`` (default ``<run_dir>/plots``).

    Returns ``{name: path}`` for the plots drawn: ``tip_path`` (tracked and/or commanded tip: 3D
    and the xz, yz, xy projections), ``tip_error`` (needs both), ``cables`` (nominal, command,
    actual per cable), ``tensions``, ``bend`` (θ, φ commands per segment). A plot whose data the
    log lacks is skipped (logged at INFO).
    """
    out = Path(out_dir) if out_dir is not None else run.run_dir / "plots"
    out.mkdir(parents=True, exist_ok=True)
    n = len(run)
    step = max(1, math.ceil(n / max_points)) if n else 1
    sel = slice(None, None, step)
    t = run.t_s[sel]
    title = _title(run)
    written: dict[str, Path] = {}

    tip_meas = run.tip()[sel] if run.has(GROUP_TIP) else None
    if tip_meas is not None and not _any_finite(tip_meas):
        tip_meas = None
    tip_cmd = None
    if tip_from_psi is not None and run.has(GROUP_PSI_CMD) and n:
        tip_cmd = np.asarray(tip_from_psi(run.psi_cmd()[sel]), dtype=float)
        if tip_cmd.shape != (len(t), 3):
            raise ValueError(f"tip_from_psi returned shape {tip_cmd.shape}, expected ({len(t)}, 3)")

    if tip_meas is not None or tip_cmd is not None:
        written["tip_path"] = _save(_tip_path(tip_meas, tip_cmd, title), out / "tip_path.png")
    else:
        log.info("%s: no tip data and no forward kinematics: tip_path skipped", run.run_dir)
    if tip_meas is not None and tip_cmd is not None:
        written["tip_error"] = _save(_tip_error(t, tip_meas, tip_cmd, title), out / "tip_error.png")
    else:
        log.info("%s: tip_error needs tracked and commanded tip: skipped", run.run_dir)

    cable_groups = [g for g in (GROUP_Q_NOMINAL, GROUP_Q_CMD, GROUP_Q_ACT) if run.has(g)]
    if cable_groups and run.n_cables:
        written["cables"] = _save(_cables(run, t, sel, cable_groups, title), out / "cables.png")
    if run.has(GROUP_TENSION) and _any_finite(run.tension()):
        written["tensions"] = _save(_tensions(t, run.tension()[sel], title), out / "tensions.png")
    else:
        log.info("%s: no tensions logged: tensions skipped", run.run_dir)
    if run.has(GROUP_PSI_CMD) and run.n_segments:
        written["bend"] = _save(_bend(run, t, sel, title), out / "bend.png")
    return written


def _title(run: Run) -> str:
    m = run.metadata
    parts = [str(m.get("name") or run.run_dir.name)]
    if m.get("rig"):
        parts.append(f"rig {m['rig']}")
    if m.get("compensation"):
        parts.append(f"compensation {m['compensation']}")
    ended = run.ended
    if ended:
        parts.append(f"{ended.get('outcome')}")
    return ", ".join(parts)


_PROJ = (("x", "z", 0, 2), ("y", "z", 1, 2), ("x", "y", 0, 1))


def _tip_path(meas: np.ndarray | None, cmd: np.ndarray | None, title: str) -> Figure:
    fig = Figure(figsize=(11, 9), layout="constrained")
    fig.suptitle(f"Tip path, robot base frame — {title}")
    ax3 = fig.add_subplot(2, 2, 1, projection="3d")
    curves = [(cmd, "commanded (FK)", "--", "tab:blue"), (meas, "tracked", "-", "tab:red")]
    for data, label, ls, color in curves:
        if data is not None:
            ax3.plot(data[:, 0], data[:, 1], data[:, 2], ls, color=color, label=label, lw=1.2)
    ax3.set_xlabel("x (mm)")
    ax3.set_ylabel("y (mm)")
    ax3.set_zlabel("z (mm)")
    _cube(ax3, [c[0] for c in curves if c[0] is not None])
    ax3.legend(loc="upper left", fontsize="small")
    for k, (a, b, ia, ib) in enumerate(_PROJ, start=2):
        ax = fig.add_subplot(2, 2, k)
        for data, label, ls, color in curves:
            if data is not None:
                ax.plot(data[:, ia], data[:, ib], ls, color=color, label=label, lw=1.2)
        ax.set_xlabel(f"{a} (mm)")
        ax.set_ylabel(f"{b} (mm)")
        ax.set_title(f"{a}{b} projection")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    return fig


def _cube(ax: Any, data: list[np.ndarray]) -> None:
    """Equal scales on a 3D axes: a cube around the finite points, at least 2 mm wide."""
    pts = np.concatenate(data)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):
        return
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1.0)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_box_aspect((1, 1, 1))


def _tip_error(t: np.ndarray, meas: np.ndarray, cmd: np.ndarray, title: str) -> Figure:
    err = meas - cmd
    norm = np.linalg.norm(err, axis=1)
    fig = Figure(figsize=(10, 6), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    finite = np.isfinite(norm)
    stats = ""
    if finite.any():
        stats = f"mean {np.mean(norm[finite]):.2f} mm, max {np.max(norm[finite]):.2f} mm"
    ax1.plot(t, norm, color="black", lw=1.0)
    ax1.set_ylabel("|tracked − commanded| (mm)")
    ax1.set_title(f"Tip error — {title}\n{stats}")
    ax1.grid(True, alpha=0.3)
    colors = ("tab:red", "tab:green", "tab:blue")
    for j, (axis, color) in enumerate(zip("xyz", colors, strict=True)):
        ax2.plot(t, err[:, j], color=color, lw=1.0, label=f"e_{axis}")
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("error (mm)")
    ax2.legend(loc="best", fontsize="small")
    ax2.grid(True, alpha=0.3)
    return fig


def _cables(run: Run, t: np.ndarray, sel: slice, groups: list[str], title: str) -> Figure:
    K = run.n_cables
    fig = Figure(figsize=(10, 2.2 * K + 1), layout="constrained")
    axes = np.atleast_1d(fig.subplots(K, 1, sharex=True))
    fig.suptitle(f"Cable displacements — {title}")
    style = {
        GROUP_Q_NOMINAL: ("nominal (IK)", ":", "tab:gray"),
        GROUP_Q_CMD: ("command (sent)", "-", "tab:blue"),
        GROUP_Q_ACT: ("actual (drive)", "--", "tab:orange"),
    }
    series = {
        GROUP_Q_NOMINAL: run.q_nominal,
        GROUP_Q_CMD: run.q_cmd,
        GROUP_Q_ACT: run.q_act,
    }
    arrays = {g: series[g]()[sel] for g in groups}
    for k, ax in enumerate(axes):
        for g in groups:
            label, ls, color = style[g]
            ax.plot(t, arrays[g][:, k], ls, color=color, lw=1.1, label=label)
        ax.set_ylabel(f"cable {k + 1} q (mm)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("t (s)")
    return fig


def _tensions(t: np.ndarray, tension: np.ndarray, title: str) -> Figure:
    fig = Figure(figsize=(10, 4.5), layout="constrained")
    ax = fig.subplots()
    for k in range(tension.shape[1]):
        if _any_finite(tension[:, k]):
            ax.plot(t, tension[:, k], lw=1.0, label=f"cable {k + 1}")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("tension (N)")
    ax.set_title(f"Cable tensions (load cells) — {title}")
    ax.legend(loc="best", fontsize="small")
    ax.grid(True, alpha=0.3)
    return fig


def _bend(run: Run, t: np.ndarray, sel: slice, title: str) -> Figure:
    S = run.n_segments
    theta, phi = run.theta_cmd()[sel], run.phi_cmd()[sel]
    fig = Figure(figsize=(10, 5), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ax1.set_title(f"Segment bends — {title}")
    for i in range(S):
        line = ax1.plot(t, np.degrees(theta[:, i]), lw=1.1, label=f"seg {i + 1} θ cmd")[0]
        est = run.data.get(f"seg{i + 1}_theta_est_rad")
        if est is not None and est.dtype != object:
            ax1.plot(
                t,
                np.degrees(est[sel]),
                "--",
                color=line.get_color(),
                lw=1.0,
                label=f"seg {i + 1} θ est",
            )
        ax2.plot(t, np.degrees(phi[:, i]), lw=1.1, color=line.get_color(), label=f"seg {i + 1} φ")
    ax1.set_ylabel("θ (deg)")
    ax2.set_ylabel("φ (deg)")
    ax2.set_xlabel("t (s)")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    return fig
