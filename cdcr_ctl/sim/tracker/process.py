"""The simulated tracker a rig config expects, and ``python -m cdcr_ctl.sim.tracker``."""

from __future__ import annotations

import argparse
import contextlib
import math
import threading
import time
from typing import Any

import numpy as np

from cdcr_ctl.config.tracking import TrackerConfig
from cdcr_ctl.sim.simconfig import SimConfig
from cdcr_ctl.sim.tracker.feed import Truth, true_transform
from cdcr_ctl.sim.tracker.natnet_server import SimNatNetServer
from cdcr_ctl.sim.tracker.server import require_loopback
from cdcr_ctl.sim.tracker.stream_server import SimLineStreamServer


def sim_tracker_from_config(
    truth: Truth, tracker: TrackerConfig, sim: SimConfig
) -> SimNatNetServer | SimLineStreamServer:
    """The simulated tracker the controller's ``tracker`` section expects, with the simulator's
    rate, latency, dropout (``sim.tracker``), noise (``sim.noise.tracker_mm``), frame offset
    (``sim.effects.tracker_offset``) and seed. ``truth`` returns the tip pose in the base frame.

    NatNet: serves on ``tracker.host``:``tracker.command_port``; UDP stream: sends to
    ``tracker.host``:``tracker.port``; TCP stream: listens there. Not started.
    """
    transform = true_transform(tracker, sim.effects.tracker_offset)
    common: dict[str, Any] = {
        "transform": transform,
        "truth_frame": "base",
        "rate_hz": sim.tracker.rate_hz,
        "latency_s": sim.tracker.latency_s,
        "noise_mm": sim.noise.tracker_mm,
        "dropout": sim.tracker.dropout,
        "seed": sim.seed,
    }
    if tracker.kind == "natnet":
        return SimNatNetServer(
            truth,
            host=tracker.host,
            command_port=tracker.command_port,
            rigid_body_id=tracker.rigid_body_id,
            **common,
        )
    if tracker.kind == "udp_stream":
        return SimLineStreamServer(
            truth,
            transport="udp",
            target=(require_loopback(tracker.host), tracker.port),
            with_orientation=True,
            **common,
        )
    return SimLineStreamServer(
        truth,
        transport="tcp",
        host=tracker.host,
        port=tracker.port,
        with_orientation=True,
        **common,
    )


def main(argv: list[str] | None = None) -> int:
    """``python -m cdcr_ctl.sim.tracker``: serve a tip moving on a circle (base frame, mm).

    Prints ``command_port data_port`` on one line once serving, then runs until interrupted.
    """
    ap = argparse.ArgumentParser(prog="python -m cdcr_ctl.sim.tracker", description=main.__doc__)
    ap.add_argument("--command-port", type=int, default=0)
    ap.add_argument("--data-port", type=int, default=0)
    ap.add_argument("--rate-hz", type=float, default=120.0)
    ap.add_argument("--latency-s", type=float, default=0.0)
    ap.add_argument("--noise-mm", type=float, default=0.0)
    ap.add_argument("--dropout", type=float, default=0.0)
    ap.add_argument("--radius-mm", type=float, default=20.0)
    ap.add_argument("--duration-s", type=float, default=math.inf)
    args = ap.parse_args(argv)
    t0 = time.monotonic()

    def truth() -> np.ndarray:
        t = time.monotonic() - t0
        return np.array([args.radius_mm * math.cos(t), args.radius_mm * math.sin(t), 150.0])

    server = SimNatNetServer(
        truth,
        command_port=args.command_port,
        data_port=args.data_port,
        rate_hz=args.rate_hz,
        latency_s=args.latency_s,
        noise_mm=args.noise_mm,
        dropout=args.dropout,
    )
    with server:
        print(server.command_address[1], server.data_address[1], flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            threading.Event().wait(args.duration_s if math.isfinite(args.duration_s) else None)
    return 0
