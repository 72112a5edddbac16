"""The intake process: big requests and trajectory files are parsed and validated here, never in
the process of the control loop.

A JSON parse, a CSV read or a sample-by-sample validation holds the Python interpreter for as
long as it runs (a 10 MB request: ~2 s), and the control loop shares that interpreter with
everything in its process. So the daemon hands such work to one worker process (spawned, so it
shares nothing with the loop) and gets back a file of validated binary arrays (``.npy``) that it
maps (``numpy.load(mmap_mode="r")``: no parse, no copy under the interpreter lock).

- :meth:`Intake.parse_spooled`: a request line longer than
  :data:`~cdcr_ctl.daemon.protocol.INLINE_PARSE_BYTES`, spooled to a file by the server thread,
  is parsed and validated; a trajectory's samples come back as a prepared file;
- :meth:`Intake.prepare_file`: a trajectory ``file`` request (CSV/YAML) is read and validated.

Both wait for the worker in the calling (socket) thread; the loop never waits for them.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon.outcome import encode_outcome, outcome
from cdcr_ctl.daemon.protocol import (
    COMMANDS,
    MAX_TRAJECTORY_SAMPLES,
    ProtocolError,
    Request,
    parse_request,
)
from cdcr_ctl.daemon.workers import nice_and_watch_parent, one_worker_pool
from cdcr_ctl.errors import RigError

#: Longest wait for the worker on one request (s): a 10^6-row CSV takes ~10 s on a busy PC.
INTAKE_TIMEOUT_S = 120.0
#: Niceness added to the worker process (it yields the CPU to the loop's process).
WORKER_NICE = 15
#: Suffix of a prepared trajectory: times then (θ, φ) per segment, one row per sample, float64.
PREPARED_SUFFIX = ".prepared.npy"


def _save_prepared(traj: tj.Trajectory, path: str) -> str:
    rows = np.concatenate((traj.t_s[:, None], traj.psi.reshape(traj.n_samples, -1)), axis=1)
    np.save(path, rows)
    return path


def _limit_samples(traj: tj.Trajectory, source: str) -> None:
    if traj.n_samples > MAX_TRAJECTORY_SAMPLES:
        raise ProtocolError(
            f"{source}: {traj.n_samples} samples, more than MAX_TRAJECTORY_SAMPLES ="
            f" {MAX_TRAJECTORY_SAMPLES}",
            field="args.file",
        )


def _fast(arr: np.ndarray, n_segments: int, bend_rad: float, name: str, src: str) -> Any:
    """The trajectory of rows ``arr`` if every check of :meth:`Trajectory.validate` passes,
    vectorised (a 10^6-row trajectory in milliseconds, not seconds); None if one fails (the
    caller then runs the sample-by-sample path, whose error names the sample and field)."""
    if arr.ndim != 2 or arr.shape[1] != 1 + 2 * n_segments or len(arr) < 1:
        return None
    t, th, ph = arr[:, 0], arr[:, 1::2], arr[:, 2::2]
    ok = (
        np.isfinite(arr).all()
        and t[0] >= 0
        and bool(np.all(np.diff(t) > 0))
        and bool(np.all(th >= 0))
        and bool(np.all(th <= bend_rad))
    )
    if not ok:
        return None
    psi = np.stack((th, ph), axis=-1)
    return tj.Trajectory(t, psi, name, src)


def _fast_csv(file: str, n_segments: int, bend_rad: float) -> Any:
    """A CSV trajectory read by numpy (C speed) when its header is the rig's; None otherwise."""
    if not file.lower().endswith(".csv"):
        return None
    expected = ["t_s"] + [
        f"seg{i}_{a}_rad" for i in range(1, n_segments + 1) for a in ("theta", "phi")
    ]
    try:
        with open(file, encoding="utf-8") as f:
            header = ""
            while not header:
                line = f.readline()
                if not line:
                    return None
                line = line.strip()
                header = "" if line.startswith("#") else line
            if [h.strip() for h in header.split(",")] != expected:
                return None
            arr = np.loadtxt(f, delimiter=",", ndmin=2, comments="#", dtype=float)
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return _fast(arr, n_segments, bend_rad, Path(file).stem, file)


def _intake_bug(exc: Exception) -> tuple[Any, ...]:
    """A bug: say what, in the reply."""
    return ("rig", f"intake: {type(exc).__name__}: {exc}")


def _portable(fn: Any, *args: Any) -> tuple[Any, ...]:
    """(in the worker) Run ``fn``; an error comes back as a plain tuple (the project's errors
    do not survive pickling) that :func:`outcome` raises again in the daemon."""
    return encode_outcome(fn, *args, on_bug=_intake_bug)


def _worker_parse(path: str, n_segments: int, bend_rad: float) -> tuple[int, str, dict[str, Any]]:
    """(in the worker) Parse the spooled request at ``path``; a trajectory's samples are
    validated and saved beside it; returns (id, cmd, args) with ``file`` naming them."""
    data = Path(path).read_bytes()
    req = parse_request(data)
    args = req.args.model_dump()
    if req.cmd == "trajectory" and args.get("samples") is not None:
        samples = args.pop("samples")
        src = f"request {args['name']!r}"
        try:
            traj = _fast(np.array(samples, dtype=float), n_segments, bend_rad, args["name"], src)
        except ValueError:  # ragged rows
            traj = None
        if traj is None:
            traj = tj.from_samples(
                samples, n_segments=n_segments, bend_limit_rad=bend_rad, source=src
            )
        args["file"] = _save_prepared(traj, path + PREPARED_SUFFIX)
    return req.id, req.cmd, args


def _worker_file(file: str, out: str, n_segments: int, bend_rad: float) -> str:
    """(in the worker) Read and validate a trajectory file; save it prepared at ``out``."""
    traj = _fast_csv(file, n_segments, bend_rad)
    if traj is None:
        traj = tj.load_trajectory(file, n_segments=n_segments, bend_limit_rad=bend_rad)
    _limit_samples(traj, file)
    return _save_prepared(traj, out)


class Intake:
    """One spawned worker process for the daemon's heavy parsing (see the module docstring).

    ``n_segments`` and ``bend_rad`` are the rig's, for validation. Prepared files live in a
    private temporary directory removed by :meth:`close`; with ``directory`` (another process's
    intake, whose prepared files this one maps) that directory is used and left in place.
    """

    def __init__(self, n_segments: int, bend_rad: float, directory: str | None = None) -> None:
        self.n_segments, self.bend_rad = n_segments, bend_rad
        self._owns_dir = directory is None
        self.dir = Path(directory) if directory else Path(tempfile.mkdtemp(prefix="cdcr-intake-"))
        self._pool: ProcessPoolExecutor | None = None
        self._n = 0

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            # Niced: on a small machine the worker must not take the loop's core.
            self._pool = one_worker_pool(nice_and_watch_parent, (WORKER_NICE, os.getpid()))
        return self._pool

    def start(self) -> Intake:
        """Start the worker now, in the background (a spawn costs ~1 s: better at start-up
        than on the first big request, which waits for it anyway)."""
        self._executor().submit(int, 0)
        return self

    def new_spool(self) -> Path:
        self._n += 1
        return self.dir / f"req{self._n}-{os.getpid()}.json"

    def _call(self, fn: Any, *args: Any) -> Any:
        try:
            out = self._executor().submit(_portable, fn, *args).result(INTAKE_TIMEOUT_S)
        except BrokenProcessPool as exc:
            self._pool = None  # a new worker next time
            raise RigError(f"intake worker died: {exc}") from exc
        except TimeoutError as exc:
            raise RigError(
                f"intake: no answer within INTAKE_TIMEOUT_S = {INTAKE_TIMEOUT_S:g} s"
            ) from exc
        return outcome(out)

    def parse_spooled(self, path: Path) -> Request:
        """The request spooled at ``path``, parsed and validated in the worker; the spool is
        removed. Raises :class:`ProtocolError` (or :class:`RigError`) naming the field."""
        try:
            rid, cmd, args = self._call(_worker_parse, str(path), self.n_segments, self.bend_rad)
        finally:
            with contextlib.suppress(OSError):
                path.unlink()
        return Request(id=rid, cmd=cmd, args=COMMANDS[cmd].model_validate(args))

    def prepare_file(self, file: str) -> str:
        """A trajectory file read and validated in the worker; the prepared file's path."""
        if file.endswith(PREPARED_SUFFIX) and Path(file).parent == self.dir:
            return file
        self._n += 1
        out = str(self.dir / f"file{self._n}{PREPARED_SUFFIX}")
        return self._call(_worker_file, file, out, self.n_segments, self.bend_rad)

    def load(self, prepared: str, name: str) -> tj.Trajectory:
        """The prepared trajectory (validated in the worker), mapped, not parsed."""
        rows = np.load(prepared, mmap_mode="r")
        S = (rows.shape[1] - 1) // 2
        traj = tj.Trajectory(rows[:, 0], rows[:, 1:].reshape(len(rows), S, 2), name, prepared)
        with contextlib.suppress(OSError):
            os.unlink(prepared)
        return traj

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        if not self._owns_dir:
            return
        for p in self.dir.glob("*"):
            with contextlib.suppress(OSError):
                p.unlink()
        with contextlib.suppress(OSError):
            self.dir.rmdir()
