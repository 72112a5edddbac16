"""docs/operating/channels.md against the files: its channel table names every channel a
``run.mcap`` holds and the live view serves, with the schema each has and the fields of that
schema; every message in a file has those fields, ``t_s`` and ``cycle`` among them, as the page's
one statement says."""

from __future__ import annotations

import json
import math
import re
import time
from pathlib import Path

import can
import numpy as np
from mcap.reader import make_reader

from cdcr_ctl.runlog import sample_columns, streams
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS
from cdcr_ctl.runlog.live import LiveView
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP, McapSink
from cdcr_ctl.runlog.model_tip import ModelTip

PAGE = Path(__file__).resolve().parents[2] / "docs" / "operating" / "channels.md"
COLS = sample_columns(2, 3, (*LOOP_EXTRA_COLUMNS, "motor_temp_C"))
HEAD = {"t_s", "cycle"}


def _table() -> dict[str, dict]:
    """Topic -> schema, fields, in run.mcap, in the live view: the page's channel table."""
    rows = {}
    for line in PAGE.read_text(encoding="utf-8").splitlines():
        if not line.startswith("| `/"):
            continue
        topic, schema, fields, _per, in_file, live = (c.strip() for c in line.strip("|").split("|"))
        rows[topic.strip("`")] = {
            "schema": schema.strip("`"),
            # Field names: the backticked identifiers of the cell.
            "fields": set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", fields)),
            "file": in_file == "yes",
            "live": live == "yes",
        }
    return rows


def _write_run(path: Path) -> list[float]:
    """A run with a message on every channel; returns its CAN frames' timestamps."""
    sink = McapSink(path, COLS, model_tip=ModelTip(lambda psi: np.ones(3)))
    rows = []
    for i in range(50):
        d = {c: float(i) for c in COLS}
        d.update(t_s=i * 1e-3, cycle=i, event="tension_low: cable 1" if i == 9 else "")
        d["tip_y_mm"] = math.nan if i == 3 else d["tip_y_mm"]
        rows.append(d)
    stamps = [time.time(), 0.0]  # the second one unstamped, as a lock-step bus leaves frames
    sink.can_tap(can.Message(timestamp=stamps[0], arbitration_id=0x80, data=b""))  # before rows
    sink.write_rows(rows[:20])
    sink.can_tap(can.Message(timestamp=stamps[1], arbitration_id=0x181, data=b"\x01\x02"))
    sink.write_rows(rows[20:])
    sink.close("name: doc\n")
    return stamps


def test_the_channel_table_matches_run_mcap_and_the_live_view(tmp_path):
    table = _table()
    stamps = _write_run(tmp_path / RUN_MCAP)
    with open(tmp_path / RUN_MCAP, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        found = list(reader.iter_messages(log_time_order=False))
    messages = [(ch.topic, json.loads(m.data)) for _, ch, m in found]
    log_ns = {(ch.topic, json.loads(m.data)["cycle"]): m.log_time for _, ch, m in found}
    in_file = {ch.topic: summary.schemas[ch.schema_id] for ch in summary.channels.values()}
    assert {t for t, row in table.items() if row["file"]} == set(in_file)
    for topic, schema in in_file.items():
        row = table[topic]
        props = set(json.loads(schema.data)["properties"])
        assert schema.name == row["schema"], topic
        assert props == HEAD | row["fields"], (topic, props ^ (HEAD | row["fields"]))
    seen = {topic for topic, _ in messages}
    assert seen == set(in_file)  # the run above has a message on every channel
    for topic, msg in messages:  # the one statement: every message, t_s and cycle
        assert set(msg) == HEAD | table[topic]["fields"], (topic, msg)
        assert isinstance(msg["cycle"], int)
    can_msgs = [m for t, m in messages if t == streams.CAN]
    # /can: t_s and cycle of the last row written before the frame; its own time apart.
    assert [(m["t_s"], m["cycle"]) for m in can_msgs] == [(0.019, 19), (0.049, 49)]
    assert [m["timestamp_s"] for m in can_msgs] == stamps
    # Logged at its own time, or when unstamped at its row's (never at UNIX time 0).
    assert log_ns[(streams.CAN, 19)] == round(stamps[0] * 1e9)
    assert log_ns[(streams.CAN, 49)] == log_ns[(streams.COMMAND, 49)] > 0

    with LiveView(lambda: None, COLS, port=0) as live:
        served = {*live._channels, live._scene.topic()}
    assert {t for t, row in table.items() if row["live"]} == served
    assert table[streams.SCENE]["schema"] == "foxglove.SceneUpdate"


def test_the_page_states_what_every_message_carries():
    text = " ".join(PAGE.read_text(encoding="utf-8").split())
    statement = "Every message on every `cdcr.*` channel, in the file and on the wire, carries"
    assert f"{statement} `t_s` and `cycle`" in text
    assert "benchmarks/bench_runlog_size.py" in text
