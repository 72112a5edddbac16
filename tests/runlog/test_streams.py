"""The run log's channels: schemas with units, rows to messages and back, a cut file, the layout."""

from __future__ import annotations

import json
import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.opcode import Opcode

from cdcr_ctl.errors import ConfigError
from cdcr_ctl.runlog import load_run, streams
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.mcap_reader import read_mcap
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP, McapSink
from cdcr_ctl.runlog.model_tip import ModelTip

ROOT = Path(__file__).resolve().parents[2]
COLS = sample_columns(2, 6, LOOP_EXTRA_COLUMNS)
floats = st.floats(allow_nan=True, allow_infinity=False, width=64)


def test_every_number_in_every_schema_names_its_unit():
    unit = re.compile(r"^(mm|N|rad|s|µs): ")
    for topic, (name, schema) in streams.SCHEMAS.items():
        assert name.startswith("cdcr.")
        for field, spec in schema["properties"].items():
            if spec.get("type") in ("number", ["number", "null"], "array"):
                assert unit.match(spec.get("description", "")), (topic, field)


def _rows(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        d = {c: float(rng.normal()) for c in COLS}
        d["t_s"] = round(i * 1e-3, 6)
        d["cycle"] = i
        d["tip_x_mm"] = math.nan if i % 7 == 0 else d["tip_x_mm"]
        d["event"] = "tension_low" if i == 3 else ""
        rows.append(d)
    return rows


def test_rows_round_trip_through_run_mcap_exactly(tmp_path):
    rows = _rows(500)
    sink = McapSink(
        tmp_path / RUN_MCAP, COLS, model_tip=ModelTip(lambda p: np.array([1.0, 2.0, 3.0]))
    )
    sink.write_rows(rows[:200])
    sink.flush()
    sink.write_rows(rows[200:])
    sink.close("name: t\nended: {outcome: completed}\n")
    run = load_run(tmp_path / RUN_MCAP)
    assert len(run) == 500 and run.columns == COLS
    for c in COLS:
        want = [r[c] for r in rows]
        if c == "event":
            assert list(run.data[c]) == want
        else:
            assert np.array_equal(run.data[c], np.array(want, dtype=float), equal_nan=True), c
    assert run.metadata["ended"]["outcome"] == "completed"
    m = read_mcap(tmp_path / RUN_MCAP)
    assert len(m.model_tip) == 500 and m.model_tip[1]["error_mm"] is not None
    assert m.model_tip[0]["error_mm"] is None  # no tracked tip that cycle


def test_a_cut_file_reads_up_to_its_last_flush(tmp_path):
    rows = _rows(300)
    path = tmp_path / RUN_MCAP
    sink = McapSink(path, COLS)
    sink.write_rows(rows[:120])
    sink.flush()
    flushed = path.stat().st_size
    sink.write_rows(rows[120:])
    sink.flush()
    whole = path.read_bytes()
    sink.close()
    # The second flush wrote a chunk record, then its message indexes (one record a channel).
    opcode, length = struct.unpack_from("<BQ", whole, flushed)
    assert opcode == Opcode.CHUNK
    chunk_end = flushed + 9 + length
    assert struct.unpack_from("<B", whole, chunk_end)[0] == Opcode.MESSAGE_INDEX
    cuts = {flushed: 120, flushed + 1: 120, (flushed + chunk_end) // 2: 120, chunk_end - 1: 120}
    cuts |= {chunk_end: 300, chunk_end + 5: 300, len(whole) - 3: 300}  # only indexes cut
    for cut, n in cuts.items():
        p = tmp_path / f"cut{cut}.mcap"
        p.write_bytes(whole[:cut] + b"\0" * 64)  # a tail the file system extended, never wrote
        run = load_run(p)
        assert len(run) == n, cut
        assert run.warnings and "last flush" in run.warnings[0]
        assert np.array_equal(run.t_s, [r["t_s"] for r in rows[:n]])
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(ConfigError, match=r"junk.mcap.*not an MCAP file"):
        load_run(tmp_path / "junk.mcap")


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(floats, floats, floats), min_size=1, max_size=20))
def test_messages_are_strict_json_and_keep_every_finite_float(values):
    rs = streams.RowStreams(tuple(COLS))
    for n, (a, b, c) in enumerate(values):
        d = {
            "t_s": float(n),
            "cycle": n,
            "cable1_tension_N": a,
            "tip_x_mm": b,
            "seg1_theta_cmd_rad": c,
        }
        fast = dict(rs.encoded(d, n))
        for topic, msg in rs.messages(d, n):
            back = json.loads(streams.encode(msg))  # allow_nan=False: never NaN in the text
            assert json.loads(fast[topic]) == back  # the writer's direct text: the same JSON
            if topic == streams.TENSION:
                got = back["tension_N"][0]
                assert (got is None) if math.isnan(a) else got == a
            if topic == streams.TIP_TRACKED:
                assert (back["x_mm"] is None) if math.isnan(b) else back["x_mm"] == b


def test_the_foxglove_layout_names_only_channels_and_fields_that_exist():
    layout = json.loads((ROOT / "config" / "foxglove" / "cdcr-layout.json").read_text())
    paths = []
    for cfg in layout["configById"].values():
        paths += [p["value"] for p in cfg.get("paths", [])]
        if "topicPath" in cfg:
            paths.append(cfg["topicPath"])
        paths += list(cfg.get("topics", {}))
    assert paths
    for p in paths:
        topic, _, field = p.partition(".")
        if topic == streams.SCENE:
            continue
        assert topic in streams.SCHEMAS, p
        if field:
            name = field.split("[")[0]
            assert name in streams.SCHEMAS[topic][1]["properties"], p
