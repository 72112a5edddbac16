"""Load-cell sample rate: 3 Modbus RTU cells on one 115200 bit/s bus, and one ASCII stream.

Runs the simulated transmitters as their own process (``python -m cdcr_ctl.sim.loadcells``, so
they do not share the reader's interpreter lock), reads them with the production sampler
(:func:`cdcr_ctl.sensors.loadcell_sampler.open_load_cells`) for ``--duration-s`` seconds, and
prints the achieved rate beside the theoretical limit of the baud rate:

    per polled cell: request 8 bytes + reply (5 + 2 * registers) bytes, 10 bits per character
    (8N1: start + 8 data + stop), plus the t3.5 inter-frame silence at each end (before the
    slave answers and before the master's next request).

Two silences are measured: 3.5 character times (0.30 ms at 115200), and the 1.75 ms the Modbus
serial-line spec fixes for t3.5 above 19200 bit/s (what the reader uses by default). The pty
carries bytes instantly, so the simulator paces its replies as the wire would; a third run turns
that pacing off to show what the software alone achieves. Usage::

    .venv/bin/python benchmarks/bench_loadcells.py [--duration-s 3]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdcr_ctl.config.loadcells import LoadCellsConfig, ModbusRegisterMap  # noqa: E402
from cdcr_ctl.sensors.loadcell_modbus import (  # noqa: E402
    READ_REQUEST_BYTES,
    SPEC_T35_FIXED_S,
    char_time_s,
    plan_read,
)
from cdcr_ctl.sensors.loadcell_sampler import open_load_cells  # noqa: E402

BAUD = 115200
SLAVES = (1, 2, 3)


def theory(register_map: ModbusRegisterMap, silence_s: float) -> tuple[float, str]:
    """(bus transactions per second, explanation) for one polled cell at ``BAUD``."""
    plan = plan_read(register_map)
    char_s = char_time_s(BAUD)
    chars = READ_REQUEST_BYTES + plan.reply_bytes
    t_s = chars * char_s + 2 * silence_s
    text = (
        f"({READ_REQUEST_BYTES} + {plan.reply_bytes}) chars x {char_s * 1e6:.2f} us"
        f" + 2 x {silence_s * 1e3:.3f} ms silence = {t_s * 1e3:.3f} ms/transaction"
    )
    return 1.0 / t_s, text


def spawn_sim(*args: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cdcr_ctl.sim.loadcells", "--duration-s", "600", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=ROOT,
    )
    return proc, proc.stdout.readline().strip()


def measure(
    path: str, protocol: str, n_cells: int, inter_frame_s: float | None, duration_s: float
) -> tuple[list[float], object]:
    cfg = LoadCellsConfig.model_validate(
        {
            "protocol": protocol,
            "serial": {"port": path, "baudrate": BAUD, "timeout_s": 0.05},
            "cells": [{"cable": f"c{i + 1}", "slave": s} for i, s in enumerate(SLAVES[:n_cells])],
            "inter_frame_s": inter_frame_s,
            "stale_after_s": 1.0,
        }
    )
    with open_load_cells(cfg) as cells:
        cells.wait_for_samples(3, timeout_s=5.0)
        seq0, t0 = [s.seq for s in cells.latest()], time.monotonic()
        time.sleep(duration_s)
        seq1, t1 = [s.seq for s in cells.latest()], time.monotonic()
        stats = cells.stats
    return [(b - a) / (t1 - t0) for a, b in zip(seq0, seq1, strict=True)], stats


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=3.0)
    args = ap.parse_args(argv)
    rm = ModbusRegisterMap()
    char_s = char_time_s(BAUD)
    plan = plan_read(rm)
    print(f"Load cells at {BAUD} bit/s, 8N1 (10 bits/char = {char_s * 1e6:.2f} us/char).")
    print(
        f"Register map: int32 value at {rm.value_register} + decimals at {rm.decimals_register}"
        f" -> one read of {plan.count} registers; reply {plan.reply_bytes} bytes."
    )
    print(f"{len(SLAVES)} cells polled round robin; per-cell rate = bus rate / {len(SLAVES)}.")
    print(f"Machine: {os.cpu_count()} CPUs; simulator in its own process on a pty.\n")

    runs = [
        ("3.5-char silences", ["--silence-s", f"{3.5 * char_s}"], 3.5 * char_s, 3.5 * char_s),
        ("spec t3.5 = 1.75 ms (default)", [], None, SPEC_T35_FIXED_S),
        ("no wire pacing (software only)", ["--no-baud-emulation", "--silence-s", "0"], 0.0, None),
    ]
    header = f"{'case':34s} {'per cell (Hz)':>22s} {'bus (1/s)':>10s} {'limit bus':>10s} {'%':>5s}"
    print(header)
    print("-" * len(header))
    notes = []
    for name, sim_args, inter_frame_s, silence_s in runs:
        proc, path = spawn_sim("--slaves", *map(str, SLAVES), *sim_args)
        try:
            rates, stats = measure(path, "modbus_rtu", len(SLAVES), inter_frame_s, args.duration_s)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(10)
        bus = sum(rates)
        if silence_s is not None:
            limit, text = theory(rm, silence_s)
            notes.append(
                f"  {name}: {text} -> {limit:.1f}/s, {limit / len(SLAVES):.1f} Hz per cell"
            )
            pct = f"{100 * bus / limit:5.1f}"
            lim = f"{limit:10.1f}"
        else:
            pct, lim = "    -", "         -"
        per = "/".join(f"{r:.1f}" for r in rates)
        print(f"{name:34s} {per:>22s} {bus:10.1f} {lim} {pct}   {stats}")

    proc, path = spawn_sim("--protocol", "ascii")
    try:
        rates, stats = measure(path, "ascii", 1, None, args.duration_s)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
    line = len(b"ST,GS,+  4.876kg\r\n")
    limit = 1.0 / (line * char_s)
    print(
        f"{'ASCII stream, 1 cell':34s} {rates[0]:22.1f} {rates[0]:10.1f} {limit:10.1f}"
        f" {100 * rates[0] / limit:5.1f}   {stats}"
    )
    print("\nTheoretical limits:")
    print("\n".join(notes))
    print(f"  ASCII: {line} chars/line x {char_s * 1e6:.2f} us = {line * char_s * 1e3:.3f} ms/line")
    print(
        "\nA pty has no baud timing: the simulator sleeps until the last reply byte would have"
        "\narrived on a real line, so the paced rows approximate a real bus minus USB-adapter"
        "\nlatency (an FTDI adapter adds 1-16 ms per reply unless its latency timer is lowered)"
        "\nand minus the transmitter's own turnaround, both of which lower a real rig's rate."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
