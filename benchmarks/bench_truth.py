"""The simulated world's statics solve alone: CPU per solve and residual evaluations per solve of
the Qi truth (config/sim/qi2023-truth.yaml: lost motion, capstan friction with stick, tilted
gravity, chord geometry), replaying the drive counts it saw in lock-step runs of the planar bend
(0 -> 90 deg at pi/10 rad/s) and the spatial circle (45 deg, pi/10 rad/s), compensation model.

    .venv/bin/python benchmarks/bench_truth.py [--repeat 3]
    .venv/bin/python benchmarks/bench_truth.py --record            # new counts (lock-step runs)
    .venv/bin/python benchmarks/bench_truth.py --write-reference   # outputs of this code

The counts and the reference outputs (tip mm, base and actuator tensions N, every 10th solve) live
in tests/model/data/qi_truth_paths.npz; tests/model/test_truth_tolerance.py checks the solver
against them. The reference there was written by the solver of commit 6abec19 (before the
truth speed-up). CPU time (``time.thread_time``) is summed over chunks of 50 solves, each chunk
the least of ``--repeat`` replays from the start (the machine is shared: the least is the one
least disturbed by other processes).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]
SIM = ROOT / "config/sim/qi2023-truth.yaml"
DATA = ROOT / "tests/model/data/qi_truth_paths.npz"
PATHS = ("bend", "circle")
EVERY = 10  # reference rows: every 10th solve
CHUNK = 50


def record() -> dict[str, np.ndarray]:
    """Drive counts the truth is stepped with in lock-step runs (truth in the loop's process)."""
    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.control import trajectory as tj
    from cdcr_ctl.sim.lockstep.session import LockstepSession
    from cdcr_ctl.sim.truth import SteppedTruth

    loaded = load_sim_config(str(SIM))
    ctl = load_rig_config(loaded.rig_path)
    trajs = {
        "bend": tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10),
        "circle": tj.spatial_circle(theta_rad=math.pi / 4, phi_rate_rad_s=math.pi / 10),
    }
    seen: list[list[int]] = []
    orig = SteppedTruth.step

    def step(self, counts):
        seen.append([int(c) for c in counts])
        return orig(self, counts)

    SteppedTruth.step = step  # type: ignore[method-assign]
    out = {}
    try:
        for name, traj in trajs.items():
            seen.clear()
            with tempfile.TemporaryDirectory() as tmp:
                s = LockstepSession.open(loaded, ctl, loaded.rig_path, tmp, truth_process=False)
                try:
                    s.run(traj, name, "model")
                finally:
                    s.close()
            out[f"counts_{name}"] = np.array(seen, dtype=np.int32)
    finally:
        SteppedTruth.step = orig  # type: ignore[method-assign]
    return out


def replay(counts: np.ndarray, repeat: int = 1) -> tuple[np.ndarray, float, float]:
    """Outputs (N, 9: tip, T_base, T_actuator), CPU s per solve, evaluations per solve."""
    loaded = load_sim_config(str(SIM))
    best: list[float] | None = None
    rows: list[np.ndarray] = []
    evals = 0
    for _ in range(repeat):
        truth = make_truth(loaded)
        model = truth.stepper.model
        n_eval = [0]
        raw_eval = model._raw_eval

        def counted(z, raw_eval=raw_eval, n_eval=n_eval):
            n_eval[0] += 1
            return raw_eval(z)

        model._raw_eval = counted
        rows = []
        chunks = []
        for j in range(0, len(counts), CHUNK):
            c0 = time.thread_time()
            for c in counts[j : j + CHUNK].tolist():
                st = truth.step(c)
                rows.append(np.concatenate((st.tip_mm, st.tension_base_N, st.tension_actuator_N)))
            chunks.append(time.thread_time() - c0)
        best = chunks if best is None else [min(a, b) for a, b in zip(best, chunks, strict=True)]
        evals = n_eval[0]
    assert best is not None
    n = len(counts)
    return np.array(rows), sum(best) / n, evals / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--record", action="store_true", help="record new counts (drops the reference)")
    ap.add_argument("--write-reference", action="store_true", help="store this code's outputs")
    args = ap.parse_args()
    if args.record:
        DATA.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(DATA, **record())
        print(f"wrote {DATA.relative_to(ROOT)} (counts only: run --write-reference next)")
        return
    data = dict(np.load(DATA))
    for name in PATHS:
        counts = data[f"counts_{name}"]
        out, cpu, evals = replay(counts, 1 if args.write_reference else args.repeat)
        line = (
            f"{name:7s} {len(counts):5d} solves: {cpu * 1e6:6.1f} us CPU per solve, "
            f"{evals:.2f} residual evaluations per solve"
        )
        ref = data.get(f"ref_{name}")
        if ref is not None and not args.write_reference:
            d = np.abs(out[::EVERY] - ref)
            line += (
                f"; against the reference: tip {d[:, :3].max():.1e} mm, T_base "
                f"{d[:, 3:6].max():.1e} N, T_actuator {d[:, 6:].max():.1e} N"
            )
        print(line)
        if args.write_reference:
            data[f"ref_{name}"] = out[::EVERY]
    if args.write_reference:
        np.savez_compressed(DATA, **data)
        print(f"wrote the reference into {DATA.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
