"""The run-log writer's second sink: run.mcap beside samples.csv from the same rows; a failing
MCAP write stops the log like a CSV write error; the live section of the config."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdcr_ctl.config.loader import load_rig_config
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.runlog import RunLogWriter, RunMetadata, load_run, sample_columns
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP, McapSinkFactory, yaml_metadata
from cdcr_ctl.runlog.model_tip import ModelTip
from cdcr_ctl.runlog.writer.factory import RunLogFactory

ROOT = Path(__file__).resolve().parents[2]
COLS = sample_columns(1, 3, ("cycle", "lateness_us", "event"))


def _row(i: int) -> dict:
    d = {c: math.sin(i + j) for j, c in enumerate(COLS)}
    d.update(t_s=i * 0.001, cycle=i, event="")
    return d


def test_the_writer_writes_both_files_from_the_same_rows(tmp_path):
    w = RunLogWriter(
        tmp_path / "run",
        COLS,
        RunMetadata(name="both", rate_hz=1000.0),
        config_text="name: x\n",
        second_sink=McapSinkFactory(ModelTip(lambda psi: np.zeros(3)), 1000.0),
        fsync_every_s=0.05,
    )
    for i in range(400):
        w.write(_row(i))
    w.close("done", outcome="completed")
    assert w.stats.complete and w.failure is None
    csv_run = load_run(tmp_path / "run")
    mcap_run = load_run(tmp_path / "run" / RUN_MCAP)
    assert len(csv_run) == len(mcap_run) == 400
    for c in COLS:
        a, b = csv_run.data[c], mcap_run.data[c]
        assert (list(a) == list(b)) if a.dtype == object else np.array_equal(a, b, equal_nan=True)
    assert mcap_run.metadata["ended"]["outcome"] == "completed"
    assert w.stats.fsyncs >= 2


class _Failing:
    """A second sink whose writes fail like a full disk."""

    def __init__(self, *_):
        self.closed = False

    def write_rows(self, rows):
        raise OSError(28, "No space left on device")

    def flush(self):
        pass

    def fileno(self):
        raise ValueError("no file")

    def close(self, run_yaml, ok):
        self.closed = True


def test_a_failing_second_sink_stops_the_log_and_says_so(tmp_path):
    failures = []
    w = RunLogWriter(
        tmp_path / "run",
        COLS,
        RunMetadata(name="fail"),
        second_sink=_Failing,
        on_failure=failures.append,
    )
    w.write(_row(0))
    w.close("done")
    assert w.failure and "_Failing write failed: No space left on device" in w.failure
    assert failures == [w.failure]
    assert not w.write(_row(1))  # refused from now on: the loop sees it and trips


def test_factory_from_config_writes_mcap_unless_switched_off(tmp_path):
    base = str((ROOT / "config" / "qi2023-sim.yaml").resolve())
    for mcap, expect in ((True, True), (False, False)):
        doc = {"extends": base, "logging": {"directory": str(tmp_path), "mcap": mcap}}
        path = tmp_path / f"rig-{mcap}.yaml"
        path.write_text(yaml.safe_dump(doc))
        factory = RunLogFactory.from_config(load_rig_config(path), path)
        w = factory("run", "model")
        w.close("done")
        assert (w.run_dir / RUN_MCAP).exists() == expect


def test_live_host_must_be_an_address_and_the_error_names_the_key(tmp_path):
    base = str(ROOT / "config" / "qi2023-sim.yaml")
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"extends": base, "live": {"enabled": True, "host": "any"}}))
    with pytest.raises(ConfigError) as err:
        load_rig_config(path)
    assert "live.host" in str(err.value) and "any" in str(err.value)
    path.write_text(yaml.safe_dump({"extends": base, "live": {"enabled": True}}))
    live = load_rig_config(path).live
    assert (live.host, live.port, live.enabled) == ("127.0.0.1", 8765, True)


def test_metadata_values_are_plain_yaml_text():
    text = (
        "rate_hz: 250.0\nok: true\nname: x\nnothing: null\nstarted: 2026-11-29 01:59:56+00:00\n"
        "ended: {outcome: completed, rows: {written: 3}}\ncables: [1, 2]\n"
    )
    meta = yaml_metadata(text)
    assert meta == {
        "rate_hz": "250.0",
        "ok": "true",
        "name": "x",
        "nothing": "null",
        "started": "2026-11-29 01:59:56+00:00",
        "ended": "{outcome: completed, rows: {written: 3}}",
        "cables": "[1, 2]",
    }
    doc = yaml.safe_load(text)
    assert {k: yaml.safe_load(v) for k, v in meta.items()} == doc  # each value reads back
