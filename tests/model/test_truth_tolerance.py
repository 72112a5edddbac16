"""The truth's statics solve against the solver before its speed-up (commit 6abec19), on the
Qi world (config/sim/qi2023-truth.yaml) replaying the drive counts of lock-step runs of the planar
bend and the spatial circle (tests/model/data/qi_truth_paths.npz, written by
``benchmarks/bench_truth.py --record`` and, at 6abec19, ``--write-reference``).

The bound, from TRUTH_TOL and the conditioning. Each solve stops with the largest scaled residual
|r|_inf <= tol (TRUTH_TOL, rad-equivalent). Near the solution z* the error of an output y (tip mm,
tensions N) is dy = G J^-1 r, J the scaled Jacobian of the residual at the solution and G = dy/dz,
so |dy_j| <= C_y tol with C_y = max_j sum_i |(G J^-1)_ji| (the row norm). Two solvers that both
stop within tol differ by at most 2 C_y tol in one solve. The friction memory carries errors
from solve to solve: a stuck cable's equation is w = w_prev, so an error in w_prev acts as a
residual of its own. The w of the solve before a stick run is within C_w tol (C_w the row norm
of the scaled w rows, w / r), and each solve of the run adds at most tol. Hence, at a solve
where the longest run of stuck solves of any cable is n,

    |y_new - y_ref| <= 2 tol C_y (1 + C_w + n).

C_y and C_w are measured here: the largest row norms at every 50th solution (fresh
finite-difference Jacobians), about 60-70 mm/rad for the tip, 92 N/rad for the base tensions,
274 N/rad at the actuators, C_w ~ 1.4. Outside stick runs that is 4e-7 mm on the tip and 1.3e-6 N
at the actuators, far below what the simulated sensors resolve (tracker noise 0.05 mm, load cells
0.02 N noise and 1 mN digits). Measured differences are at most 7 % of the bound.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.model.cc_disk.kinematics import tip_position_fast
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.simconfig import load_sim_config
from cdcr_ctl.sim.truth import TRUTH_TOL, TruthModel

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parent / "data" / "qi_truth_paths.npz"
SIM = ROOT / "config" / "sim" / "qi2023-truth.yaml"
EVERY = 10  # the reference holds every 10th solve
SAMPLE = 50  # conditioning measured at every 50th solution


def _row_norms(truth: TruthModel) -> tuple[np.ndarray, float]:
    """Row norms of G J^-1 at the stepper's last solution: (tip, T_base, T_actuator) and w."""
    m = truth.stepper.model
    r = truth.stepper.last
    S2, K = 2 * m.S, m.K
    z = r.x.tolist() + r.tension_distal_N.tolist() + list(r.state.s)
    modes = list(r.modes)
    raw = m._raw_eval(z)
    Jinv = np.linalg.inv(m._assemble(m._jacobian(raw, z, modes), modes))

    def outputs(zz: list[float]) -> np.ndarray:
        cab = m._raw_eval(zz)[4]
        return np.array(
            list(tip_position_fast(zz[:S2], m._lengths))
            + [c[0] for c in cab]
            + [c[1] for c in cab]
            + [c[2] * m._w_len for c in cab]
        )

    y0 = outputs(z)
    G = np.empty((3 + 3 * K, len(z)))
    for j in range(len(z)):
        h = 1e-7 * max(1.0, abs(z[j]))
        zz = list(z)
        zz[j] += h
        G[:, j] = (outputs(zz) - y0) / h
    rows = np.abs(G @ Jinv).sum(axis=1)
    groups = (rows[:3].max(), rows[3 : 3 + K].max(), rows[3 + K : 3 + 2 * K].max())
    return np.array(groups), float(rows[3 + 2 * K :].max())


@pytest.mark.parametrize("path", ["bend", "circle"])
def test_truth_matches_the_solver_before_the_speed_up_within_the_tolerance_bound(path):
    data = np.load(DATA)
    counts, ref = data[f"counts_{path}"], data[f"ref_{path}"]
    truth = make_truth(load_sim_config(str(SIM)))
    assert isinstance(truth, TruthModel)
    assert truth.stepper.model.tol == TRUTH_TOL
    K = truth.stepper.model.K
    C_y, C_w = np.zeros(3), 0.0
    run = [0] * K
    rows, longest = [], []
    for i, c in enumerate(counts.tolist()):
        st = truth.step(c)
        modes = truth.stepper.last.modes
        run = [n + 1 if m == "stick" else 0 for n, m in zip(run, modes, strict=True)]
        if i % SAMPLE == 0:
            cy, cw = _row_norms(truth)
            C_y, C_w = np.maximum(C_y, cy), max(C_w, cw)
        if i % EVERY == 0:
            rows.append(np.concatenate((st.tip_mm, st.tension_base_N, st.tension_actuator_N)))
            longest.append(max(run))
    assert truth.failures == 0
    out = np.array(rows)
    assert out.shape == ref.shape
    n = np.array(longest, dtype=float)
    if path == "circle":
        assert n.max() > 100  # the circle's reversals hold cables stuck for long runs
    for group, (lo, hi) in enumerate(((0, 3), (3, 3 + K), (3 + K, 3 + 2 * K))):
        bound = 2.0 * TRUTH_TOL * C_y[group] * (1.0 + C_w + n)
        diff = np.abs(out[:, lo:hi] - ref[:, lo:hi]).max(axis=1)
        worst = int(np.argmax(diff / bound))
        assert np.all(diff <= bound), (group, worst * EVERY, diff[worst], bound[worst])
