#!/usr/bin/env python3
"""Per-cycle cost of the vertebra model (daemon side) and of its simulated truth (sim side).

What is measured, per cycle, along a smooth 300-cycle path of the three joints (0 -> about
1 rad, directions turning), as the control loop and the simulator call them:

- model: ``q_nominal(psi)`` + ``q_command(psi, q_nom, state, "model")`` (sag compensation: one
  warm-started statics solve per cycle) + ``tip(psi)`` of the rig's VertebraModel
  (config/vertebra-sim.yaml, built by ``build_model``);
- truth: one ``VertebraTruth.step(counts)`` of the simulator (config/sim/vertebra-truth.yaml):
  kinematic inverse of eq. 5, statics with gravity sag, joint-end frames.

How: CPU time of this process (``time.process_time``), best of 5 repetitions of the 300 cycles,
so other processes on a shared machine inflate it less than wall time would (they still share
caches and cores); the wall time of the best repetition is printed too.

    nice .venv/bin/python benchmarks/bench_vertebra_model.py
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]
N_CYCLES = 300
REPEATS = 5


def best_of(fn) -> tuple[float, float]:
    """(CPU s, wall s) of the fastest of REPEATS calls of ``fn``."""
    best = (math.inf, math.inf)
    for _ in range(REPEATS):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        best = min(best, (time.process_time() - c0, time.perf_counter() - w0))
    return best


def main() -> None:
    cfg = load_rig_config(ROOT / "config" / "vertebra-sim.yaml")
    model = build_model(cfg)
    path = [
        np.array([[0.9 * s, 0.6], [0.7 * s, 0.6 + s], [1.0 * s, -0.5]])
        for s in np.linspace(0.0, 1.0, N_CYCLES)
    ]

    def run_model() -> None:
        state = model.new_state()
        for psi in path:
            q_nom = model.q_nominal(psi)
            model.q_command(psi, q_nom, state, "model", None)
            model.tip(psi)

    loaded = load_sim_config(ROOT / "config" / "sim" / "vertebra-truth.yaml")
    cpm = np.array([d.counts_per_mm for d in loaded.rig.drives])
    counts = [np.rint(model.q_nominal(p) * cpm).astype(np.int64) for p in path]

    def run_truth() -> None:
        truth = make_truth(loaded)
        for c in counts:
            truth.step(c)

    for name, fn in (
        ("model q_nominal + q_command(model) + tip", run_model),
        ("truth step (VertebraTruth.step)", run_truth),
    ):
        cpu, wall = best_of(fn)
        print(
            f"{name}: {cpu / N_CYCLES * 1e3:.3f} ms CPU per cycle"
            f" ({wall / N_CYCLES * 1e3:.3f} ms wall; best of {REPEATS} x {N_CYCLES} cycles)"
        )


if __name__ == "__main__":
    main()
