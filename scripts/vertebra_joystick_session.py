#!/usr/bin/env python3
"""Scripted joystick end-following session on the simulated vertebra arm; prints numbers.

How it is measured. The controller side is what the control loop runs: the joystick source
(:class:`EndFollowSource` over the planner of the rig config, stick scripted after the paper's
Fig. 12 by :func:`paper_session`) is sampled every cycle (``control.rate_hz``) and the model port
(``build_model``) turns the setpoint into cable commands in the chosen mode. The world is the
simulator's :class:`VertebraTruth` (config/sim/vertebra-truth.yaml: softer rod, heavier disks,
uneven pretension, gravity sag), stepped every cycle with the commands rounded to drive counts
(drives following ideally: no CAN, deterministic). The attitude sensors are simulated from the
truth's joint-end orientations: roll/pitch of each sensor with Gaussian noise (the simulator
config's ``attitude.noise_deg``), one cycle old, and reach the model through its attitude port.

Printed per mode (off = the paper's kinematic control; measured = joint-space closed loop on
the attitude sensors; model = sag compensation): the distal pose commanded by the stick and
reached, every joint's final error, the mean joint-angle error over the session, the highest
cable speed of each axis against its limit, and the synchronisation of the steps (largest spread,
over all steps, of the cycle in which the moving axes reach their step end).

    nice .venv/bin/python scripts/vertebra_joystick_session.py [--sim-config ...] [--quick]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.config.designs import follow_params, vertebra_arm
from cdcr_ctl.model.vertebra import EndFollowPlanner, x_from_psi
from cdcr_ctl.model.vertebra.follow import EndFollowSource, paper_session, scripted_stick
from cdcr_ctl.sensors.attitude import rpy_from_rotation
from cdcr_ctl.sim.design_truth import make_truth
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]


class TruthAttitude:
    """AttitudePort over the truth: each sensor's roll/pitch with noise, refreshed by
    :meth:`sample` once per cycle (so the model sees the previous cycle's reading)."""

    def __init__(self, truth, noise_deg: float, seed: int) -> None:
        self.truth = truth
        self.noise = math.radians(noise_deg)
        self.rng = np.random.default_rng(seed)
        n = truth.arm.n_joints
        self.roll, self.pitch, self.age = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.inf)

    def sample(self) -> None:
        for i in range(len(self.roll)):
            r, p, _ = rpy_from_rotation(self.truth.sensor_orientation(i))
            self.roll[i] = r + self.rng.normal(0.0, self.noise)
            self.pitch[i] = p + self.rng.normal(0.0, self.noise)
        self.age[:] = 0.0

    def latest(self):
        return self.roll.copy(), self.pitch.copy(), self.age.copy()

    def close(self) -> None:
        pass


def session(sim_config: Path, mode: str, quick: bool) -> dict:
    loaded = load_sim_config(sim_config)
    rig = loaded.rig
    truth = make_truth(loaded)
    model = build_model(rig)
    sensors = TruthAttitude(truth, loaded.sim.attitude.noise_deg, loaded.sim.seed)
    model.attach_attitude(sensors)
    state = model.new_state()
    arm = vertebra_arm(rig)
    now = [0.0]
    script = paper_session(scale=0.5 if quick else 1.0)
    source = EndFollowSource(
        EndFollowPlanner(arm, follow_params(rig)), scripted_stick(script, lambda: now[0])
    )
    cpm = np.array([d.counts_per_mm for d in rig.drives])
    dt = 1.0 / rig.control.rate_hz
    t_end = max(f.t_s for f in script)
    ts, qs, qn, cmd, act = [], [], [], [], []
    t = 0.0
    while t < 600.0:
        now[0] = t
        psi = source.sample(t)
        q_nom = model.q_nominal(psi)
        q = model.q_command(psi, q_nom, state, mode, None)
        truth.step(np.rint(q * cpm).astype(np.int64))
        sensors.sample()
        ts.append(t)
        qs.append(q)
        qn.append(q_nom)
        cmd.append(psi)
        act.append(truth.state.psi.copy())
        if t > t_end and not source.busy:
            break
        t += dt
    # hold a second so the closed loop can settle at the final pose
    for _ in range(round(1.0 / dt)):
        t += dt
        q_nom = model.q_nominal(psi)
        q = model.q_command(psi, q_nom, state, mode, None)
        truth.step(np.rint(q * cpm).astype(np.int64))
        sensors.sample()
        ts.append(t)
        qs.append(q)
        qn.append(q_nom)
        cmd.append(psi)
        act.append(truth.state.psi.copy())
    return {
        "t": np.array(ts),
        "q": np.array(qs),
        "q_nominal": np.array(qn),
        "cmd": np.array(cmd),
        "act": np.array(act),
        "source": source,
        "arm": arm,
        "dt": dt,
        "target": source.planner.target.copy(),
    }


def step_sync(res: dict) -> tuple[float, int]:
    """Largest spread (in cycles) between the moving axes reaching their step end, over steps."""
    t, q, dt = res["t"], res["q_nominal"][: len(res["t"])], res["dt"]
    worst = 0.0
    for rec in res["source"].log:
        moving = np.abs(rec.q_to_mm - rec.q_from_mm) > 1e-3
        t_end = rec.t_start_s + rec.duration_s
        idx = np.nonzero((t >= rec.t_start_s) & (t <= t_end + 2 * dt))[0]
        if not moving.any() or idx.size == 0:
            continue
        done = []
        for k in np.nonzero(moving)[0]:
            reached = idx[np.abs(q[idx, k] - rec.q_to_mm[k]) <= 1e-3 + 1e-9]
            done.append(t[reached[0]] if reached.size else np.inf)
        worst = max(worst, (max(done) - min(done)) / dt)
    return worst, len(res["source"].log)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--sim-config", type=Path, default=ROOT / "config" / "sim" / "vertebra-truth.yaml"
    )
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    v_max = None
    base_err = None
    for mode in ("off", "measured", "model"):
        r = session(a.sim_config, mode, a.quick)
        arm, dt = r["arm"], r["dt"]
        v_max = np.array([m.v_max_mm_s for m in arm.modules])
        target = r["target"]
        final = r["act"][-1]
        speed = np.abs(np.diff(r["q"], axis=0)).max(axis=0) / dt
        err_x = np.linalg.norm(x_from_psi(final) - x_from_psi(target), axis=1)
        traj_err = np.linalg.norm(
            x_from_psi(r["act"].reshape(-1, 2)) - x_from_psi(r["cmd"].reshape(-1, 2)), axis=1
        ).reshape(len(r["t"]), -1)
        spread, steps = step_sync(r)
        print(f"mode {mode}: {steps} synchronised steps, {r['t'][-1]:.1f} s")
        print(
            f"  commanded distal pose (theta, phi) = ({math.degrees(target[-1, 0]):.2f}, "
            f"{math.degrees(target[-1, 1]):.2f}) deg; every joint's target "
            f"{np.round(np.degrees(target[:, 0]), 2).tolist()} deg bend"
        )
        print(
            f"  reached: bends {np.round(np.degrees(final[:, 0]), 2).tolist()} deg, directions "
            f"{np.round(np.degrees(final[:, 1]), 2).tolist()} deg; joint error "
            f"{np.round(np.degrees(err_x), 3).tolist()} deg"
        )
        print(
            f"  mean joint-angle error over the session {np.degrees(traj_err.mean()):.3f} deg, "
            f"final mean {np.degrees(err_x.mean()):.3f} deg"
        )
        print(
            f"  peak cable speed / limit per axis: "
            f"{np.round(speed / v_max, 3).tolist()} (max {float((speed / v_max).max()):.3f})"
        )
        print(
            f"  step synchronisation (commanded ideal positions): the moving axes reach each "
            f"step's end within {spread:.2f} cycles of each other"
        )
        if mode == "off":
            base_err = float(err_x.mean())
        elif base_err:
            print(
                f"  final joint-angle error vs off: {100 * (1 - err_x.mean() / base_err):.1f} % "
                "lower"
            )


if __name__ == "__main__":
    main()
