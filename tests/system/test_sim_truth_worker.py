"""The simulator's truth solved in a worker process (``cdcr-ctl sim``, :class:`SimRig`
``truth_worker``): the world its stand-in devices show is the truth at the drives' positions, as
when it is solved in the simulator's own process."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.cli.demo import make_session
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.rig import SimRig
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[2]


def test_the_worker_solves_the_world_at_the_drives_positions(tmp_path):
    # The shipped world on a session's free loopback ports and private paths: a user's
    # `cdcr-ctl sim` of the same world may hold the shipped ones.
    _, sim = make_session(ROOT / "config/sim/qi2023-truth.yaml", tmp_path, tmp_path)
    loaded = load_sim_config(sim)
    channel = f"truth-worker-{os.getpid()}"
    with SimRig(
        loaded, can_interface="virtual", can_channel=channel, link_paths=False, truth_worker=True
    ) as rig:
        end = time.monotonic() + 60  # the worker's interpreter and imports first
        while rig.counters.physics_steps < 5:
            assert time.monotonic() < end, rig.counters
            time.sleep(0.05)
        counts = rig.drives.actual_positions()
        steps = rig.truth.steps
        tip = np.asarray(rig.truth.tip_pose()[1], dtype=float)
        tensions = np.asarray(rig.truth.cell_tensions(), dtype=float)
        worker_cpu_s = rig._truth_proc.cpu_s if rig._truth_proc is not None else 0.0
    assert worker_cpu_s > 0  # the worker solved them
    assert steps >= 5  # the results came back into this process's truth
    ref = make_truth(loaded)
    for _ in range(steps):  # the same solves, in this process
        ref.step(counts)
    # One code, one machine, floats pickled exactly: only a solver's iteration count could
    # differ, and it stops at its tolerance, far below these (1 um, 1 mN).
    assert np.allclose(tip, np.asarray(ref.tip_pose()[1], dtype=float), rtol=0, atol=1e-3)
    assert np.allclose(tensions, np.asarray(ref.cell_tensions(), dtype=float), rtol=0, atol=1e-3)
