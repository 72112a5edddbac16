"""The loop process's side of one lock-step truth hand-off (``TruthProcess.submit`` +
``collect``, :mod:`cdcr_ctl.sim.lockstep.truthproc`): thread CPU of the calling thread, the
worker's solve excluded (the result is ready when ``collect`` is called, as in a lock-step cycle,
where the loop's work runs meanwhile).

    .venv/bin/python benchmarks/bench_truth_handoff.py [--blocks 3] [--per-block 300]

Each hand-off solves a new pose of the Qi rig (drive counts moving as in a bend); between submit
and collect the caller sleeps 1 ms (wall) so the solve is done, which also leaves the caches as
cold as a lock-step cycle's other work does. Prints the least mean of the blocks (the load
disturbs the least the least) and every block.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.lockstep.truthproc import TruthProcess
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sim-config", default=str(ROOT / "config/sim/qi2023-truth.yaml"))
    ap.add_argument("--blocks", type=int, default=3)
    ap.add_argument("--per-block", type=int, default=300)
    args = ap.parse_args()
    loaded = load_sim_config(args.sim_config)
    local = make_truth(loaded)
    proc = TruthProcess(str(loaded.path), local)
    try:
        means = []
        for _ in range(args.blocks):
            cpu = 0.0
            for i in range(args.per_block):
                counts = [10 * i, -6 * i, -5 * i]
                c0 = time.thread_time()
                proc.submit(counts)
                cpu += time.thread_time() - c0
                time.sleep(0.001)
                c0 = time.thread_time()
                proc.collect()
                cpu += time.thread_time() - c0
            means.append(cpu / args.per_block * 1e6)
        blocks = ", ".join(f"{m:.1f}" for m in means)
        print(f"submit + collect: {min(means):.1f} us thread CPU (blocks: {blocks})")
    finally:
        proc.close()


if __name__ == "__main__":
    main()
