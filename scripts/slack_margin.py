#!/usr/bin/env python3
"""Least cable tension of the experiments' trajectories on a simulated world, compensation off.

Replays the planar bend (0 -> 90 -> 0 deg) and the circle at 45 deg of ``cdcr-ctl experiments``
through a world's quasi-static truth (the simulator's own :class:`~cdcr_ctl.sim.truth.
TruthModel`: its parameters, lost motion, mount and friction law) with the commands the
nominal controller sends in mode ``off`` (the bare geometry), and prints each cable's least
tension at the robot base and where it occurs. A world whose uncompensated run drops a cable
below the rig's slack limit (``limits.tension_N[0]``) cannot give the ``off`` row of the table:
the supervisor holds it, as it must. No noise, no dynamics: the margin against the limit must
cover the load-cell noise (0.02 N per sample) on top of this.

Usage::

    .venv/bin/python scripts/slack_margin.py [config/sim/qi2023-truth.yaml] [--step-s 0.05]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdcr_ctl.config.build_model import build_model  # noqa: E402
from cdcr_ctl.control import trajectory as tj  # noqa: E402
from cdcr_ctl.sim.simconfig import load_sim_config  # noqa: E402
from cdcr_ctl.sim.truth import TruthModel  # noqa: E402


def least_tensions(sim_yaml: Path, step_s: float) -> dict[str, list[tuple[float, float, float]]]:
    """Per trajectory, per cable: (least tension N, at time s, at phi rad)."""
    loaded = load_sim_config(sim_yaml)
    truth = TruthModel(loaded)
    model = build_model(loaded.rig)
    trajs = {
        "planar_bend": tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10),
        "circle": tj.spatial_circle(theta_rad=math.pi / 4, phi_rate_rad_s=math.pi / 10),
    }
    out: dict[str, list[tuple[float, float, float]]] = {}
    for name, traj in trajs.items():
        stepper = type(truth.stepper)(truth.params, truth.effects)
        state = model.new_state()
        best = [(math.inf, 0.0, 0.0)] * model.n_cables
        for t in np.arange(0.0, traj.duration_s + step_s, step_s):
            psi = traj.sample(min(float(t), traj.duration_s))
            q = model.q_command(psi, model.q_nominal(psi), state, "off", None)
            T = stepper.step(q).tension_at("robot_base")
            best = [
                (float(T[k]), float(t), float(psi[0, 1])) if T[k] < best[k][0] else best[k]
                for k in range(model.n_cables)
            ]
        out[name] = best
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sim", nargs="?", type=Path, default=ROOT / "config/sim/qi2023-truth.yaml")
    ap.add_argument("--step-s", type=float, default=0.05)
    args = ap.parse_args()
    limit = load_sim_config(args.sim).rig.limits.tension_N[0]
    for name, per_cable in least_tensions(args.sim, args.step_s).items():
        cells = ", ".join(
            f"c{k + 1} {T:.3f} N (t {t:.1f} s, phi {math.degrees(ph):.0f} deg)"
            for k, (T, t, ph) in enumerate(per_cable)
        )
        worst = min(T for T, _, _ in per_cable)
        verdict = "above" if worst > limit else "BELOW"
        print(f"{name:12s} least tension, off: {cells}; {verdict} the {limit} N slack limit")


if __name__ == "__main__":
    main()
