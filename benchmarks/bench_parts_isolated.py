"""The lock-step loop process's parts, each timed alone (thread CPU, warm caches), and the model
timed inside a running session, to tell the code's own cost from what the session around it
adds (the Qi et al. 2023 rig of ``config/sim/qi2023-truth.yaml``, 250 Hz, truth inline).

    .venv/bin/python benchmarks/bench_parts_isolated.py [--repeat 5] [--n 3000]

Printed, each the least of ``--repeat`` rounds of ``--n`` calls (us per call, thread CPU):

- ``drives``: one cycle of ``DriveGroupPort.send_cycle`` on a homed lock-step rig with the loop
  paused: the three RPDOs and SYNC encoded, the three simulated EPOS nodes handling them and
  stepping 4 ms (16 plant sub-steps each), their TPDOs decoded (``bench_lockstep.py``'s
  "protocol" + "sim drives");
- ``modbus``: one load-cell transaction, both ends (the reader's request, the simulated
  transmitter's reply, the reader's decode, the sample published);
- ``natnet``: one tracker frame, both ends (made from the truth, packed, parsed, published);
- ``model``: the loop's model work for one cycle (``q_nominal``, ``q_command`` with compensation
  model, ``tip``) over the planar bend's set-points, alone; then the same calls timed in a
  lock-step session's loop thread (``in session``).

A lock-step cycle has one drives cycle, ~1.18 Modbus transactions (back to back at the bus's
wire time) and ~0.48 NatNet frames (120 Hz): per cycle alone they cost about ``drives + 1.18
modbus + 0.48 natnet + model``; ``bench_lockstep.py`` gives what they cost in a session.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.sensors.natnet import pack_frame_of_data
from cdcr_ctl.sim.lockstep.session import LockstepSession
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[1]
SIM = ROOT / "config/sim/qi2023-truth.yaml"


def least_us(fn: Callable[[int], None], n: int, repeat: int) -> float:
    """Least over ``repeat`` rounds of the thread CPU per call (us) of ``fn(k)``, k < n."""
    best = math.inf
    for _ in range(repeat):
        c0 = time.thread_time()
        for k in range(n):
            fn(k)
        best = min(best, (time.thread_time() - c0) / n * 1e6)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--n", type=int, default=3000)
    args = ap.parse_args()
    loaded = load_sim_config(str(SIM))
    ctl = load_rig_config(loaded.rig_path)
    traj = tj.planar_bend(theta_max_rad=math.pi / 2, rate_rad_s=math.pi / 10)
    psis = [np.asarray(traj.sample(k * 0.004), dtype=float) for k in range(1250)]
    out: dict[str, float] = {}
    with (
        tempfile.TemporaryDirectory() as tmp,
        LockstepSession.open(loaded, ctl, loaded.rig_path, tmp, truth_process=False) as s,
    ):
        s.loop.pause(True)
        time.sleep(0.05)  # the loop thread takes the pause up
        drives, lc, tr = s.drives, s.rig.loadcells, s.rig.tracker
        assert lc is not None and tr is not None
        base = [n.position_counts for n in s.rig.nodes]

        def drive_cycle(k: int) -> None:  # a 1.2 mm/s ramp back and forth (~3 counts/cycle)
            drives.send_cycle([b + (k % 400) * 3 for b in base])

        def modbus(k: int) -> None:
            got = lc.link.poll()
            if got:
                lc.sampler.publish(got, 1.0)

        server, reader = tr.server, tr.reader

        def natnet(k: int) -> None:
            frame = server.make_frame(1.0, transmit_s=1.004)
            reader.handle_datagram(pack_frame_of_data(frame, server.version), tr._source, 1.004)

        out["drives"] = least_us(drive_cycle, args.n, args.repeat)
        out["modbus"] = least_us(modbus, args.n, args.repeat)
        out["natnet"] = least_us(natnet, args.n, args.repeat)
        s.loop.pause(False)

    model = build_model(ctl, source=str(loaded.rig_path))
    state = model.new_state()

    def model_cycle(k: int) -> None:
        psi = psis[k % len(psis)]
        model.q_command(psi, model.q_nominal(psi), state, "model", None)
        model.tip(psi)

    out["model"] = least_us(model_cycle, len(psis), args.repeat)
    out["model in session"] = model_in_session(loaded, ctl, traj)
    per_cycle = out["drives"] + 1.18 * out["modbus"] + 0.48 * out["natnet"] + out["model"]
    for k, v in out.items():
        print(f"  {k:18s} {v:8.1f} us")
    print(f"  drives + 1.18 modbus + 0.48 natnet + model, alone: {per_cycle:.1f} us per cycle")


def model_in_session(loaded, ctl, traj) -> float:
    """The loop's model calls timed in the loop thread of a lock-step session (us per cycle,
    thread CPU, two clock reads per call included: ~1 us)."""
    acc = [0.0]
    with (
        tempfile.TemporaryDirectory() as tmp,
        LockstepSession.open(loaded, ctl, loaded.rig_path, tmp, truth_process=False) as s,
    ):
        for name in ("q_nominal", "q_command", "tip"):
            fn = getattr(s.model, name)

            def timed(*a, fn=fn):
                c0 = time.thread_time()
                try:
                    return fn(*a)
                finally:
                    acc[0] += time.thread_time() - c0

            setattr(s.model, name, timed)
        c0 = s.rig.clock.cycles
        s.run(traj, "model-in-session", "model")
        return acc[0] / max(s.rig.clock.cycles - c0, 1) * 1e6


if __name__ == "__main__":
    main()
