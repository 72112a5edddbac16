"""Run plots: every PNG is written from a full log, and a partial log only skips what it lacks."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.control.trajectory import planar_bend
from cdcr_ctl.runlog import RunLogWriter, RunMetadata, load_run, sample_columns
from cdcr_ctl.runlog.plots import plot_run

L_MM = 90.0
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def cc_tip(psi: np.ndarray) -> np.ndarray:
    """Tip of one constant-curvature segment of length L (mm) for (N, 1, 2) (θ, φ), base frame:
    p = L/θ (1 - cos θ) (cos φ, sin φ), L sin θ / θ (straight: (0, 0, L))."""
    th, ph = psi[:, 0, 0], psi[:, 0, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(th > 1e-9, L_MM * (1 - np.cos(th)) / th, L_MM * th / 2)
        z = np.where(th > 1e-9, L_MM * np.sin(th) / th, L_MM)
    return np.column_stack((r * np.cos(ph), r * np.sin(ph), z))


def write_run(tmp_path, with_tip=True, with_tension=True):
    traj = planar_bend()
    t = np.arange(0.0, traj.duration_s, 0.002)
    psi = traj.sample_many(t)
    tip = cc_tip(psi)
    rng = np.random.default_rng(3)
    cols = sample_columns(1, 3, ("cycle",))
    w = RunLogWriter(
        tmp_path / "run", cols, RunMetadata(name="planar", rig="bench", compensation="model")
    )
    gam = np.array([0.0, 2 * math.pi / 3, 4 * math.pi / 3])
    for n, ti in enumerate(t):
        th, ph = psi[n, 0]
        q_nom = 2.5 * th * np.cos(ph - gam)
        row = {"t_s": ti, "cycle": n, "seg1_theta_cmd_rad": th, "seg1_phi_cmd_rad": ph}
        for k in range(3):
            row[f"cable{k + 1}_q_nominal_mm"] = q_nom[k]
            row[f"cable{k + 1}_q_cmd_mm"] = q_nom[k] * 1.05
            row[f"cable{k + 1}_q_act_mm"] = q_nom[k] * 1.05 - 0.01
            if with_tension:
                row[f"cable{k + 1}_tension_N"] = 5 + 3 * th * math.cos(ph - gam[k])
        if with_tip and n % 4:  # the tracker misses some frames: empty fields
            sag = 1.0 + 2.0 * th
            row["tip_x_mm"], row["tip_y_mm"] = tip[n, 0] - sag, tip[n, 1] + rng.normal(0, 0.2)
            row["tip_z_mm"] = tip[n, 2] - sag
        w.write(row)
    w.close("trajectory completed", outcome="completed")
    return load_run(w.run_dir)


def test_full_run_writes_every_plot(tmp_path):
    run = write_run(tmp_path)
    out = plot_run(run, tmp_path / "plots", tip_from_psi=cc_tip)
    assert set(out) == {"tip_path", "tip_error", "cables", "tensions", "bend"}
    for path in out.values():
        data = path.read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 20_000


def test_partial_run_skips_what_it_lacks(tmp_path):
    run = write_run(tmp_path, with_tip=False, with_tension=False)
    assert run.has("tip") and np.isnan(run.tip()).all()  # columns exist, every field empty
    out = plot_run(run, tip_from_psi=None, max_points=500)
    assert set(out) == {"cables", "bend"}
    assert all(p.parent == run.run_dir / "plots" for p in out.values())
    out = plot_run(run, tmp_path / "p2", tip_from_psi=cc_tip)
    assert set(out) == {"tip_path", "cables", "bend"}  # commanded tip only; no error without data


def test_tip_from_psi_shape_is_checked(tmp_path):
    run = write_run(tmp_path, with_tension=False)
    with pytest.raises(ValueError, match="expected"):
        plot_run(run, tmp_path / "p", tip_from_psi=lambda psi: psi[:, 0, :])


def test_plot_command_says_where_it_wrote(tmp_path, capsys):
    import yaml

    from cdcr_ctl.cli.main import main
    from cdcr_ctl.config import load_rig_config

    run = write_run(tmp_path, with_tip=False, with_tension=False)
    rig = load_rig_config(Path(__file__).resolve().parents[2] / "config" / "qi2023.yaml")
    (run.run_dir / "config_effective.yaml").write_text(yaml.safe_dump(rig.model_dump(mode="json")))
    assert main(["plot", str(run.run_dir)]) == 0
    lines = capsys.readouterr().out.splitlines()
    where = (run.run_dir / "plots").resolve()
    assert lines[0] == f"{len(lines) - 1} plot(s) in {where}" and len(lines) > 1
    assert all(Path(p.strip()).parent == where and Path(p.strip()).is_file() for p in lines[1:])
    assert main(["plot", str(run.run_dir), "--out", str(tmp_path / "o"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["out_dir"] == str((tmp_path / "o").resolve())
    assert set(out["plots"]) == {"tip_path", "cables", "bend"}  # commanded tip from the config
