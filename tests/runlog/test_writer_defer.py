"""A ring that waits (``on_full="wait"``, lock-step) is drained by its writer process only once
it is half full (``spawn.WAIT_DEFER_FILL``), at the run's close, or when the loop's process is
gone; a ring that trips (real time) is drained every drain interval, as before. The factory of a
waiting ring starts the next spare writer when a run's log closes, not beside the run, and sizes
its ring by ``logging.wait_ring_s``.

What is checked is where the rows are (the ring's tail, the files), never how fast."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import yaml
from waits import wait_for

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.runlog import RunLogFactory, RunMetadata, load_run
from cdcr_ctl.runlog.reader import wait_run_closed
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
from cdcr_ctl.runlog.writer.ring import READY, ROW_HEAD, ROW_TAIL
from cdcr_ctl.runlog.writer.spawn import WAIT_DEFER_FILL, defer_fill

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 30.0  # generous: the machine may be loaded; nothing here measures time
DRAIN_S = 0.005  # the writer process looks at the ring this often
#: Drain intervals a deferring writer is watched for without taking a row.
LOOKS = 40


def _writer(tmp_path: Path, on_full: str, rows: int = 100) -> ProcessRunLogWriter:
    return ProcessRunLogWriter(
        tmp_path / "r", ["t_s"], RunMetadata(name=on_full), max_queued_rows=rows,
        drain_interval_s=DRAIN_S, on_full=on_full,
    )  # fmt: skip


def _tail(w: ProcessRunLogWriter) -> int:
    return int(w._ring.hq[ROW_TAIL])


def _ready(w: ProcessRunLogWriter) -> None:
    """Wait until the writer process has its run (it looks at the ring from then on)."""
    assert wait_for(lambda: w._ring.hq[READY] == 1, WAIT_S, 0.01)


def test_the_policy_by_what_a_full_ring_does():
    assert defer_fill("wait") == WAIT_DEFER_FILL == 0.5
    assert defer_fill("trip") is None


def test_a_waiting_ring_is_drained_only_once_half_full_and_at_the_close(tmp_path):
    w = _writer(tmp_path, "wait", rows=100)
    _ready(w)
    for i in range(49):  # below half: the rows wait in the ring
        assert w.write({"t_s": float(i)})
    time.sleep(LOOKS * DRAIN_S)
    assert _tail(w) == 0 and w._ring.hq[ROW_HEAD] == 49
    assert w.write({"t_s": 49.0})  # 50 of 100: half full, drained at its next look
    assert wait_for(lambda: _tail(w) == 50, WAIT_S, 0.001)
    for i in range(50, 60):
        assert w.write({"t_s": float(i)})
    time.sleep(LOOKS * DRAIN_S)
    assert _tail(w) == 50  # 10 rows: deferred again
    w.close("done", outcome="completed")  # the close drains the rest
    assert wait_run_closed(w.run_dir, WAIT_S)
    assert load_run(w.run_dir).t_s.tolist() == [float(i) for i in range(60)]


def test_a_tripping_ring_is_drained_every_interval(tmp_path):
    w = _writer(tmp_path, "trip", rows=100)
    _ready(w)
    for i in range(3):
        assert w.write({"t_s": float(i)})
    assert wait_for(lambda: _tail(w) == 3, WAIT_S, 0.001)
    w.close("done", outcome="completed")
    assert load_run(w.run_dir).t_s.tolist() == [0.0, 1.0, 2.0]


KILLED = textwrap.dedent(
    """
    import os, signal, sys
    from cdcr_ctl.runlog import RunMetadata
    from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
    from cdcr_ctl.runlog.writer.ring import READY
    from waits import wait_for
    w = ProcessRunLogWriter(sys.argv[1], ["t_s"], RunMetadata(name="killed"),
                            max_queued_rows=1000, drain_interval_s=0.005, on_full="wait")
    assert wait_for(lambda: w._ring.hq[READY] == 1, 30.0, 0.01)
    for i in range(int(sys.argv[2])):
        w.write({"t_s": float(i)})
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


def test_rows_deferred_in_the_ring_are_written_when_the_loop_process_is_killed(tmp_path):
    """The writer process holds the shared ring too: it drains it when its parent is gone."""
    run_dir = tmp_path / "r"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(Path(__file__).parent)])}
    proc = subprocess.run(
        [sys.executable, "-c", KILLED, str(run_dir), "300"],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    run_yaml = run_dir / "run.yaml"
    assert wait_for(
        lambda: run_yaml.is_file() and (yaml.safe_load(run_yaml.read_text()) or {}).get("ended"),
        WAIT_S,
        0.05,
    )
    assert yaml.safe_load(run_yaml.read_text())["ended"]["outcome"] == "aborted"
    assert load_run(run_dir).t_s.tolist() == [float(i) for i in range(300)]  # none lost


def test_a_waiting_factory_starts_the_next_spare_when_a_run_closes(tmp_path):
    f = RunLogFactory(
        tmp_path, rig="r", design="d", rate_hz=250.0, n_segments=1, n_cables=3,
        ring_s=2.0, on_full="wait",
    )  # fmt: skip
    try:
        w = f("first", "off")
        assert f._spare is None  # not beside the run
        w.close("done", outcome="completed")
        assert f._spare is not None  # started once the run's log closes
        assert w.wait_closed(WAIT_S)
    finally:
        f.close_spare()


def test_a_tripping_factory_starts_the_next_spare_with_the_run(tmp_path):
    f = RunLogFactory(
        tmp_path, rig="r", design="d", rate_hz=250.0, n_segments=1, n_cables=3, ring_s=2.0
    )
    try:
        w = f("first", "off")
        assert f._spare is not None
        w.close("done", outcome="completed")
        assert w.wait_closed(WAIT_S)
    finally:
        f.close_spare()


def test_from_config_sizes_a_waiting_ring_by_wait_ring_s(tmp_path):
    path = ROOT / "config" / "qi2023-sim.yaml"
    cfg = load_rig_config(path)
    rate = cfg.control.rate_hz
    waiting = RunLogFactory.from_config(cfg, path, base_dir=tmp_path, on_full="wait")
    tripping = RunLogFactory.from_config(cfg, path, base_dir=tmp_path)
    try:
        assert waiting.max_queued_rows == math.ceil(cfg.logging.wait_ring_s * rate)
        assert tripping.max_queued_rows == math.ceil(cfg.logging.ring_s * rate)
        assert cfg.logging.wait_ring_s == 60.0  # the default: 15 000 rows at 250 Hz
    finally:
        waiting.close_spare()
        tripping.close_spare()
