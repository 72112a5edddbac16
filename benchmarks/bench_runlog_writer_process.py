"""The run-log writer process's three costs per run (Qi rig columns, ``run.mcap`` on):

1. start: CPU (user + system, s) of a writer process from ``python -c _BOOT`` to waiting for its
   settings (then its stdin is closed and it exits), as the factory's spare;
2. rows: CPU per row (us, ``time.thread_time``) of what the writer process does with a loop row,
   in this process: the ring slot back to a row (``RingDrain``), ``samples.csv``'s line and
   ``run.mcap``'s messages, in drains of ``--batch`` rows;
3. close: wall (ms) from ``close(wait=False)`` to ``wait_closed`` returning, once the writer
   has written every row (a run's end in lock-step: ``LockstepSession.run``).

    PYTHONPATH=<tree> .venv/bin/python benchmarks/bench_runlog_writer_process.py [--runs 5]

Run it from outside the trees (``python -c`` puts the working directory first on the writer
process's path) against two trees alternately (CPU, not wall, is the measure on a shared
machine; the close's wall depends on the writer getting a CPU at nice 10).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.mcap_sink import McapSinkFactory
from cdcr_ctl.runlog.writer.child import RingDrain
from cdcr_ctl.runlog.writer.factory import RunLogFactory
from cdcr_ctl.runlog.writer.files import RunMetadata
from cdcr_ctl.runlog.writer.ring import RingLayout, SharedRing
from cdcr_ctl.runlog.writer.slots import SlotFiller
from cdcr_ctl.runlog.writer.spawn import start_writer_process
from cdcr_ctl.runlog.writer.thread import RunLogWriter

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config/qi2023-sim.yaml"
HEAD = ("t_s", "cycle", "lateness_us", "event")


class Row:
    """A loop row (``row_parts``, as the loop's ``CycleRow``) with varied full-precision floats."""

    def __init__(self, keys: tuple[str, ...], k: int) -> None:
        self.keys, self.k = keys, k
        self.values = np.sin(np.arange(len(keys)) * 0.7 + k * 0.013) * (10.0 + k % 7)

    def row_parts(self) -> tuple:
        return self.keys, self.values, self.k * 0.004, self.k, 1.234e-6, ""


def start_cpu(runs: int) -> list[float]:
    out = []
    for _ in range(runs):
        p = start_writer_process()
        p.stdin.close()
        _, _, ru = os.wait4(p.pid, 0)
        p.returncode = 0
        out.append(ru.ru_utime + ru.ru_stime)
    return out


def row_cpu_us(columns: list[str], n_rows: int, batch: int, tmp: Path) -> float:
    keys = tuple(c for c in columns if c not in HEAD)
    rows = [Row(keys, k) for k in range(n_rows)]
    meta = RunMetadata(name="b", rig="r", design="d", compensation="c", rate_hz=250.0)
    tmp.mkdir(parents=True)
    RunLogWriter.make_start_files(
        tmp, columns, meta, config_text="a: 1\n", config_source="", extra_files=None,
        fsync_every_s=0.5,
    )  # fmt: skip
    ring = SharedRing.create(RingLayout(len(columns) - 1, n_rows + 1, 16))
    fill = SlotFiller(ring, columns, tmp).fill
    for k, row in enumerate(rows):
        fill(row, k)
    kw = {"yield_gil": False} if "yield_gil" in RunLogWriter.__init__.__code__.co_varnames else {}
    w = RunLogWriter(
        tmp, columns, meta, config_text="a: 1\n", fsync_every_s=1e6, drain_interval_s=1e6,
        max_queued_rows=10 * n_rows, second_sink=McapSinkFactory(None, 250.0),
        require_empty=False, files_made=True, **kw,
    )  # fmt: skip
    drain = RingDrain(ring, w, columns)
    t0 = time.thread_time()
    for lo in range(0, n_rows, batch):
        ring.hq[0] = min(lo + batch, n_rows)
        drain.all()
        w._drain()  # the writer thread's drain, here (its thread waits for the close)
    cpu = time.thread_time() - t0
    w.close("done", outcome="completed")
    return cpu / n_rows * 1e6


def close_ms(runs: int, n_rows: int, tmp: Path) -> list[float]:
    cfg = load_rig_config(str(CONFIG))
    factory = RunLogFactory.from_config(cfg, CONFIG, base_dir=tmp, on_full="wait")
    out = []
    try:
        for i in range(runs):
            time.sleep(1.0)  # the spare's imports done
            w = factory(f"close{i}", "model")
            keys = tuple(c for c in w.columns if c not in HEAD)
            for k in range(n_rows):
                w.write(Row(keys, k))
            while w.stats.written < n_rows:
                time.sleep(0.01)
            time.sleep(0.2)
            t0 = time.monotonic()
            w.close("done", outcome="completed", wait=False)
            w.wait_closed(30.0)
            out.append((time.monotonic() - t0) * 1e3)
    finally:
        factory.close_spare()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--rows", type=int, default=5000)
    ap.add_argument("--batch", type=int, default=12, help="rows a drain (50 ms at 250 Hz)")
    args = ap.parse_args()
    cfg = load_rig_config(str(CONFIG))
    columns = sample_columns(len(cfg.robot.segments), len(cfg.robot.cables), LOOP_EXTRA_COLUMNS)
    s = start_cpu(args.runs)
    print(f"start: CPU {min(s):.3f} s min, {statistics.median(s):.3f} s median ({args.runs} runs)")
    with tempfile.TemporaryDirectory() as tmp:
        r = [row_cpu_us(columns, args.rows, args.batch, Path(tmp) / f"r{i}") for i in range(3)]
        print(
            f"rows: {min(r):.1f} us CPU a row min of 3 ({args.rows} rows, drains of {args.batch})"
        )
        c = close_ms(args.runs, 1250, Path(tmp) / "close")
        print(f"close: {min(c):.0f} ms min, {statistics.median(c):.0f} ms median "
              f"({', '.join(f'{v:.0f}' for v in c)})")  # fmt: skip


if __name__ == "__main__":
    main()
