"""Run-log writer and reader: exact round trip, partial and damaged logs, write errors, overflow."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cdcr_ctl.errors import ConfigError, RigError
from cdcr_ctl.runlog import (
    LOOP_EXTRA_COLUMNS,
    RunLogFactory,
    RunLogWriter,
    RunMetadata,
    load_run,
    sample_columns,
)
from cdcr_ctl.runlog import reader as reader_mod
from cdcr_ctl.runlog.writer import can_log_path

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 10.0


def wait_until(pred, timeout_s: float = WAIT_S) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.002)
    return bool(pred())


def loop_row(n: int, S: int, K: int, rng: np.random.Generator) -> dict:
    """A row as the control loop builds it (floats, NaN for missing tension, an event text)."""
    row: dict = {"t_s": n * 0.001, "cycle": n}
    for i in range(1, S + 1):
        row[f"seg{i}_theta_cmd_rad"] = float(rng.uniform(0, 1.6))
        row[f"seg{i}_phi_cmd_rad"] = float(rng.uniform(-np.pi, np.pi))
    for k in range(1, K + 1):
        row[f"cable{k}_q_nominal_mm"] = float(rng.normal(0, 10))
        row[f"cable{k}_q_cmd_mm"] = np.float64(rng.normal(0, 10))  # numpy scalars too
        row[f"cable{k}_q_act_mm"] = float(rng.normal(0, 10)) * 1e-300  # subnormal-ish range
        row[f"cable{k}_tension_N"] = float("nan") if k == K else float(rng.uniform(0, 50))
    row["tip_x_mm"], row["tip_y_mm"], row["tip_z_mm"] = (float(v) for v in rng.normal(0, 80, 3))
    row["lateness_us"] = round(float(rng.uniform(0, 300)), 1)
    row["event"] = ["", "tension_low", 'a, "quoted"\nevent'][n % 3]
    return row


def meta(name: str = "round trip") -> RunMetadata:
    return RunMetadata(
        name=name,
        rig="bench",
        design="cc_disk",
        compensation="model",
        rate_hz=1000.0,
        trajectory="planar_bend",
    )


# ============================================================================ round trip
def test_round_trip_is_exact_with_metadata_and_counts(tmp_path):
    S, K = 2, 3
    rng = np.random.default_rng(0)
    rows = [loop_row(n, S, K, rng) for n in range(3000)]
    config_text = "name: bench  # the config as loaded, comments and all\n"
    w = RunLogWriter.create(
        tmp_path,
        meta(),
        S,
        K,
        config_text=config_text,
        config_source="/etc/cdcr/bench.yaml",
        fsync_every_s=0.05,
    )
    assert w.run_dir.parent == tmp_path and w.run_dir.name.endswith("_round_trip")
    for row in rows:
        assert w.write(row)
    w.close("trajectory completed", outcome="completed")
    assert w.closed and w.failure is None
    assert w.stats.complete and w.stats.written == 3000 and w.stats.fsyncs >= 2

    run = load_run(w.run_dir)
    assert run.warnings == [] and len(run) == 3000
    assert run.columns == sample_columns(S, K, LOOP_EXTRA_COLUMNS)
    assert (run.n_segments, run.n_cables) == (S, K)
    assert run.groups == {"psi_cmd", "q_nominal", "q_cmd", "q_act", "tension", "tip"}
    for name in run.columns:
        want = [r[name] for r in rows]
        if name == "event":
            assert run.data[name].tolist() == [e.replace("\n", " ") for e in want]
        else:
            assert np.array_equal(run.data[name], np.array(want, dtype=float), equal_nan=True), name
    q_cmd = np.array([[r[f"cable{k}_q_cmd_mm"] for k in range(1, K + 1)] for r in rows])
    assert np.array_equal(run.q_cmd(), q_cmd)
    assert run.tip().shape == (3000, 3) and run.psi_cmd().shape == (3000, S, 2)
    assert np.array_equal(run.phi_cmd()[:, 1], [r["seg2_phi_cmd_rad"] for r in rows])
    assert np.isnan(run.tension()[:, K - 1]).all()

    m = run.metadata
    assert (m["rig"], m["design"], m["compensation"], m["rate_hz"]) == (
        "bench",
        "cc_disk",
        "model",
        1000.0,
    )
    assert m["trajectory"] == "planar_bend" and m["software_version"]
    assert m["start_utc"].endswith("Z")
    assert m["config"] == {"files": ["config.yaml"], "source": "/etc/cdcr/bench.yaml"}
    assert run.ended["outcome"] == "completed" and run.ended["reason"] == "trajectory completed"
    assert run.ended["rows"] == {"queued": 3000, "written": 3000, "dropped": 0, "lost": 0}
    assert run.ended["write_error"] is None
    assert run.config_path.read_text() == config_text
    assert run.can_log is None
    assert m["can_log"] is None  # run.yaml names no traffic file that was never written


def test_sequence_rows_empty_fields_and_unknown_keys(tmp_path):
    cols = ["t_s", "seg1_theta_cmd_rad", "note"]
    w = RunLogWriter(tmp_path / "r", cols, meta(), drain_interval_s=0.01)
    w.write([0.0, 0.1, "a"])
    w.write([0.5, None, ""])
    w.write({"t_s": 1.0, "seg1_theta_cmd_rad": float("nan"), "bogus": 3})
    w.write([2.0, 1])  # too short: padded
    w.close("done")
    text = (w.run_dir / "samples.csv").read_text()
    assert text == "t_s,seg1_theta_cmd_rad,note\n0.0,0.1,a\n0.5,,\n1.0,,\n2.0,1,\n"
    run = load_run(w.run_dir / "samples.csv")
    assert run.groups == {"psi_cmd"} and run.n_cables == 0
    assert run.data["note"].tolist() == ["a", "", "", ""]  # text extra column
    assert run.extra_columns == ["note"]


def test_close_without_waiting_and_write_after_close(tmp_path):
    w = RunLogWriter(tmp_path / "r", ["t_s"], meta())
    w.write({"t_s": 1.0})
    w.close("stopped by operator", outcome="stopped", wait=False)
    assert w.wait_closed(WAIT_S)
    assert w.write({"t_s": 2.0}) is False
    w.close("again")  # changes nothing
    run = load_run(w.run_dir)
    assert run.t_s.tolist() == [1.0]
    assert run.ended["outcome"] == "stopped" and run.ended["reason"] == "stopped by operator"
    assert w.stats.dropped == 1  # after the end was recorded: counted, not in run.yaml


def test_context_manager_records_an_exception(tmp_path):
    with pytest.raises(KeyError), RunLogWriter(tmp_path / "r", ["t_s"], meta()) as w:
        raise KeyError("boom")
    assert load_run(w.run_dir).ended["outcome"] == "error"


def test_run_dir_must_be_new_or_empty(tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "x").write_text("")
    with pytest.raises(RigError, match="not empty"):
        RunLogWriter(tmp_path / "r", ["t_s"], meta())


def test_factory_from_the_shipped_config(tmp_path):
    from cdcr_ctl.config import load_rig_config

    path = ROOT / "config" / "qi2023.yaml"
    cfg = load_rig_config(path)
    factory = RunLogFactory.from_config(cfg, path, base_dir=tmp_path)
    w = factory("jog seg1", "off")
    w.close("done", outcome="completed")
    run = load_run(w.run_dir)
    assert run.config_path.read_text() == path.read_text()
    eff = yaml.safe_load((w.run_dir / "config_effective.yaml").read_text())
    assert eff["name"] == cfg.name and eff["control"]["rate_hz"] == cfg.control.rate_hz
    m = run.metadata
    assert (m["rig"], m["compensation"], m["trajectory"]) == (cfg.name, "off", "jog seg1")
    assert m["fsync_every_s"] == cfg.logging.fsync_every_s
    assert run.n_segments == len(cfg.robot.segments) and run.n_cables == len(cfg.robot.cables)
    assert factory("jog seg1", "off").run_dir != w.run_dir  # same second: a fresh directory


def test_can_log_name_is_reserved_and_listed(tmp_path):
    w = RunLogWriter(tmp_path / "r", ["t_s"], meta())
    assert w.can_log_path("blf") == tmp_path / "r" / "can.blf"
    w.can_log_path().write_text("date Mon May 1 12:00:00.000 am 2024\n")
    w.close("done")
    run = load_run(w.run_dir)
    assert run.can_log == can_log_path(w.run_dir)
    assert run.metadata["can_log"] == "can.asc"  # the file written, not every name reserved
    with pytest.raises(ValueError, match="asc"):
        can_log_path(tmp_path, "trc")


# ============================================================================ partial logs
def _simple_log(tmp_path: Path, rows: int = 5) -> Path:
    w = RunLogWriter(tmp_path / "r", sample_columns(1, 3), meta())
    for n in range(rows):
        w.write({"t_s": n * 0.1, "cable1_q_cmd_mm": n * 1.5})
    w.close("done")
    return w.run_dir


@pytest.mark.parametrize("tail", [b"0.5,0.1,0.2,1.", b"0.5", b"\x00" * 300, b"0.6,1,\x00\x00"])
def test_incomplete_last_line_is_dropped_and_reported(tmp_path, tail):
    run_dir = _simple_log(tmp_path)
    with open(run_dir / "samples.csv", "ab") as f:
        f.write(tail)
    run = load_run(run_dir)
    assert len(run) == 5 and run.data["cable1_q_cmd_mm"][-1] == 6.0
    assert run.dropped_tail_bytes == len(tail)
    assert any("incomplete last line" in w for w in run.warnings)


def test_missing_column_groups_are_reported(tmp_path):
    d = tmp_path / "r"
    d.mkdir()
    (d / "samples.csv").write_text(
        "t_s,seg1_theta_cmd_rad,seg1_phi_cmd_rad,cable1_q_cmd_mm,cable2_q_cmd_mm,cable2_q_act_mm\n"
        "0.0,0.1,0.0,1.0,2.0,2.1\n0.001,0.2,0.0,1.5,,2.5\n"
    )
    run = load_run(d)
    assert run.groups == {"psi_cmd", "q_cmd", "q_act"}
    assert not run.has("tension") and not run.has("tip")
    assert run.metadata == {} and "missing" in run.warnings[0]  # no run.yaml: only a warning
    assert run.ended is None and run.config_path is None
    assert np.array_equal(run.q_cmd(), [[1.0, 2.0], [1.5, np.nan]], equal_nan=True)
    assert np.array_equal(run.q_act(), [[np.nan, 2.1], [np.nan, 2.5]], equal_nan=True)
    with pytest.raises(RigError, match="no tension columns"):
        run.tension()
    with pytest.raises(RigError, match="no column 'tip_x_mm'"):
        run.column("tip_x_mm")


def test_unclosed_run_loads_with_ended_null(tmp_path):
    w = RunLogWriter(tmp_path / "r", ["t_s"], meta(), drain_interval_s=0.005)
    w.write({"t_s": 0.0})
    assert wait_until(lambda: w.stats.written == 1)
    run = load_run(w.run_dir)  # while still open
    assert run.ended is None and run.t_s.tolist() == [0.0]
    w.close("done")


@pytest.mark.parametrize(
    ("content", "key", "message"),
    [
        ("t_s,a\n0,1\n1,2,3\n", "line 3", "3 fields for 2 columns"),
        ("t_s,cable1_q_cmd_mm\n0,1\n\n1,x\n", "line 4", "'cable1_q_cmd_mm' is not a number"),
        ("t_s,a\n0,1\n,2\n", "line 3", "'t_s' is empty"),
        ("a,b\n0,1\n", "line 1", "no 't_s' column"),
        ("t_s,a,a\n", "line 1", "'a' appears twice"),
        ("t_s,,b\n", "line 1", "column 2 has no name"),
        ("", "", "empty file"),
        ("t_s,a", "line 1", "header line is incomplete"),
        ('t_s,a\n0,"x\n', "line 2", "bad CSV"),
    ],
)
def test_corrupt_samples_name_file_and_line(tmp_path, content, key, message):
    d = tmp_path / "r"
    d.mkdir()
    (d / "samples.csv").write_text(content)
    with pytest.raises(ConfigError) as err:
        load_run(d)
    assert err.value.file == str(d / "samples.csv")
    assert err.value.key == key and message in str(err.value)


def test_corrupt_metadata_and_missing_samples(tmp_path):
    d = tmp_path / "r"
    d.mkdir()
    with pytest.raises(ConfigError, match="cannot open run samples"):
        load_run(d)
    (d / "samples.csv").write_text("t_s\n0\n")
    (d / "run.yaml").write_text("name: x\nended: [\n")
    with pytest.raises(ConfigError) as err:
        load_run(d)
    assert err.value.file == str(d / "run.yaml") and err.value.key.startswith("line ")
    (d / "samples.csv").write_bytes(b"t_s\n0\n\xff\n")
    (d / "run.yaml").write_text("name: x\n")
    with pytest.raises(ConfigError, match="not UTF-8") as err:
        load_run(d)
    assert err.value.key == "line 3"


def test_chunked_reading_keeps_lines_and_mixed_extras(tmp_path, monkeypatch):
    monkeypatch.setattr(reader_mod, "CHUNK_ROWS", 7)
    d = tmp_path / "r"
    d.mkdir()
    lines = ["t_s,extra"] + [f"{n},{n}" for n in range(20)] + ["20,text"]
    (d / "samples.csv").write_text("\n".join(lines) + "\n")
    run = load_run(d)
    assert run.t_s.tolist() == list(range(21))
    assert run.data["extra"].dtype == object and run.data["extra"][-1] == "text"
    (d / "samples.csv").write_text("\n".join([*lines[:-1], "20,,x"]) + "\n")
    with pytest.raises(ConfigError) as err:
        load_run(d)
    assert err.value.key == "line 22"


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(junk=st.binary(max_size=200), cut=st.integers(0, 400))
def test_fuzzed_samples_load_or_raise_config_error(tmp_path_factory, junk, cut):
    d = tmp_path_factory.getbasetemp() / "fuzzrun"
    d.mkdir(exist_ok=True)
    good = b"t_s,cable1_q_cmd_mm,event\n0.0,1.5,\n0.001,,x\n"
    (d / "samples.csv").write_bytes(good[:cut] + junk)
    try:
        run = load_run(d)
    except ConfigError as exc:
        assert exc.file.startswith(str(d))
    else:
        assert len(run) == len(run.t_s) and np.all(np.isfinite(run.t_s))


# ============================================================================ failures
class DiskFullFile:
    """A real file that takes ``capacity`` bytes, writes what fits, then raises ENOSPC."""

    def __init__(self, path: Path, capacity: int = 10**9) -> None:
        self._f = open(path, "xb")  # noqa: SIM115 - closed by the writer
        self.capacity = capacity
        self.used = 0

    def write(self, data: bytes) -> int:
        room = self.capacity - self.used
        if len(data) > room:
            self._f.write(data[:room])
            self._f.flush()
            self.used = self.capacity
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._f.write(data)
        self.used += len(data)
        return len(data)

    def flush(self) -> None:
        self._f.flush()

    def fileno(self) -> int:
        return self._f.fileno()

    def close(self) -> None:
        self._f.close()


def test_disk_full_keeps_earlier_rows_and_reports_the_failure(tmp_path):
    files: list[DiskFullFile] = []
    failures: list[str] = []

    def opener(path: Path) -> DiskFullFile:
        files.append(DiskFullFile(path))
        return files[-1]

    w = RunLogWriter(
        tmp_path / "r",
        sample_columns(1, 3),
        meta(),
        opener=opener,
        on_failure=failures.append,
        drain_interval_s=0.005,
    )
    rng = np.random.default_rng(1)
    first = [loop_row(n, 1, 3, rng) for n in range(20)]
    for row in first:
        w.write(row)
    assert wait_until(lambda: w.stats.written == 20)
    files[0].capacity = files[0].used + 40  # room for part of one more line
    for n in range(20, 500):
        w.write(loop_row(n, 1, 3, rng))
    assert wait_until(lambda: w.failure is not None and failures)  # on_failure runs just after
    assert "No space left on device" in w.failure and "samples.csv" in w.failure
    assert failures == [w.failure] and isinstance(w.error, OSError)
    assert w.write(first[0]) is False  # refused, never raised
    w.close("trajectory completed", outcome="completed")  # must not raise
    s = w.stats
    assert s.written == 20 and s.lost + s.written == s.queued and s.dropped >= 1
    assert not s.complete

    run = load_run(w.run_dir)
    assert len(run) == 20
    assert np.array_equal(run.data["cable2_q_cmd_mm"], [r["cable2_q_cmd_mm"] for r in first])
    # The 40 bytes of the partly written row were cut: the file ends on a whole row.
    assert run.dropped_tail_bytes == 0 and not run.warnings
    assert w.samples_path.read_bytes().endswith(b"\n")
    assert run.ended["write_error"] == w.failure and run.ended["rows"]["lost"] == s.lost


def test_queue_overflow_is_counted(tmp_path):
    w = RunLogWriter(tmp_path / "r", ["t_s"], meta(), max_queued_rows=10, drain_interval_s=60.0)
    accepted = [w.write({"t_s": float(n)}) for n in range(25)]
    assert accepted == [True] * 10 + [False] * 15
    w.close("done")  # wakes the writer at once
    assert w.stats.queued == 10 and w.stats.dropped == 15 and w.stats.written == 10
    run = load_run(w.run_dir)
    assert run.t_s.tolist() == [float(n) for n in range(10)]
    assert run.ended["rows"]["dropped"] == 15


def test_start_failure_is_a_rig_error_naming_the_directory(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(RigError, match="file"):
        RunLogWriter(blocker / "r", ["t_s"], meta())


# ============================================================================ process death
CHILD = textwrap.dedent(
    """
    import os, signal, sys, time
    from cdcr_ctl.runlog import RunLogWriter, RunMetadata
    w = RunLogWriter(sys.argv[1], ["t_s", "x"], RunMetadata(name="child"), drain_interval_s=0.005)
    for n in range(500):
        w.write({"t_s": n * 0.001, "x": n})
    end = time.monotonic() + 10
    while w.stats.written < 500 and time.monotonic() < end:
        time.sleep(0.002)
    if sys.argv[2] == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
    sys.exit(0)  # normal exit without close(): the atexit hook closes the log
    """
)


@pytest.mark.parametrize("how", ["kill", "exit"])
def test_process_death_keeps_flushed_rows(tmp_path, how):
    d = tmp_path / "r"
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(d), how], cwd=ROOT, timeout=60, capture_output=True
    )
    assert proc.returncode == (-9 if how == "kill" else 0), proc.stderr.decode()
    run = load_run(d)
    assert run.data["x"].tolist() == list(range(500))
    if how == "kill":
        assert run.ended is None
    else:
        assert run.ended["outcome"] == "aborted" and run.ended["rows"]["written"] == 500
