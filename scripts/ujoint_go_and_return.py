#!/usr/bin/env python3
"""Yang et al. 2022 section 4.2 go-and-return on the simulated universal-joint arm; prints numbers.

How it is measured. The controller's model is built from the RIG config (``build_model``: the
nominal yang2022 parameters), the world from the SIMULATOR config (:class:`UJointTruth`: the
truth the simulated rig runs, which differs from the nominal by 10-15 %, see
config/sim/yang2022-truth.yaml). Every control cycle (the rig's ``control.rate_hz``) the setpoint
of the trajectory goes through the model port exactly as the control loop calls it
(``q_command(psi, q_nominal(psi), state, mode, None)``), is rounded to drive counts, and the truth
is stepped with those counts (drives following their targets ideally: no CAN, no timing, so the
numbers are deterministic). Tip error = |truth tip - model.tip(psi)| (the tracker's measure).

Trajectory: every sub-joint 0 -> 6 deg -> 0 about the segment y axis in both segments (the
paper's [0, 6, 0, 6] deg, i.e. tilt 6 deg at phi = 0), uniform rate ``--rate-deg-s``.

Printed: mean / max tip error with the ideal geometric model (mode off) and with section 3's
algorithm (mode model) and the reduction of the mean; the go/return mismatch at the same
commanded 4.8 deg (the paper's samples at 100 s and 140 s); the dead zone at the reversal (how
far the command travels back before the distal segment's true angle moves back). ``--bench``
also prints what each control cycle and physics step cost: the CPU time of this thread
(time.thread_time, so other processes on the PC count little) per call of the model port's
q_nominal, q_command and tip (what the daemon's loop calls every cycle) and of the truth's
step (what the simulator's physics thread calls), median and 95th percentile over the run.

    nice .venv/bin/python scripts/ujoint_go_and_return.py [--sim-config ...] [--rate-deg-s 1]
        [--bench]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.model.ujoint import joint_angles_from_psi
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]


def run(sim_config: Path, mode: str, theta_deg: float, rate_deg_s: float) -> dict[str, np.ndarray]:
    loaded = load_sim_config(sim_config)
    truth = make_truth(loaded)
    model = build_model(loaded.rig)
    state = model.new_state()
    cpm = np.array([d.counts_per_mm for d in loaded.rig.drives])
    traj = tj.go_and_return(2, math.radians(theta_deg), math.radians(rate_deg_s), 0.0)
    dt = 1.0 / loaded.rig.control.rate_hz
    ts = np.arange(0.0, traj.duration_s + 1.0, dt)
    out: dict[str, list] = {
        "t": [],
        "cmd": [],
        "tip": [],
        "tip_cmd": [],
        "theta": [],
        "q": [],
        "q_out": [],
        "cpu_s": [],  # per cycle: q_nominal, q_command, tip, truth step
    }
    clock = time.thread_time
    for t in ts:
        psi = traj.sample(min(t, traj.duration_s))
        c0 = clock()
        q_nom = model.q_nominal(psi)
        c1 = clock()
        q = model.q_command(psi, q_nom, state, mode, None)
        c2 = clock()
        tip_cmd = model.tip(psi)
        c3 = clock()
        s = truth.step(np.rint(q * cpm).astype(np.int64))
        c4 = clock()
        out["cpu_s"].append((c1 - c0, c2 - c1, c3 - c2, c4 - c3))
        out["t"].append(t)
        out["cmd"].append(joint_angles_from_psi(psi))
        out["tip"].append(s.tip_mm)
        out["tip_cmd"].append(tip_cmd)
        out["theta"].append(truth.theta.copy())
        out["q"].append(np.rint(q * cpm) / truth.counts_per_mm)
        out["q_out"].append(truth._memory.q_out_mm.copy())
    res = {k: np.array(v) for k, v in out.items()}
    res["err"] = np.linalg.norm(res["tip"] - res["tip_cmd"], axis=1)
    res["t_top"] = np.array(traj.duration_s / 2.0)
    return res


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--sim-config", type=Path, default=ROOT / "config" / "sim" / "yang2022-truth.yaml"
    )
    ap.add_argument("--theta-deg", type=float, default=6.0)
    ap.add_argument("--rate-deg-s", type=float, default=1.0)
    ap.add_argument("--probe-deg", type=float, default=4.8, help="go/return comparison angle")
    ap.add_argument("--bench", action="store_true", help="print the CPU time per call")
    a = ap.parse_args(argv)
    print(f"sim config {a.sim_config}; 0 -> {a.theta_deg} -> 0 deg at {a.rate_deg_s} deg/s")
    res = {m: run(a.sim_config, m, a.theta_deg, a.rate_deg_s) for m in ("off", "model")}
    for m, r in res.items():
        print(
            f"  mode {m:5s}: tip error mean {r['err'].mean():7.3f} mm  rms "
            f"{np.sqrt((r['err'] ** 2).mean()):7.3f} mm  max {r['err'].max():7.3f} mm"
        )
    red = 100.0 * (1.0 - res["model"]["err"].mean() / res["off"]["err"].mean())
    print(f"  mean tip error reduction by the compensation: {red:.1f} % (paper: 61.4 %)")
    for m, r in res.items():
        b = r["cmd"][:, :, 1]  # commanded sub-joint angle about y, both segments
        t, top = r["t"], float(r["t_top"])
        probe = math.radians(a.probe_deg)
        i_go = int(np.argmin(np.where(t <= top, np.abs(b[:, 1] - probe), np.inf)))
        i_back = int(np.argmin(np.where(t > top, np.abs(b[:, 1] - probe), np.inf)))
        go, back = np.degrees(r["theta"][i_go, :, 1]), np.degrees(r["theta"][i_back, :, 1])
        mismatch = float(np.linalg.norm(r["tip"][i_go] - r["tip"][i_back]))
        print(
            f"  mode {m:5s}: at commanded {a.probe_deg} deg the true sub-joint angles are "
            f"go {np.round(go, 2).tolist()} deg, return {np.round(back, 2).tolist()} deg; "
            f"tip error go {r['err'][i_go]:.2f} mm, return {r['err'][i_back]:.2f} mm, "
            f"go/return tip mismatch {mismatch:.2f} mm"
        )
        # dead zone at each cable's reversal: how far the drive input travels back before the
        # cable's output (what moves the arm) follows
        sticks = []
        for k in range(r["q"].shape[1]):
            q, qo = r["q"][:, k], r["q_out"][:, k]
            i_rev = int(np.argmax(np.abs(q)))
            moved = np.nonzero(np.abs(qo[i_rev:] - qo[i_rev]) > 1e-6)[0]
            if moved.size:
                sticks.append(abs(float(q[i_rev] - q[i_rev + int(moved[0])])))
        print(
            f"  mode {m:5s}: dead zone at the reversal (input travel before the output moves) "
            f"per cable {np.round(sticks, 3).tolist()} mm"
        )
    if a.bench:
        for m, r in res.items():
            cpu = 1e3 * r["cpu_s"]
            parts = ", ".join(
                f"{name} {np.median(cpu[:, j]):.3f} / {np.percentile(cpu[:, j], 95):.3f} ms"
                for j, name in enumerate(("q_nominal", "q_command", "tip", "truth step"))
            )
            loop = cpu[:, :3].sum(axis=1)
            total = f"{np.median(loop):.3f} / {np.percentile(loop, 95):.3f} ms"
            print(
                f"  mode {m:5s}: CPU per call (median / 95th percentile, {len(cpu)} cycles): "
                f"{parts}; the loop's three calls together {total}"
            )


if __name__ == "__main__":
    main()
