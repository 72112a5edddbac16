"""The rig process's planner worker (issue #21, acceptance 1): lead-ins and jog moves planned in
a process of their own equal the in-process plans, what comes back is checked against the limits
before the loop gets it, and a worker that dies is replaced (the caller plans itself meanwhile).

Model level: same model, same code, same float64 inputs on both sides (the worker builds its
model from the same config file), so the plans agree to rounding; the tolerance below is many
orders above float64 rounding of poses of order 1 rad and far below any physical pose change.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.planner import Planner, PlannerUnavailable, check_move
from cdcr_ctl.daemon.planning import plan_jog, plan_lead
from cdcr_ctl.daemon.workers import PARENT_CHECK_S
from cdcr_ctl.errors import RigError

CONFIG = Path(__file__).resolve().parents[2] / "config" / "qi2023-sim.yaml"
#: rad: agreement of two evaluations of the same float64 computation.
POSE_ATOL_RAD = 1e-12


@pytest.fixture(scope="module")
def rig():
    cfg = load_rig_config(CONFIG)
    model = build_model(cfg, source=str(CONFIG))
    planner = Planner(CONFIG).start()
    yield cfg, model, planner
    planner.close()


def test_lead_in_from_the_worker_equals_the_in_process_plan(rig):
    cfg, model, planner = rig
    v, bend = cfg.limits.cable_velocity_mm_s, cfg.limits.bend_rad
    psi_now = np.array([[0.4, 0.3]])
    state = model.new_state()
    q_now = model.q_command(psi_now, model.q_nominal(psi_now), state, "off", None)
    first = np.array([[0.1, -1.0]])
    # A mode switch (off -> model): a hold, then the move; and the same without a switch.
    for q_prev, mode in ((q_now, "model"), (None, "off")):
        mine = plan_lead(model, psi_now, q_prev, first, mode, v, None, state)
        got = planner.lead(psi_now, q_prev, first, mode, v, bend, None, state)
        assert got.hold_s == pytest.approx(mine.hold_s, abs=1e-12)
        assert got.speed_rad_s == pytest.approx(mine.speed_rad_s, rel=1e-12)
        assert mine.lead.n_samples > 2
        np.testing.assert_allclose(got.lead.t_s, mine.lead.t_s, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.lead.psi, mine.lead.psi, rtol=0, atol=POSE_ATOL_RAD)
    assert plan_lead(model, psi_now, q_now, first, "model", v, None, state).hold_s > 0


def test_jog_from_the_worker_equals_the_in_process_plan(rig):
    cfg, model, planner = rig
    v, bend = cfg.limits.cable_velocity_mm_s, cfg.limits.bend_rad
    start, goal = np.array([[0.0, 0.0]]), np.array([[0.5, 0.7]])
    # 10 rad/s is faster than the cables allow: the plan slows it.
    mine, speed, _ = plan_jog(model, start, goal, 10.0, "model", v)
    got, got_speed, _ = planner.jog(start, goal, 10.0, "model", v, bend)
    assert speed < 10.0
    assert got_speed == pytest.approx(speed, rel=1e-12)
    np.testing.assert_allclose(got.psi, mine.psi, rtol=0, atol=POSE_ATOL_RAD)
    assert planner.plans >= 1


@pytest.mark.parametrize(
    ("t", "theta", "start", "goal", "text"),
    [
        ([0.0, 1.0], [0.0, float("nan")], 0.0, 0.5, "not finite"),
        ([0.0, 0.0], [0.0, 0.5], 0.0, 0.5, "times not increasing"),
        ([0.1, 1.0], [0.0, 0.5], 0.0, 0.5, "times not increasing"),
        ([0.0, 1.0], [0.0, 5.0], 0.0, 5.0, "limits.bend_rad"),
        ([0.0, 1.0], [0.0, 0.5], 0.2, 0.5, "does not start"),
        ([0.0, 1.0], [0.0, 0.5], 0.0, 0.4, "does not end"),
    ],
)
def test_a_bad_plan_is_refused_naming_what_failed(t, theta, start, goal, text):
    traj = tj.Trajectory(t, [[[th, 0.0]] for th in theta])
    with pytest.raises(RigError, match=text):
        check_move(traj, np.array([[start, 0.0]]), np.array([[goal, 0.0]]), 1.5, "jog")


def test_a_good_plan_passes():
    m = tj.move(np.array([[0.0, 0.0]]), np.array([[0.5, 1.0]]), 0.3)
    check_move(m, np.array([[0.0, 0.0]]), np.array([[0.5, 1.0]]), 1.5, "jog")


def test_a_dead_worker_is_reported_then_replaced(rig):
    cfg = rig[0]
    planner = Planner(CONFIG).start()
    try:
        v, bend = cfg.limits.cable_velocity_mm_s, cfg.limits.bend_rad
        start, goal = np.array([[0.0, 0.0]]), np.array([[0.3, 0.0]])
        for proc in list(planner._pool._processes.values()):
            proc.kill()
            proc.join(10)
        with pytest.raises(PlannerUnavailable, match="died"):
            planner.jog(start, goal, 0.3, "off", v, bend)
        traj, _, _ = planner.jog(start, goal, 0.3, "off", v, bend)  # a new worker
        assert traj.n_samples > 2
        assert planner.failures == 1
    finally:
        planner.close()


def test_the_worker_ends_when_its_parent_is_killed(tmp_path):
    """A rig process killed with SIGKILL cannot shut its planner down: the worker notices its
    parent is gone (within PARENT_CHECK_S) and exits instead of living on as an orphan."""
    code = (
        "import sys, time\n"
        "from cdcr_ctl.daemon.planner import Planner\n"
        "if __name__ == '__main__':\n"
        "    p = Planner(sys.argv[1]).start()\n"
        "    print(*[w.pid for w in p._pool._processes.values()], flush=True)\n"
        "    time.sleep(600)\n"
    )
    script = tmp_path / "parent.py"
    script.write_text(code)
    parent = subprocess.Popen(
        [sys.executable, str(script), str(CONFIG)], stdout=subprocess.PIPE, text=True
    )
    try:
        worker = int(parent.stdout.readline().split()[0])
        parent.kill()
        parent.wait(10)
        end = time.monotonic() + 30 * PARENT_CHECK_S
        while _alive(worker) and time.monotonic() < end:
            time.sleep(0.1)
        assert not _alive(worker)
    finally:
        parent.kill()


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False
