"""A full run-log queue or ring (issue #23): ``on_full="trip"`` (real time) refuses the row and
names the overflow; ``on_full="wait"`` (simulated time) blocks the writing thread until the
writer has made room, and loses nothing. The writer is held back on purpose (a gate on its file,
a stopped process), so nothing here depends on the machine's speed. The loop's side of both
rules (the ``log_overflow`` trip, the lock-step wait) is in tests/control/test_loop_log_overflow.
"""

from __future__ import annotations

import math
import os
import signal
import threading
from pathlib import Path

import pytest
import yaml
from waits import wait_for

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.errors import ConfigError, ConfigErrors
from cdcr_ctl.runlog import RunLogFactory, RunLogWriter, RunMetadata, load_run
from cdcr_ctl.runlog.reader import run_closed, wait_run_closed
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter

WAIT_S = 30.0  # generous: the machine may be loaded; nothing here measures time


def _wait(pred, timeout_s: float = WAIT_S) -> bool:
    return wait_for(pred, timeout_s, 0.005)


class _GatedFile:
    """samples.csv whose writes wait for ``gate`` (the writer thread falls behind)."""

    def __init__(self, f, gate: threading.Event) -> None:
        self._f, self._gate = f, gate

    def write(self, data: bytes) -> int:
        self._gate.wait()
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)


def _feed(w, n: int) -> tuple[threading.Thread, list[bool]]:
    out: list[bool] = []
    t = threading.Thread(target=lambda: out.extend(w.write({"t_s": float(i)}) for i in range(n)))
    t.start()
    return t, out


def test_thread_writer_trip_refuses_and_names_the_overflow(tmp_path):
    w = RunLogWriter(
        tmp_path / "r", ["t_s"], RunMetadata(name="full", rate_hz=1000.0),
        max_queued_rows=10, drain_interval_s=60.0,
    )  # fmt: skip
    assert w.overflow is None
    accepted = [w.write({"t_s": float(n)}) for n in range(12)]
    assert accepted == [True] * 10 + [False] * 2
    assert str(w.samples_path) in w.overflow and "10 rows = 0.01 s at 1000 Hz" in w.overflow
    w.close("done")


def test_thread_writer_wait_blocks_until_room_and_loses_nothing(tmp_path):
    gate = threading.Event()
    gate.set()
    w = RunLogWriter(
        tmp_path / "r", ["t_s"], RunMetadata(name="wait"), max_queued_rows=10,
        drain_interval_s=0.005, on_full="wait",
        opener=lambda p: _GatedFile(open(p, "wb"), gate),  # noqa: SIM115 - closed by the writer
    )  # fmt: skip
    gate.clear()  # the writer thread now stalls on its next write
    feeder, accepted = _feed(w, 200)
    assert _wait(lambda: w.waits >= 1)
    assert feeder.is_alive() and w.stats.dropped == 0  # blocked, not dropping
    gate.set()
    feeder.join(WAIT_S)
    assert accepted == [True] * 200 and w.overflow is None
    w.close("done", outcome="completed")
    assert load_run(w.run_dir).t_s.tolist() == [float(i) for i in range(200)]


def test_process_writer_wait_blocks_until_room_and_loses_nothing(tmp_path):
    w = ProcessRunLogWriter(
        tmp_path / "r", ["t_s"], RunMetadata(name="wait"), max_queued_rows=8, on_full="wait"
    )
    os.kill(w._proc.pid, signal.SIGSTOP)
    try:
        feeder, accepted = _feed(w, 500)
        assert _wait(lambda: w.waits >= 1)
        assert feeder.is_alive() and w._head == 8 and w.stats.dropped == 0
    finally:
        os.kill(w._proc.pid, signal.SIGCONT)
    feeder.join(WAIT_S)
    assert accepted == [True] * 500
    assert not run_closed(w.run_dir)
    w.close("done", outcome="completed")
    assert wait_run_closed(w.run_dir, WAIT_S)
    assert load_run(w.run_dir).t_s.tolist() == [float(i) for i in range(500)]
    assert w.high_water == 8 and w.overflow is None


def test_process_writer_wait_gives_up_when_the_writer_dies(tmp_path):
    w = ProcessRunLogWriter(
        tmp_path / "r", ["t_s"], RunMetadata(name="dies"), max_queued_rows=4, on_full="wait"
    )
    os.kill(w._proc.pid, signal.SIGSTOP)
    feeder, accepted = _feed(w, 10)
    assert _wait(lambda: w.waits >= 1)
    os.kill(w._proc.pid, signal.SIGKILL)
    feeder.join(WAIT_S)
    assert not feeder.is_alive() and accepted[:4] == [True] * 4 and False in accepted
    assert "writer process ended" in (w.failure or "")
    w.close("done", wait=False)
    w.wait_closed(WAIT_S)


def test_the_factory_sizes_the_ring_by_time(tmp_path):
    f = RunLogFactory(
        tmp_path, rig="r", design="d", rate_hz=250.0, n_segments=1, n_cables=3,
        ring_s=2.0, on_full="wait", writer="thread",
    )  # fmt: skip
    w = f("sized", "off")
    assert w.max_queued_rows == 500 and w.on_full == "wait"  # 2 s at 250 Hz, whatever the run
    f.close_all("done")
    doc = yaml.safe_load((w.run_dir / "run.yaml").read_text())
    assert doc["ended"]["outcome"] == "aborted"


QI = Path(__file__).resolve().parents[2] / "config" / "qi2023.yaml"


@pytest.mark.parametrize("value", ["0", "-1.0", "1.0e9"])
def test_a_bad_ring_length_is_refused_naming_file_and_key(tmp_path, value):
    path = tmp_path / "rig.yaml"
    path.write_text(f"extends: {QI}\nlogging: {{ring_s: {value}}}\n")
    with pytest.raises((ConfigError, ConfigErrors)) as info:
        load_rig_config(path)
    errors = info.value.errors if isinstance(info.value, ConfigErrors) else [info.value]
    assert [e.file for e in errors if e.key == "logging.ring_s"] == [str(path)]


def test_the_config_sets_the_ring_length(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(f"extends: {QI}\nlogging: {{ring_s: 2.5, writer: thread}}\n")
    cfg = load_rig_config(path)
    f = RunLogFactory.from_config(cfg, path, base_dir=tmp_path / "runs")
    assert f.max_queued_rows == math.ceil(2.5 * cfg.control.rate_hz) and f.on_full == "trip"
