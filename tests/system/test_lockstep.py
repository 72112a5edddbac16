"""System: the lock-step simulated rig (cdcr_ctl.sim.lockstep) - the production loop, drive
layer, Modbus reader and NatNet parser on simulated time: same seed, same logs; the same
trajectory as in real time."""

from __future__ import annotations

import csv
import math
import os

import numpy as np
import pytest
from syshelp import TRUTH

from cdcr_ctl.analysis import tip_errors
from cdcr_ctl.config import load_rig_config
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.sim.lockstep.placement import Placement, allowed_cpus
from cdcr_ctl.sim.lockstep.session import LockstepSession
from cdcr_ctl.sim.simconfig import load_sim_config

#: A short bend (0 -> 40 deg at 0.5 rad/s, ~1.4 s simulated) and back, with compensation.
BEND = tj.planar_bend(theta_max_rad=math.radians(40), rate_rad_s=0.5)


def _run(tmp_path, tag: str, comp: str = "model", placement: Placement | None = None):
    loaded = load_sim_config(TRUTH)
    ctl = load_rig_config(loaded.rig_path)
    with LockstepSession.open(loaded, ctl, loaded.rig_path, tmp_path / tag, True, placement) as s:
        run = s.run(BEND, f"bend-{comp}", comp)
        clock = s.rig.clock
        p = s.rig.placement
        if p.loop_cpu is not None:
            # Pinned where the placement says: the loop thread and the truth worker.
            assert os.sched_getaffinity(s.loop._thread.native_id) == {p.loop_cpu}
            assert os.sched_getaffinity(s.rig.truth_proc.pid) == {p.worker_cpu}
        return run, clock.cycles, s.rig.truth_steps, s.rig.tracker.frames


@pytest.mark.multicore
@pytest.mark.timeout(300)
def test_two_lockstep_runs_with_one_seed_give_byte_identical_samples(tmp_path):
    # The first pinned as by default (loop thread and truth worker on CPUs of their own where
    # there are two), the second not pinned: where the work runs changes nothing it computes.
    run_a, cycles_a, truth_a, frames_a = _run(tmp_path, "a")
    run_b, cycles_b, truth_b, frames_b = _run(tmp_path, "b", placement=Placement())
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
    """A state that cannot go through shared memory crosses the truth worker's pipe as nested
    float lists (sim/lockstep/truthproc.py): rebuilt, every array is the same class, shape,
    dtype and bits; other states pass as they are."""
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


def test_truth_states_cross_shared_memory_exactly():
    """The truth worker's solved state crosses in shared memory (sim/lockstep/truthproc.py):
    rebuilt, every array is the same class, shape, dtype and bits; a state of other shapes
    is refused by name."""
    import multiprocessing
    from dataclasses import fields, replace

    from cdcr_ctl.errors import RigError
    from cdcr_ctl.sim.design_truth import make_truth
    from cdcr_ctl.sim.lockstep.truthproc import _Shared, state_shapes

    truth = make_truth(load_sim_config(TRUTH))
    state = truth.step([1234, -800, -600])
    shapes = state_shapes(state)
    assert shapes is not None and state_shapes({"not": "a dataclass"}) is None
    n = sum(int(np.prod(s)) for s in shapes)
    ctx = multiprocessing.get_context("spawn")
    sh = _Shared(ctx.RawArray("q", 6), ctx.RawArray("d", 1 + n), shapes)
    sh.put_state(state)
    back = sh.get_state(truth.state)
    assert type(back) is type(state)
    for f in fields(state):
        a, b = getattr(state, f.name), getattr(back, f.name)
        assert (a.shape, a.dtype, a.tobytes()) == (b.shape, b.dtype, b.tobytes()), f.name
    with pytest.raises(RigError, match="tip_mm"):
        sh.put_state(replace(state, tip_mm=np.zeros(4)))


@pytest.mark.timeout(120)
def test_truth_worker_solves_what_the_local_truth_solves():
    """TruthProcess: the counts go to the worker and its solve comes back into the local truth
    bit for bit (the same solves in the same order as a truth solving here), failures and
    steps counted; close() ends the worker."""
    from cdcr_ctl.sim.design_truth import make_truth
    from cdcr_ctl.sim.lockstep.truthproc import TruthProcess

    loaded = load_sim_config(TRUTH)
    here, local = make_truth(loaded), make_truth(loaded)
    proc = TruthProcess(str(loaded.path), local)
    try:
        for counts in ([0, 0, 0], [1234, -800, -600], [2500, -1500, -1200], [2600, -1550, -1250]):
            want = here.step(counts)
            proc.submit(counts)
            assert proc.pending
            proc.collect()
            got = local.state
            assert not proc.pending and local.steps == here.steps
            for name in ("tip_mm", "R_tip", "tension_base_N", "tension_actuator_N", "psi"):
                assert getattr(got, name).tobytes() == getattr(want, name).tobytes(), name
        assert local.failures == here.failures == 0 and proc.cpu_s > 0
    finally:
        proc.close()
    assert not proc._proc.is_alive()


def test_placement_parses_and_rotates_over_the_allowed_cpus():
    cpus = allowed_cpus()
    assert Placement.parse("none") == Placement()
    if len(cpus) >= 2:
        assert Placement.parse("auto") == Placement(cpus[0], cpus[1])
        # Sessions side by side: job i's loop on the i-th CPU, its worker on the next.
        assert Placement.parse("job:1") == Placement(cpus[1], cpus[2 % len(cpus)])
        assert Placement.parse(f"{cpus[1]},{cpus[0]}") == Placement(cpus[1], cpus[0])
    else:
        assert Placement.parse("auto") == Placement()
    for bad in ("fast", "0", "job:x", "0,1,2"):
        with pytest.raises(ConfigError, match="cpus"):
            Placement.parse(bad)
    with pytest.raises(ConfigError, match="not one of"):
        Placement.parse(f"{max(cpus, default=0) + 1},{max(cpus, default=0) + 2}")
