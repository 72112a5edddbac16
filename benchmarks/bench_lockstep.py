"""Lock-step simulated rig: speed factor (simulated s per wall s) and CPU per simulated cycle of
each part, over the Qi et al. 2023 planar bend (0 -> 90 deg at pi/10 rad/s) at the rig's 250 Hz.

    .venv/bin/python benchmarks/bench_lockstep.py [--sim-config config/sim/qi2023-truth.yaml]
        [--compensation model] [--repeat 1]

One process: the controller's loop, drive layer (CANopen), Modbus RTU reader and NatNet parser,
the simulated EPOS nodes, transmitters, tracker and truth (cdcr_ctl.sim.lockstep). Parts:
``loop`` = the loop thread's cycle work minus what it spends in the simulated drives, the TPDO
decoding and the sensors; ``protocol`` = RPDO/SYNC encode (the loop's send stage minus the
nodes) + TPDO decode; ``sim drives`` = the nodes handling the frames and stepping at SYNC;
``sensors`` = Modbus and NatNet traffic, both ends; ``truth`` = the world's statics solves.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.sim.lockstep.session import LockstepSession
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sim-config", default=str(ROOT / "config/sim/qi2023-truth.yaml"))
    ap.add_argument("--compensation", default="model", choices=["off", "model", "measured"])
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    loaded = load_sim_config(args.sim_config)
    ctl = load_rig_config(loaded.rig_path)
    traj = tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10)
    with tempfile.TemporaryDirectory() as tmp:
        s = LockstepSession.open(loaded, ctl, loaded.rig_path, tmp)
        try:
            for i in range(args.repeat):
                rig, loop = s.rig, s.loop
                cyc0, t_sim0 = rig.clock.cycles, rig.clock.now()
                parts0 = rig.cpu_breakdown_s()
                work0, send0 = loop.counters.work_cpu_s, loop.counters.stage_s["send"]
                w0, c0 = time.perf_counter(), time.process_time()
                run = s.run(traj, f"bench{i}", args.compensation)
                wall, cpu = time.perf_counter() - w0, time.process_time() - c0
                n = rig.clock.cycles - cyc0
                sim_s = rig.clock.now() - t_sim0
                parts = {k: v - parts0[k] for k, v in rig.cpu_breakdown_s().items()}
                work = loop.counters.work_cpu_s - work0
                send = loop.counters.stage_s["send"] - send0
                sensors = parts["loadcells_modbus"] + parts["tracker_natnet"]
                world = parts["truth"] + sensors  # in the clock's wait, outside the cycle work
                us = 1e6 / max(n, 1)
                print(f"run {run.name}: {run.state}, {n} cycles = {sim_s:.2f} s simulated")
                print(
                    f"  wall {wall:.2f} s -> speed factor {sim_s / wall:.1f}x real time; "
                    f"process CPU {cpu:.2f} s ({cpu / wall * 100:.0f} % of one core)"
                )
                print(f"  CPU per simulated cycle ({1e3 / ctl.control.rate_hz:.0f} ms period):")
                rows = [
                    ("loop (setpoint, model, checks, log row)", work - send),
                    (
                        "protocol: RPDO+SYNC encode/send",
                        send - parts["sim_drives"] - parts["tpdo_decode"],
                    ),
                    ("protocol: TPDO decode", parts["tpdo_decode"]),
                    ("sim drives (nodes at RPDO/SYNC)", parts["sim_drives"]),
                    ("sensors: Modbus RTU both ends", parts["loadcells_modbus"]),
                    ("sensors: NatNet both ends", parts["tracker_natnet"]),
                    ("truth (statics solves)", parts["truth"]),
                    ("rest (writer, threads, waits)", cpu - work - world),
                ]
                for label, v in rows:
                    print(f"    {label:42s} {v * us:8.1f} us")
        finally:
            s.close()


if __name__ == "__main__":
    main()
