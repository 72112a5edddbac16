"""Benchmark (not a test): bytes per row of ``samples.csv`` and ``run.mcap`` for the same rows.

Replays a logged run (its ``samples.csv`` rows and, when present, the CAN frames of its
``can.asc``) through the run-log writer with the MCAP sink attached, at full speed, and prints
the size per logged row of each file, the hourly size at 1 kHz (bytes per row x 3.6 M rows), and
the writer thread's CPU time per row with and without the MCAP sink.

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

from cdcr_ctl.runlog import load_run
from cdcr_ctl.runlog.mcap_sink import McapSinkFactory
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


def replay(src, out: Path, mcap: bool) -> tuple[dict[str, float], int]:
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
        second_sink=McapSinkFactory(None, 1000.0) if mcap else None,
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
        t = time.process_time()
        replay(src, Path(tmp) / "csv", mcap=False)
        cpu_csv = time.process_time() - t
        t = time.process_time()
        sizes, n_frames = replay(src, Path(tmp) / "mcap", mcap=True)
        cpu_mcap = time.process_time() - t
    print(f"source: {src} ({n} rows, {n_frames} CAN frames replayed into run.mcap's /can)")
    for name, b in sizes.items():
        print(f"{name}: {b:.0f} B/row = {b * 3.6e6 / 1e6:.0f} MB/h at 1 kHz")
    print(
        f"process CPU per row (replay + writer thread): csv {1e6 * cpu_csv / n:.0f} us, "
        f"csv + mcap {1e6 * cpu_mcap / n:.0f} us"
    )


if __name__ == "__main__":
    main()
