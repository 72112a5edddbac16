"""Tip-error analysis of logged runs: how far the tracked tip was from the commanded one.

The commanded tip is the forward kinematics of the logged commanded (theta, phi) per segment, with
the geometry of the config the run was made with (its validated copy in the run directory).
This is the error measure of Qi et al. 2023 section 5 (mean position error of the tip).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from cdcr_ctl.config.loader import validate_mapping
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.reader import Run, load_run
from cdcr_ctl.runlog.writer import EFFECTIVE_CONFIG_YAML as EFFECTIVE_CONFIG


def run_config(run: Run) -> RigConfig:
    """The validated rig config a run was made with (from its run directory)."""
    path = run.run_dir / EFFECTIVE_CONFIG
    if not path.exists():
        raise RigError(f"{run.run_dir}: no {EFFECTIVE_CONFIG}; cannot know the rig's geometry")
    return validate_mapping(yaml.safe_load(path.read_text()), RigConfig, str(path))


def tip_from_psi_for_run(run: Run) -> Callable[[np.ndarray], np.ndarray]:
    """Commanded-tip function (N, S, 2) rad -> (N, 3) mm for the run's rig design."""
    from cdcr_ctl.config.build_model import build_model

    model = build_model(run_config(run), source=str(run.run_dir / EFFECTIVE_CONFIG))

    def tips(psi: np.ndarray) -> np.ndarray:
        psi = np.asarray(psi, dtype=float)
        return np.array([model.tip(p) for p in psi.reshape(len(psi), -1, 2)])

    return tips


@dataclass(frozen=True)
class TipErrors:
    """Per-sample tip error (mm) of one run, NaN where the tracker had no sample."""

    run_dir: Path
    t_s: np.ndarray
    error_mm: np.ndarray
    compensation: str

    def summary(self) -> dict[str, float | int | str]:
        ok = np.isfinite(self.error_mm)
        e = self.error_mm[ok]
        return {
            "run": self.run_dir.name,
            "compensation": self.compensation,
            "samples": int(ok.sum()),
            "mean_mm": float(np.mean(e)) if e.size else float("nan"),
            "rms_mm": float(np.sqrt(np.mean(e**2))) if e.size else float("nan"),
            "max_mm": float(np.max(e)) if e.size else float("nan"),
        }


def tip_errors(run_dir: str | Path, settle_s: float = 0.0) -> TipErrors:
    """Tip error of every logged sample after ``settle_s`` from the start (s)."""
    run = load_run(run_dir)
    if not run.has("tip"):
        raise RigError(f"{run.samples_path}: no tracker columns; no tip error to compute")
    tips = tip_from_psi_for_run(run)(run.psi_cmd())
    err = np.linalg.norm(run.tip() - tips, axis=1)
    keep = run.t_s >= run.t_s[0] + settle_s
    comp = str(run.metadata.get("compensation", ""))
    return TipErrors(run.run_dir, run.t_s[keep], err[keep], comp)
