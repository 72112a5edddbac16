"""Live joystick end-following on the simulated vertebra rig: what a session achieves, and how
fast a lost joystick holds the arm.

What is measured, and how:

1. Live sessions. Per compensation mode, a fresh ``cdcr-ctl sim`` (config/sim/vertebra-truth.yaml
   with its network joystick playing the paper's Fig. 12 stick session, ``--scale`` of the bend
   moves) and ``cdcr-ctl daemon`` run as processes (``cdcr_ctl.cli.demo.make_session``); the
   session is started with the daemon's ``joystick`` command, and stopped (halt) once the script
   is over and the planner is idle. From the run's log: session length, planner steps, the
   distal joint's final command against the offline plan of the same script
   (:func:`plan_session` at the loop rate), the distal pose from the ACTUAL cable displacements
   (drives reached the command?), the highest cable speed of the logged commands against
   ``limits.cable_velocity_mm_s``, late cycles, and the tracked tip error against the model tip
   (:func:`cdcr_ctl.analysis.tip_errors`: the sag the kinematic control leaves).
2. Joystick lost -> arm held. In-process: the daemon (real loop, supervisor, control socket) on
   the vertebra rig config with drives that follow their targets exactly, and the simulated
   network joystick on loopback. While the stick steers, the sender hangs up
   (``NetworkJoystickServer.hang_up``; ``time.monotonic`` before the call); this process polls
   the supervisor every 0.2 ms and records when ``joystick_lost`` latches. The latency is that
   difference: TCP close -> reader thread's EOF -> next loop cycle's check (one cycle is
   1 / control.rate_hz). Repeated ``--trials`` times.

Usage::

    nice .venv/bin/python benchmarks/bench_joystick_session.py [--scale 1.0] [--trials 20]
        [--modes off,model] [--skip-live]
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from cdcr_ctl.cli.demo import (
    ROOT_CONFIG,
    _cli,
    make_session,
    running,
    wait_for_socket,
)
from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.designs import plan_follow_offline, vertebra_arm
from cdcr_ctl.daemon.client import ControlClient
from cdcr_ctl.model.vertebra import joints_from_displacements, x_from_psi
from cdcr_ctl.model.vertebra.follow import paper_session
from cdcr_ctl.runlog import load_run

TRUTH = ROOT_CONFIG / "sim" / "vertebra-truth.yaml"


def _wait(work: Path, pred, timeout_s: float) -> dict:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        with contextlib.suppress(Exception), ControlClient(work / "control.sock") as c:
            st = c.call("status")
            if pred(st):
                return st
        time.sleep(0.1)
    raise TimeoutError("status never matched")


def live_session(mode: str, scale: float, out: Path) -> dict:
    work = Path(tempfile.mkdtemp(prefix="cdcr-bj-", dir="/tmp"))
    runs = out / f"runs-{mode}"
    runs.mkdir(parents=True, exist_ok=True)
    rig, sim = make_session(TRUTH, work, runs)
    doc = yaml.safe_load(sim.read_text())
    doc["joystick"] = {"script": "paper", "scale": scale}
    sim.write_text(yaml.safe_dump(doc, sort_keys=False))
    cfg = load_rig_config(rig)
    script = paper_session(scale=scale)
    try:
        with (
            running(_cli("sim", str(sim)), out / f"sim-{mode}.log", ready='"ready"'),
            running(_cli("--config", str(rig), "daemon"), out / f"daemon-{mode}.log") as d,
        ):
            wait_for_socket(work / "control.sock", d, out / f"daemon-{mode}.log")
            with ControlClient(work / "control.sock") as c:
                c.call("enable")
                c.call("home")
                res = c.call("joystick", compensation=mode)
            _wait(
                work,
                lambda st: (
                    (st["run"] or {}).get("elapsed_s", 0.0) > script[-1].t_s + 0.5
                    and st["joystick"]["mode"] == "idle"
                ),
                300,
            )
            with ControlClient(work / "control.sock") as c:
                c.call("stop", mode="halt")
            st = _wait(work, lambda st: any(r["id"] == res["run"] for r in st["runs"]), 30)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    entry = next(r for r in st["runs"] if r["id"] == res["run"])
    run = load_run(res["log_dir"])
    K = run.n_cables
    q_cmd = np.column_stack([run.data[f"cable{k}_q_cmd_mm"] for k in range(1, K + 1)])
    q_act = np.column_stack([run.data[f"cable{k}_q_act_mm"] for k in range(1, K + 1)])
    v = np.abs(np.diff(q_cmd, axis=0)) / np.diff(run.t_s)[:, None]
    final = np.array(
        [[run.data[f"seg{i}_{a}_cmd_rad"][-1] for a in ("theta", "phi")] for i in (1, 2, 3)]
    )
    _, psi_plan, _ = plan_follow_offline(cfg, script)
    x_cmd = x_from_psi(final)
    x_act = joints_from_displacements(vertebra_arm(cfg), q_act[-1], x_cmd)
    late = run.data.get("lateness_us")
    from cdcr_ctl.analysis import tip_errors

    tip = tip_errors(res["log_dir"], settle_s=0.0).summary()
    return {
        "mode": mode,
        "state": entry["state"],
        "elapsed_s": float(run.t_s[-1] - run.t_s[0]),
        "rows": len(run),
        "steps": st["joystick"]["steps"],
        "final_cmd": final,
        "plan": psi_plan[-1],
        "reach_rad": float(np.max(np.abs(x_act - x_cmd))),
        "follow_mm": float(np.max(np.abs(q_act[-1] - q_cmd[-1]))),
        "v_max": float(v.max()),
        "v_limit": cfg.limits.cable_velocity_mm_s,
        "late_gt_period": int(np.sum(late > 1e6 / cfg.control.rate_hz)) if late is not None else -1,
        "tip": tip,
    }


def lost_latency(trials: int) -> list[float]:
    """Seconds from the sender's hang-up to the supervisor's joystick_lost trip."""
    from cdcr_ctl.config.build_model import build_model
    from cdcr_ctl.control import trajectory
    from cdcr_ctl.control.ports import DriveState, NoTension, NoTip
    from cdcr_ctl.daemon.service import Daemon, RigIO
    from cdcr_ctl.runlog.writer.factory import RunLogFactory
    from cdcr_ctl.sim.joystick import JoystickFrame, NetworkJoystickServer, ScriptedJoystick

    class IdealDrives:
        def __init__(self, n: int) -> None:
            self.counts = [0] * n

        def send_cycle(self, targets):
            self.counts = list(targets)

        def feedback(self):
            return [DriveState(c, "OPERATION_ENABLED", "", 0.0) for c in self.counts]

        def first_fault(self):
            return None

        def home(self):
            return [0] * len(self.counts)

        enable = disable = quick_stop = reset_faults = close = lambda self: None

    frames = [JoystickFrame(0.0, 0.0, -1.0), JoystickFrame(600.0, 0.0, -1.0)]  # forward (inv.)
    server = NetworkJoystickServer(lambda: ScriptedJoystick(frames)).start()
    tmp = Path(tempfile.mkdtemp(prefix="cdcr-bl-", dir="/tmp"))
    doc = {
        "extends": str(ROOT_CONFIG / "vertebra-sim.yaml"),
        "daemon": {"socket_path": str(tmp / "ctl.sock")},
        "logging": {"directory": str(tmp / "runs")},
        "sensors": {"joystick": {"device": server.url}},
    }
    (tmp / "rig.yaml").write_text(yaml.safe_dump(doc))
    cfg = load_rig_config(tmp / "rig.yaml")
    cfg = cfg.model_copy(
        update={"sensors": cfg.sensors.model_copy(update={"tracker": None, "attitude": None})}
    )
    K = len(cfg.robot.cables)
    io = RigIO(IdealDrives(K), NoTension(K), NoTip(), close=lambda: None)
    d = Daemon(
        cfg,
        tmp / "rig.yaml",
        io,
        build_model(cfg),
        RunLogFactory.from_config(cfg, tmp / "rig.yaml"),
        trajectory,
    )
    d.start()
    out: list[float] = []
    try:
        with ControlClient(tmp / "ctl.sock") as c:
            c.call("enable")
            c.call("home")
            for _ in range(trials):
                c.call("joystick", log=False)
                time.sleep(0.3)  # steering
                t0 = time.monotonic()
                server.hang_up()
                while d.supervisor.trip is None and time.monotonic() - t0 < 5.0:
                    time.sleep(0.0002)
                out.append(time.monotonic() - t0)
                trip = d.supervisor.trip
                assert trip is not None and trip.cause == "joystick_lost", (trip, out)
                while d._session is not None and d._session.active:
                    time.sleep(0.01)
                c.call("reset_fault", confirm=True)  # the next session starts where this held
    finally:
        d.shutdown("benchmark over")
        server.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--modes", default="off,model")
    ap.add_argument("--skip-live", action="store_true")
    ap.add_argument("--out", type=Path, default=Path("bench-joystick-output"))
    a = ap.parse_args()
    if not a.skip_live:
        a.out.mkdir(parents=True, exist_ok=True)
        for mode in a.modes.split(","):
            r = live_session(mode, a.scale, a.out.resolve())
            f, p = r["final_cmd"], r["plan"]
            print(
                f"live session compensation={r['mode']} ({r['state']}): {r['elapsed_s']:.1f} s,"
                f" {r['rows']} rows, {r['steps']} steps, {r['late_gt_period']} late cycles"
            )
            print(
                f"  distal final cmd theta {f[2, 0]:.3f} phi {f[2, 1]:.3f} rad; offline plan"
                f" {p[2, 0]:.3f} {p[2, 1]:.3f}; all joints cmd {np.round(f[:, 0], 3).tolist()}"
                f" plan {np.round(p[:, 0], 3).tolist()}"
            )
            reach = (
                f"distal pose from q_act vs command {r['reach_rad'] * 1e3:.2f} mrad, "
                if r["mode"] == "off"  # with compensation q_cmd is not the nominal q of psi
                else ""
            )
            print(
                f"  drives reached it: |q_act - q_cmd| max {r['follow_mm']:.3f} mm, {reach}"
                f"max cable speed {r['v_max']:.2f} mm/s (limit {r['v_limit']:.1f})"
            )
            t = r["tip"]
            print(
                f"  tracked tip vs model tip: mean {t['mean_mm']:.2f} mm, max {t['max_mm']:.2f} mm"
            )
    lat = lost_latency(a.trials)
    ms = sorted(x * 1e3 for x in lat)
    print(
        f"joystick lost -> joystick_lost trip (HALT), {len(ms)} trials: median"
        f" {statistics.median(ms):.1f} ms, max {ms[-1]:.1f} ms, min {ms[0]:.1f} ms"
    )


if __name__ == "__main__":
    main()
