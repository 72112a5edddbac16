"""Benchmark (not a test): bytes per row of ``samples.csv`` and ``run.mcap`` for the same rows.

Replays a logged run (its ``samples.csv`` rows and, when present, the CAN frames of its
``can.asc``) through the run-log writer with the MCAP sink attached, at full speed, and prints
the size per logged row of each file, the hourly size at 1 kHz (bytes per row x 3.6 M rows), and
the process CPU time per row (replay and writer thread) for the CSV alone and with ``run.mcap``.
``run.mcap`` is written twice: as the sink writes it (every index, message indexes included)
and without message indexes, the difference being their cost.

    .venv/bin/python benchmarks/bench_runlog_size.py [RUN_DIR]

Without RUN_DIR it makes a 60 s run of the simulated Qi rig at 100 Hz with load-cell and tracker
noise (``scripts/make_discrepancy_runs.py``, no CAN traffic) and replays that.
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
import time
from pathlib import Path

import can
import numpy as np
from mcap.writer import IndexType

from cdcr_ctl.runlog import load_run
from cdcr_ctl.runlog.mcap_sink import INDEXES, McapSinkFactory
from cdcr_ctl.runlog.writer import RunLogWriter, RunMetadata

ROOT = Path(__file__).resolve().parents[1]


def make_source(tmp: Path) -> Path:
    spec = importlib.util.spec_from_file_location(
        "make_discrepancy_runs", ROOT / "scripts" / "make_discrepancy_runs.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return Path(
        mod.make_run(
            ROOT / "config" / "sim" / "effects" / "none.yaml",
            tmp,
            duration_s=60.0,
            rate_hz=100.0,
            trajectory="rich",
            seed=1,
            name="size",
        )
    )


#: The indexes of ``run.mcap`` without message indexes.
NO_MESSAGE_INDEX = INDEXES & ~IndexType.MESSAGE


def replay(
    src, out: Path, mcap: bool, index_types: IndexType = INDEXES
) -> tuple[dict[str, float], int]:
    run = load_run(src)
    frames = list(can.LogReader(str(run.can_log))) if run.can_log is not None else []
    cols = [run.data[c] for c in run.columns]
    rows = [
        [None if (isinstance(v, float) and np.isnan(v)) else v for v in (a[i] for a in cols)]
        for i in range(len(run))
    ]
    w = RunLogWriter(
        out,
        run.columns,
        RunMetadata(name="size", rate_hz=1000.0),
        second_sink=McapSinkFactory(None, 1000.0, index_types) if mcap else None,
        max_queued_rows=len(rows) + 1,
    )
    per_row = max(1, len(frames) // max(1, len(rows)))
    for i, row in enumerate(rows):
        w.write(row)
        if mcap:
            for m in frames[i * per_row : (i + 1) * per_row]:
                w.can_tap.on_message_received(m)
    w.close("done")
    sizes = {p.name: p.stat().st_size / len(rows) for p in out.iterdir() if p.name != "run.yaml"}
    return sizes, len(frames)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(argv[0]) if argv else make_source(Path(tmp) / "src")
        n = len(load_run(src))
        cpu: dict[str, float] = {}
        sizes: dict[str, float] = {}
        variants = (
            ("csv", False, INDEXES),
            ("mcap, message indexes", True, INDEXES),
            ("mcap, no message indexes", True, NO_MESSAGE_INDEX),
        )
        for label, mcap, index_types in variants:
            t = time.process_time()
            got, n_frames = replay(src, Path(tmp) / label.replace(" ", ""), mcap, index_types)
            cpu[label] = time.process_time() - t
            if not mcap:
                sizes["samples.csv"] = got["samples.csv"]
            else:
                sizes[f"run.mcap ({label[6:]})"] = got["run.mcap"]
    print(f"source: {src} ({n} rows, {n_frames} CAN frames replayed into run.mcap's /can)")
    for name, b in sizes.items():
        print(f"{name}: {b:.0f} B/row = {b * 3.6e6 / 1e6:.0f} MB/h at 1 kHz")
    print(
        "process CPU per row (replay + writer thread): "
        + ", ".join(f"{label} {1e6 * c / n:.0f} us" for label, c in cpu.items())
    )


if __name__ == "__main__":
    main()
