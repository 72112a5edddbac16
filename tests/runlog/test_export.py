"""`cdcr-ctl export`: CSV and Parquet of a run.mcap, and its CAN frames as a candump log that
python-can's player replays."""

from __future__ import annotations

import subprocess
import sys

import can
import numpy as np
import pyarrow.parquet as pq

from cdcr_ctl.cli.main import main
from cdcr_ctl.runlog import load_run
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP, McapSink

COLS = sample_columns(1, 3, LOOP_EXTRA_COLUMNS)


def _mcap_run(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    sink = McapSink(run_dir / RUN_MCAP, COLS, attachments={"config.yaml": "name: x\n"})
    rows = []
    for i in range(50):
        d = {c: 0.25 * i + j for j, c in enumerate(COLS)}
        d.update(cycle=i, t_s=i * 0.004, event="")
        rows.append(d)
        for cob, data, rx in ((0x80, b"", False), (0x201, bytes([i, 1, 2, 3]), False),
                              (0x181, bytes([0x37, 0x06, i, 0, 0, 0]), True)):  # fmt: skip
            sink.can_tap.on_message_received(
                can.Message(
                    timestamp=1000.0 + i * 0.004,
                    arbitration_id=cob,
                    data=data,
                    is_extended_id=False,
                    is_rx=rx,
                )
            )
    sink.write_rows(rows)
    sink.close("name: x\nended: {outcome: completed}\n")
    return run_dir, rows


def test_csv_parquet_and_candump_of_an_mcap_run(tmp_path):
    run_dir, rows = _mcap_run(tmp_path)
    out = tmp_path / "out"
    assert main(["export", str(run_dir), "--csv", "--parquet", "--out", str(out)]) == 0
    csv_run = load_run(out)
    assert (out / "config.yaml").read_text() == "name: x\n"  # from the MCAP attachment
    assert csv_run.metadata["ended"]["outcome"] == "completed"
    assert np.array_equal(csv_run.column("cable2_q_cmd_mm"), [r["cable2_q_cmd_mm"] for r in rows])
    table = pq.read_table(out / "samples.parquet")
    assert table.column_names == COLS
    assert table.column("t_s").to_pylist() == [r["t_s"] for r in rows]

    frames = list(can.LogReader(str(out / "can.log")))
    assert len(frames) == 150
    assert [f.arbitration_id for f in frames[:3]] == [0x80, 0x201, 0x181]
    assert bytes(frames[4].data) == bytes([1, 1, 2, 3])
    assert frames[2].is_rx and not frames[1].is_rx
    # python-can's own player replays it (onto a virtual bus).
    res = subprocess.run(
        [sys.executable, "-m", "can.player", "-i", "virtual", "-c", "export-test",
         "--ignore-timestamps", str(out / "can.log")],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr


def test_export_needs_a_format(tmp_path):
    run_dir, _ = _mcap_run(tmp_path)
    assert main(["export", str(run_dir)]) == 2
