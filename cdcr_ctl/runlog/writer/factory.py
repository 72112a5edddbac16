"""The run-log factory: one :class:`~cdcr_ctl.runlog.writer.thread.RunLogWriter` per run with the
rig's metadata, config copies and (``run.mcap``) second sink; the daemon's ``run_sink_factory``.
"""

from __future__ import annotations

import contextlib
import math
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from cdcr_ctl.config.control import run_log_dir
from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.mcap_sink import McapSinkFactory
from cdcr_ctl.runlog.model_tip import ModelTip
from cdcr_ctl.runlog.writer.files import EFFECTIVE_CONFIG_YAML, RunMetadata, new_run_dir
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
from cdcr_ctl.runlog.writer.spawn import start_writer_process
from cdcr_ctl.runlog.writer.thread import (
    CLOSE_TIMEOUT_S,
    DEFAULT_QUEUE_ROWS,
    ON_FULL,
    RunLogWriter,
)

if TYPE_CHECKING:
    from cdcr_ctl.config.schema import RigConfig


class RunLogFactory:
    """Makes one run-log writer per run with the rig's metadata and config copy.

    ``writer``: ``"process"`` (default, ``logging.writer``): a
    :class:`~cdcr_ctl.runlog.writer.process.ProcessRunLogWriter`, the encoding in a writer
    process of its own; ``"thread"``: a :class:`RunLogWriter` thread in this process.

    Called as ``factory(name, compensation, trajectory="")`` (the daemon's ``run_sink_factory``).
    ``config_text`` is the rig config file as loaded; ``effective_config`` (optional) the
    validated config with defaults filled, written as ``config_effective.yaml``.
    """

    def __init__(
        self,
        base_dir: str | Path,
        *,
        rig: str,
        design: str,
        rate_hz: float,
        n_segments: int,
        n_cables: int,
        config_text: str | None = None,
        config_source: str = "",
        effective_config: str | None = None,
        fsync_every_s: float = 0.5,
        extra_columns: Sequence[str] = LOOP_EXTRA_COLUMNS,
        max_queued_rows: int | None = None,
        on_failure: Callable[[str], None] | None = None,
        mcap: bool = False,
        tip_from_psi: Callable[[Any], Any] | None = None,
        writer: str = "process",
        ring_s: float = DEFAULT_QUEUE_ROWS / 1000.0,
        on_full: str = "trip",
    ) -> None:
        if writer not in ("process", "thread"):
            raise ValueError(f"writer {writer!r}: use 'process' or 'thread'")
        if on_full not in ON_FULL:
            raise ValueError(f"on_full {on_full!r}: use one of {ON_FULL}")
        if ring_s <= 0:
            raise ValueError(f"ring_s {ring_s!r}: must be > 0")
        #: What a full ring does (``trip`` in real time, ``wait`` when the loop runs on
        #: simulated time: see :mod:`cdcr_ctl.runlog.writer.process`).
        self.on_full = on_full
        self.writer = writer
        self.base_dir = Path(base_dir)
        #: ``run.mcap`` beside ``samples.csv`` (``logging.mcap``); ``tip_from_psi``: the model's
        #: tip of a commanded pose for its ``/tip/model`` channel.
        tip = ModelTip(tip_from_psi) if tip_from_psi is not None else None
        self.second_sink = McapSinkFactory(tip, rate_hz) if mcap else None
        self.rig, self.design, self.rate_hz = rig, design, float(rate_hz)
        self.n_segments, self.n_cables = n_segments, n_cables
        self.config_text, self.config_source = config_text, config_source
        self.effective_config = effective_config
        self.fsync_every_s = fsync_every_s
        self.extra_columns = tuple(extra_columns)
        #: Rows a writer may hold: ``ring_s`` seconds at the loop's rate (``logging.ring_s``),
        #: bounded by time, never by the run's length; ``max_queued_rows`` overrides (tests).
        self.max_queued_rows = (
            max(1, math.ceil(ring_s * float(rate_hz)))
            if max_queued_rows is None
            else int(max_queued_rows)
        )
        self.on_failure = on_failure
        sample_columns(n_segments, n_cables, self.extra_columns)  # fail early on bad names
        #: Writers made and not yet seen finished (held: the loop drops a run's writer as soon
        #: as it asked it to close, and the daemon's shutdown waits for the files).
        self._made: list[Any] = []
        #: A writer process started ahead, imports done, for the next run (a run then starts
        #: without waiting for an interpreter: ~0.5 s idle, seconds on a loaded machine).
        self._spare = start_writer_process(on_full=on_full) if writer == "process" else None
        self._spare_closed = False
        self._spare_lock = threading.Lock()
        #: The control loop's "between my cycles" (its ``between_cycles``), set by the daemon:
        #: a process writer in real time then stores its rows into the ring only then
        #: (:mod:`cdcr_ctl.runlog.writer.handoff`). None: on the loop's thread, in ``write``.
        self.quiet: Callable[[], bool] | None = None

    @classmethod
    def from_config(
        cls,
        cfg: RigConfig,
        config_path: str | Path,
        *,
        n_segments: int | None = None,
        n_cables: int | None = None,
        base_dir: str | Path | None = None,
        **kwargs: Any,
    ) -> RunLogFactory:
        """Factory for a validated rig config read from ``config_path``.

        The log directory is :func:`~cdcr_ctl.config.control.run_log_dir` of the config (its
        ``logging.directory`` against the working directory, else the state directory's
        ``runs``) unless ``base_dir`` is given; counts default to the config's segments and
        cables. The ring holds ``cfg.logging.ring_s`` of rows, ``cfg.logging.wait_ring_s`` for
        ``on_full="wait"`` (lock-step). Raises :class:`RigError` naming the file if the config
        cannot be re-read.
        """
        path = Path(config_path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise RigError(f"{path}: cannot read the config for the run logs: {exc}") from exc
        if base_dir is None:
            base_dir = run_log_dir(cfg.logging)
        effective = yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)
        return cls(
            base_dir,
            rig=cfg.name,
            design=cfg.design,
            rate_hz=cfg.control.rate_hz,
            n_segments=n_segments or len(cfg.robot.segments),
            n_cables=n_cables or len(cfg.robot.cables),
            config_text=text,
            config_source=str(path.resolve()),
            effective_config=effective,
            fsync_every_s=cfg.logging.fsync_every_s,
            mcap=cfg.logging.mcap,
            writer=cfg.logging.writer,
            ring_s=(
                cfg.logging.wait_ring_s if kwargs.get("on_full") == "wait" else cfg.logging.ring_s
            ),
            **kwargs,
        )

    def __call__(
        self, name: str, compensation: str, trajectory: str = ""
    ) -> RunLogWriter | ProcessRunLogWriter:
        meta = RunMetadata(
            name=name,
            rig=self.rig,
            design=self.design,
            compensation=compensation,
            rate_hz=self.rate_hz,
            trajectory=trajectory or name,
        )
        extra = {EFFECTIVE_CONFIG_YAML: self.effective_config} if self.effective_config else None
        kw: dict[str, Any] = {}
        if self.writer == "process":
            cls: Any = ProcessRunLogWriter
            with self._spare_lock:
                kw["process"], self._spare = self._spare, None
            kw["quiet"] = self.quiet
        else:
            cls = RunLogWriter
        writer = cls(
            new_run_dir(self.base_dir, meta.name),
            sample_columns(self.n_segments, self.n_cables, self.extra_columns),
            meta,
            config_text=self.config_text,
            config_source=self.config_source,
            extra_files=extra,
            fsync_every_s=self.fsync_every_s,
            max_queued_rows=self.max_queued_rows,
            on_failure=self.on_failure,
            second_sink=self.second_sink,
            on_full=self.on_full,
            **kw,
        )
        if self.writer == "process":
            if self.on_full == "wait":
                # Lock-step: the next spare's start-up (an interpreter, ~0.1 s of CPU) after
                # this run's last cycle, not beside its cycles (spawn.WAIT_DEFER_FILL).
                writer.on_close = self._start_spare
            else:
                self._start_spare()
        self._made = [w for w in self._made if not (w.closed and w.wait_closed(0))]
        self._made.append(writer)
        return writer

    def _start_spare(self) -> None:
        """Start the next run's spare writer process, unless one is waiting or spares are
        closed."""
        with self._spare_lock:
            if self._spare is None and not self._spare_closed:
                self._spare = start_writer_process(on_full=self.on_full)

    def close_spare(self, timeout_s: float = 5.0) -> None:
        """End the spare writer process started ahead (it exits when its stdin closes; killed
        after ``timeout_s``). Idempotent; writers already made are not touched, and a writer
        made later starts a process of its own. For owners done making runs (a session
        closing, a test), so spares do not outlive them."""
        with self._spare_lock:
            self._spare_closed = True
            spare, self._spare = self._spare, None
        if spare is None:
            return
        with contextlib.suppress(OSError):
            if spare.stdin is not None:
                spare.stdin.close()
        try:
            spare.wait(timeout_s)
        except subprocess.TimeoutExpired:
            spare.kill()
            spare.wait()

    def close_all(self, reason: str, timeout_s: float = CLOSE_TIMEOUT_S) -> bool:
        """Close every writer this factory made that is still open (outcome ``aborted``) and
        wait, up to ``timeout_s`` in all, until each has written its files and run.yaml (the
        daemon's shutdown: the loop closes a run's log without waiting). False on timeout."""
        writers = list(self._made)
        for w in writers:
            w.close(reason, outcome="aborted", wait=False)  # no change to one already closing
        end = time.monotonic() + timeout_s
        return all(w.wait_closed(max(0.0, end - time.monotonic())) for w in writers)
