"""System: the lock-step simulated rig (cdcr_ctl.sim.lockstep) - the production loop, drive
layer, Modbus reader and NatNet parser on simulated time: same seed, same logs; the same
trajectory as in real time."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from syshelp import TRUTH

from cdcr_ctl.analysis import tip_errors
from cdcr_ctl.config import load_rig_config
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.sim.lockstep.session import LockstepSession
from cdcr_ctl.sim.simconfig import load_sim_config

#: A short bend (0 -> 40 deg at 0.5 rad/s, ~1.4 s simulated) and back, with compensation.
BEND = tj.planar_bend(theta_max_rad=math.radians(40), rate_rad_s=0.5)


def _run(tmp_path, tag: str, comp: str = "model"):
    loaded = load_sim_config(TRUTH)
    ctl = load_rig_config(loaded.rig_path)
    with LockstepSession.open(loaded, ctl, loaded.rig_path, tmp_path / tag) as s:
        run = s.run(BEND, f"bend-{comp}", comp)
        clock = s.rig.clock
        return run, clock.cycles, s.rig.truth_steps, s.rig.tracker.frames


@pytest.mark.multicore
@pytest.mark.timeout(300)
def test_two_lockstep_runs_with_one_seed_give_byte_identical_samples(tmp_path):
    run_a, cycles_a, truth_a, frames_a = _run(tmp_path, "a")
    run_b, cycles_b, truth_b, frames_b = _run(tmp_path, "b")
    assert run_a.state == run_b.state == "completed"
    a = (tmp_path / "a" / run_a.log_dir.split("/")[-1] / "samples.csv").read_bytes()
    b = (tmp_path / "b" / run_b.log_dir.split("/")[-1] / "samples.csv").read_bytes()
    assert len(a) > 10_000
    assert a == b  # the subject: simulated time and seeded noise, not a tolerance
    assert (cycles_a, truth_a, frames_a) == (cycles_b, truth_b, frames_b)
    rows = list(csv.DictReader(a.decode().splitlines()))
    t = np.array([float(r["t_s"]) for r in rows])
    # One SYNC period per cycle of simulated time, never late; tracker at its 120 Hz; tensions.
    np.testing.assert_allclose(np.diff(t), 0.004, atol=1.5e-6)  # t_s is rounded to 1 us
    assert {r["lateness_us"] for r in rows} == {"0.0"}
    assert all(r["tip_x_mm"] and r["cable1_tension_N"] for r in rows)
    assert 110 < frames_a / (cycles_a * 0.004) < 135  # 120 Hz over the session (+ priming)
    summ = tip_errors(run_a.log_dir, settle_s=0.0).summary()
    assert summ["mean_mm"] < 3.0 and summ["samples"] == len(rows)


def test_truth_states_cross_the_worker_pipe_exactly():
    """The truth worker sends solved states as nested float lists (sim/lockstep/truthproc.py):
    rebuilt, every array is the same class, shape, dtype and bits; other states pass as they
    are."""
    import pickle
    from dataclasses import fields

    from cdcr_ctl.sim.design_truth import make_truth
    from cdcr_ctl.sim.lockstep.truthproc import from_wire, to_wire

    truth = make_truth(load_sim_config(TRUTH))
    state = truth.step([1234, -800, -600])
    back = from_wire(pickle.loads(pickle.dumps(to_wire(state))), truth.state)
    assert type(back) is type(state)
    for f in fields(state):
        a, b = getattr(state, f.name), getattr(back, f.name)
        assert (a.shape, a.dtype, a.tobytes()) == (b.shape, b.dtype, b.tobytes()), f.name
    other = {"not": "a dataclass of arrays"}
    assert to_wire(other) is other and from_wire(other, truth.state) is other
