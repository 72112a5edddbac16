"""The simulated transmitters from a rig config, or as their own process (``python -m``).

``python -m cdcr_ctl.sim.loadcells`` prints the pty path on its first line of output and serves
until SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from cdcr_ctl.config.loadcells import LoadCellsConfig, ModbusRegisterMap
from cdcr_ctl.sim.loadcells.ascii import AsciiLoadCellSim
from cdcr_ctl.sim.loadcells.feed import SensorNoise, Tensions
from cdcr_ctl.sim.loadcells.modbus import ModbusLoadCellSim
from cdcr_ctl.sim.loadcells.pty import PtySim


def sim_for_config(
    lc: LoadCellsConfig,
    tensions: Tensions,
    *,
    noise: SensorNoise | None = None,
    link: str | Path | None = None,
    emulate_baud: bool = True,
    clock: Callable[[], float] = time.monotonic,
) -> PtySim:
    """The simulated transmitter(s) a rig config's ``sensors.load_cells`` section talks to (not
    started): its protocol, slave addresses (in ``cells`` order: ``tensions()[i]`` is
    ``cells[i]``), register map and baud rate. ``link`` defaults to nothing; pass
    ``lc.serial.port`` to put the pty where the controller's config looks for it."""
    if lc.protocol == "modbus_rtu":
        return ModbusLoadCellSim(
            tensions,
            [c.slave for c in lc.cells],
            lc.register_map,
            baudrate=lc.serial.baudrate,
            emulate_baud=emulate_baud,
            noise=noise,
            link=link,
            clock=clock,
        )
    return AsciiLoadCellSim(
        tensions,
        unit=lc.register_map.unit,
        decimals=lc.register_map.decimals,
        baudrate=lc.serial.baudrate,
        emulate_baud=emulate_baud,
        noise=noise,
        link=link,
        clock=clock,
    )


# -- standalone process ----------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m cdcr_ctl.sim.loadcells",
        description="Simulated load-cell transmitters on a pty; prints the pty path first.",
    )
    p.add_argument(
        "--rig",
        help="rig YAML: protocol, slaves, register map, baud and port "
        "(as --link) from its sensors.load_cells",
    )
    p.add_argument("--protocol", choices=["modbus_rtu", "ascii"], default=None)
    p.add_argument("--slaves", type=int, nargs="+", default=None, help="Modbus slave addresses")
    p.add_argument(
        "--tension-N",
        type=float,
        nargs="+",
        default=[5.0],
        help="truth tension per cell (N); one value is used for every cell",
    )
    p.add_argument("--amplitude-N", type=float, default=0.0, help="sine added to the truth (N)")
    p.add_argument("--period-s", type=float, default=2.0, help="period of that sine (s)")
    p.add_argument("--noise-N", type=float, default=0.0)
    p.add_argument("--drift-N-per-s", type=float, default=0.0)
    p.add_argument("--dropout", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--baudrate", type=int, default=None)
    p.add_argument(
        "--no-baud-emulation",
        action="store_true",
        help="answer at once instead of at the pace of the baud rate",
    )
    p.add_argument("--turnaround-s", type=float, default=0.0, help="slave think time (s)")
    p.add_argument(
        "--silence-s",
        type=float,
        default=None,
        help="end-of-request silence (s); default t3.5 of the Modbus spec",
    )
    p.add_argument("--rate-hz", type=float, default=None, help="ASCII lines per second")
    p.add_argument("--link", help="make this symlink to the pty")
    p.add_argument("--duration-s", type=float, default=None, help="exit after this long")
    return p


def build_sim(args: argparse.Namespace, clock: Callable[[], float] = time.monotonic) -> PtySim:
    """The simulator the command line asks for (not started)."""
    protocol, slaves, register_map = "modbus_rtu", [1, 2, 3], ModbusRegisterMap()
    baudrate, link = 115200, args.link
    if args.rig:
        from cdcr_ctl.config.loader import load_rig_config

        lc = load_rig_config(args.rig).sensors.load_cells
        if lc is None:
            raise SystemExit(f"{args.rig}: no sensors.load_cells section")
        protocol, register_map = lc.protocol, lc.register_map
        slaves, baudrate = [c.slave for c in lc.cells], lc.serial.baudrate
        link = link or lc.serial.port
    protocol = args.protocol or protocol
    slaves = args.slaves or slaves
    baudrate = args.baudrate or baudrate
    n = len(slaves) if protocol == "modbus_rtu" else 1
    base = list(args.tension_N) * n if len(args.tension_N) == 1 else list(args.tension_N)
    if len(base) != n:
        raise SystemExit(f"--tension-N needs 1 or {n} values, got {len(base)}")
    t0 = clock()
    amp, period = args.amplitude_N, args.period_s

    def tensions() -> list[float]:
        wave = amp * math.sin(2 * math.pi * (clock() - t0) / period) if amp else 0.0
        return [b + wave for b in base]

    noise = SensorNoise(args.noise_N, args.drift_N_per_s, args.dropout, args.seed)
    emulate = not args.no_baud_emulation
    if protocol == "modbus_rtu":
        return ModbusLoadCellSim(
            tensions,
            slaves,
            register_map,
            baudrate=baudrate,
            emulate_baud=emulate,
            silence_s=args.silence_s,
            turnaround_s=args.turnaround_s,
            noise=noise,
            link=link,
            clock=clock,
        )
    return AsciiLoadCellSim(
        tensions,
        unit=register_map.unit,
        decimals=register_map.decimals,
        rate_hz=args.rate_hz,
        baudrate=baudrate,
        emulate_baud=emulate,
        noise=noise,
        link=link,
        clock=clock,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Run the simulator until SIGINT/SIGTERM (or ``--duration-s``); print the pty path first."""
    args = _parser().parse_args(argv)
    sim = build_sim(args)
    stop = threading.Event()

    def on_signal(_sig: int, _frame: object) -> None:
        stop.set()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
    print(sim.path, flush=True)
    if sim.pty.link is not None:
        print(f"linked {sim.pty.link} -> {sim.path}", file=sys.stderr, flush=True)
    with sim:
        stop.wait(args.duration_s)
    print(f"stats {sim.stats}", file=sys.stderr, flush=True)
    return 0
