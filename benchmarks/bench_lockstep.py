"""Lock-step simulated rig: speed factor (simulated s per wall s) and CPU per simulated cycle of
each part, over the Qi et al. 2023 planar bend (0 -> 90 deg at pi/10 rad/s) at the rig's 250 Hz.

    .venv/bin/python benchmarks/bench_lockstep.py [--sim-config config/sim/qi2023-truth.yaml]
        [--compensation model] [--repeat 1] [--truth-inline] [--no-parts]

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
    ap.add_argument(
        "--truth-inline",
        action="store_true",
        help="Solve the truth in the loop's process right after each SYNC (default: a worker "
        "process, one period behind)",
    )
    ap.add_argument(
        "--no-parts",
        action="store_true",
        help="Speed factor only: do not time the simulated parts (the per-part CPU clock reads, "
        "~1.5 us each, some 20 per cycle, are themselves a cost); as experiments and tests run",
    )
    args = ap.parse_args()
    loaded = load_sim_config(args.sim_config)
    ctl = load_rig_config(loaded.rig_path)
    traj = tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10)
    with tempfile.TemporaryDirectory() as tmp:
        s = LockstepSession.open(
            loaded, ctl, loaded.rig_path, tmp, truth_process=not args.truth_inline
        )
        try:
            s.rig.measure_cpu(not args.no_parts)
            send_cpu = [0.0]
            send = s.drives.send_cycle

            def timed_send(targets, send=send):
                c = time.thread_time()
                send(targets)
                send_cpu[0] += time.thread_time() - c

            if not args.no_parts:
                s.drives.send_cycle = timed_send  # the loop calls it through the port
            for i in range(args.repeat):
                rig, loop = s.rig, s.loop
                cyc0, t_sim0 = rig.clock.cycles, rig.clock.now()
                parts0 = rig.cpu_breakdown_s()
                solves0 = rig.truth_steps
                work0, send0 = loop.counters.work_cpu_s, send_cpu[0]
                w0, c0 = time.perf_counter(), time.process_time()
                run = s.run(traj, f"bench{i}", args.compensation)
                wall, cpu = time.perf_counter() - w0, time.process_time() - c0
                n = rig.clock.cycles - cyc0
                sim_s = rig.clock.now() - t_sim0
                p = {k: v - parts0[k] for k, v in rig.cpu_breakdown_s().items()}
                work = loop.counters.work_cpu_s - work0
                sent = send_cpu[0] - send0
                world_here = (
                    p["truth"]
                    + p["loadcells_modbus"]
                    + p["tracker_natnet"]
                    + p["attitude_witmotion"]
                )
                total = cpu + p["truth_worker"]
                us = 1e6 / max(n, 1)
                print(f"run {run.name}: {run.state}, {n} cycles = {sim_s:.2f} s simulated")
                print(f"  truth {'inline' if args.truth_inline else 'in a worker process'}")
                print(
                    f"  wall {wall:.2f} s -> speed factor {sim_s / wall:.1f}x real time; CPU "
                    f"{total:.2f} s ({total / wall * 100:.0f} % of one core, both processes)"
                )
                if args.no_parts:
                    continue
                print(f"  CPU per simulated cycle ({1e3 / ctl.control.rate_hz:.0f} ms period):")
                rows = [
                    ("loop (setpoint, model, checks, log row)", work - sent),
                    ("protocol: RPDO+SYNC encode/send", sent - p["sim_drives"] - p["tpdo_decode"]),
                    ("protocol: TPDO decode", p["tpdo_decode"]),
                    ("sim drives (nodes at RPDO/SYNC)", p["sim_drives"]),
                    ("sensors: Modbus RTU both ends", p["loadcells_modbus"]),
                    ("sensors: NatNet both ends", p["tracker_natnet"]),
                    ("sensors: WitMotion attitude both ends", p["attitude_witmotion"]),
                    ("truth (statics solves)", p["truth"] + p["truth_worker"]),
                    ("rest of the loop's process (writer, threads)", cpu - work - world_here),
                    ("total", total),
                ]
                for label, v in rows:
                    print(f"    {label:46s} {v * us:8.1f} us")
                solves = rig.truth_steps - solves0
                truth_s = p["truth"] + p["truth_worker"]
                print(
                    f"  truth: {solves} statics solves, {truth_s / max(solves, 1) * 1e6:.1f} us "
                    "CPU per solve (the solve without a loop beside it: benchmarks/bench_truth.py)"
                )
        finally:
            s.close()


if __name__ == "__main__":
    main()
