"""Time one evaluation of the full force-transfer compensation (Qi et al. 2023 eq. 37).

Case: config/three_segment_example.yaml (3 segments x 3 cables = 9 cables, 16 disks with
weights, 2 pulleys per cable, one with the non-linear n = 0.67 law), every effect on: gravity,
coupling, disk friction, pulley friction (tables), elongation.

Measured with time.perf_counter_ns around each single call, after a warm-up, over N calls at
poses that change every call (a slow circle), so no result is reused. Prints median and p90 (us).
Target: stateless compensation median < 200 us.

Then the cost of each term on the loop's path (issue #17): ``CCDiskModel.q_command`` of the
Qi et al. 2023 rig (config/qi2023.yaml, the 1 kHz loop's model) built with one more effect at a
time (geometry only -> + elongation -> + disk friction -> + pulleys -> + gravity -> + the cables'
lost motion, 0.3 mm, with its direction memory), and the dead-zone inverse alone; the increments
are the terms' costs. A tilted mount (gravity_direction) or a fitted actuator scale change
values, not work: the same calls.

    .venv/bin/python benchmarks/bench_compensation.py [--n 1000] [--warmup 200]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdcr_ctl.config import load_rig_config  # noqa: E402
from cdcr_ctl.config.build_model import build_model, robot_params  # noqa: E402
from cdcr_ctl.model import Compensator, Effects, ForwardStepper  # noqa: E402

CONFIG = ROOT / "config" / "three_segment_example.yaml"


def poses(n: int) -> list[np.ndarray]:
    """A slow spatial circle of every segment (theta 0.4-0.8 rad, phi sweeping)."""
    out = []
    for j in range(n):
        a = 2.0 * math.pi * j / n
        out.append(
            np.array(
                [
                    [0.6 + 0.2 * math.sin(a), a],
                    [0.5 + 0.1 * math.cos(a), a + 1.0],
                    [0.7, -a],
                ]
            )
        )
    return out


def timed(fn, args_list, warmup: int) -> list[float]:
    for j in range(warmup):
        fn(*args_list[j % len(args_list)])
    out = []
    for args in args_list:
        t0 = time.perf_counter_ns()
        fn(*args)
        out.append((time.perf_counter_ns() - t0) / 1000.0)
    return out


def report(name: str, us: list[float]) -> None:
    us_sorted = sorted(us)
    p90 = us_sorted[int(0.9 * (len(us_sorted) - 1))]
    print(
        f"{name:<48} median {statistics.median(us):8.1f} us   p90 {p90:8.1f} us   "
        f"min {us_sorted[0]:7.1f} us   N={len(us)}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--warmup", type=int, default=200)
    ns = ap.parse_args(argv)

    cfg = load_rig_config(CONFIG)
    params = robot_params(cfg.robot)
    t0 = time.perf_counter()
    comp = Compensator(params, Effects())
    print(f"model built in {time.perf_counter() - t0:.3f} s (pulley tables included)")
    print(f"{params.n_segments} segments x {params.n_cables} cables, all effects on")
    print(
        f"method: time.perf_counter_ns per call, warm-up {ns.warmup}, N = {ns.n}, "
        f"python {sys.version.split()[0]}, numpy {np.__version__}"
    )
    P = poses(ns.n)
    s_pull = [1.0, -1.0, -1.0] * 3

    report(
        "Compensator.compensate (stateless, eq. 37)",
        timed(lambda psi: comp.compensate(psi, s_pull), [(p,) for p in P], ns.warmup),
    )
    state = comp.new_state()
    report(
        "Compensator.step (friction memory)",
        timed(lambda psi: comp.step(psi, state), [(p,) for p in P], ns.warmup),
    )
    meas = [3.0] * params.n_cables
    report(
        "Compensator.compensate (measured tensions)",
        timed(lambda psi: comp.compensate(psi, s_pull, "measured", meas), [(p,) for p in P], 50),
    )
    model = build_model(cfg)
    mstate = model.new_state()
    report(
        "CCDiskModel loop calls (q_nominal+q_command+tip)",
        timed(
            lambda psi: (
                model.q_command(psi, model.q_nominal(psi), mstate, "model", None),
                model.tip(psi),
            ),
            [(p,) for p in P],
            ns.warmup,
        ),
    )
    term_costs(ns.n, ns.warmup)
    # the simulator's forward stepper, for information (not a loop-path call)
    fw = ForwardStepper(params, Effects())
    cstate = comp.new_state()
    n_fw = min(200, ns.n)
    cmds = [(np.array(comp.step(p, cstate).q),) for p in poses(n_fw)]
    report("ForwardStepper.step (simulator truth)", timed(fw.step, cmds, 5))
    return 0


def term_costs(n: int, warmup: int) -> None:
    """q_command of the Qi rig's loop model with the effects added one at a time (docstring)."""
    from dataclasses import replace

    from cdcr_ctl.model.shared.deadzone import dead_zone_inverse

    cfg = load_rig_config(ROOT / "config" / "qi2023.yaml")
    play = cfg.model_copy(
        update={
            "robot": cfg.robot.model_copy(
                update={
                    "cables": [c.model_copy(update={"backlash_mm": 0.3}) for c in cfg.robot.cables]
                }
            )
        }
    )
    P = [np.array([[0.8 + 0.6 * math.sin(2 * math.pi * j / 200), 0.3 * j / n]]) for j in range(n)]
    base = Effects.none()
    steps = [
        ("geometry only (eq. 4)", base, cfg),
        ("+ elongation (eq. 33-36)", replace(base, elongation=True), cfg),
        ("+ disk friction (eq. 16-24)", replace(base, elongation=True, disk_friction=True), cfg),
    ]
    full = Effects(geometry=cfg.control.geometry)
    steps += [
        ("+ pulleys (eq. 25-32)", replace(full, gravity=False, coupling=False), cfg),
        ("+ gravity (eq. 7-9)", replace(full, coupling=False), cfg),
        ("+ lost motion 0.3 mm (Yang eq. 13-17)", replace(full, coupling=False), play),
    ]
    print("cost of each term, CCDiskModel.q_command + q_nominal of the Qi rig (1 segment):")
    prev = None
    for name, eff, c in steps:
        model = build_model(c, eff)
        st = model.new_state()
        us = timed(
            lambda psi, model=model, st=st: model.q_command(
                psi, model.q_nominal(psi), st, "model", None
            ),
            [(p,) for p in P],
            warmup,
        )
        med = statistics.median(us)
        inc = "" if prev is None else f"   (+{med - prev:.1f} us)"
        report(f"  {name}", us)
        if inc:
            print(f"{'':48}{inc}")
        prev = med
    state = [[0.0, 0.0, 0.0, 0.0] for _ in range(3)]
    half = [0.15] * 3
    ys = [([0.001 * j] * 3,) for j in range(n)]
    report(
        "  dead-zone inverse alone (model.deadzone)",
        timed(lambda v: dead_zone_inverse(v, state, half, 0.01), ys, warmup),
    )


if __name__ == "__main__":
    raise SystemExit(main())
