"""One owner per CAN bus, control socket and simulator link: exclusive ``flock(2)`` locks.

A process that drives a bus (``cdcr-ctl daemon``), reads it (``cdcr-ctl scan``) or stands in for
its hardware (``cdcr-ctl sim``) first takes an exclusive lock on a small file named after what it
is about to own, and holds it until it exits (the kernel drops a ``flock`` when its process
dies, so a killed owner leaves nothing stale). A second process that asks for a lock someone
holds gets :class:`AlreadyOwned`, naming the holder's pid and what it holds, before it has
opened, sent or linked anything.

Where the lock files live (:func:`lock_dirs`): ``$CDCR_CTL_LOCK_DIR`` when set, else systemd's
``$RUNTIME_DIRECTORY`` (``/run/cdcr-ctl`` under the unit), else ``/run/cdcr-ctl`` when this user
may write there, else ``$XDG_RUNTIME_DIR/cdcr-ctl``, else ``/tmp/cdcr-ctl-UID``. A process takes
its locks in the first of these it can write to, and first checks every other one that exists
for the same lock held by someone else: an operator's ``cdcr-ctl scan`` (no
``$RUNTIME_DIRECTORY``) still sees the service's lock in ``/run/cdcr-ctl`` (it only needs to
open the file for reading, which group ``cdcr`` may).

Keys: ``can:INTERFACE:CHANNEL`` for a bus (:func:`bus_key`), ``socket:PATH`` for a control
socket, ``sim:PATH`` for a simulator's link, ``sim-port:HOST:PORT`` for its network ports. A lock
file's name is the key made safe for a file name plus a hash of the whole key; its content is
the holder's pid and the key (read by the refusal message).

Standard library only (the package's bottom layer): the daemon, the CLI and the simulator use it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import re
import weakref
from pathlib import Path

from cdcr_ctl.errors import RigError

#: Environment variable that overrides where lock files live (tests, several sites on one PC).
LOCK_DIR_ENV = "CDCR_CTL_LOCK_DIR"
#: The unit's RuntimeDirectory (``/run/cdcr-ctl``).
SYSTEM_DIR = Path("/run/cdcr-ctl")


class AlreadyOwned(RigError):
    """The lock for ``key`` is held by process ``pid`` (None when it could not be read)."""

    def __init__(self, key: str, pid: int | None, path: Path) -> None:
        self.key = key
        self.pid = pid
        self.path = path
        who = f"pid {pid}" if pid is not None else "another process"
        super().__init__(f"{key}: already running ({who}; lock {path})")


def bus_key(interface: str, channel: str) -> str:
    """The key of a CAN bus: a device path (an slcan channel, or any channel with a ``/``) is
    made absolute, so the same link named from two working directories is one bus; interface
    names (``can0``) and URLs (``socket://...``) stay as they are."""
    if "://" not in channel and (interface == "slcan" or "/" in channel):
        channel = os.path.abspath(channel)
    return f"can:{interface}:{channel}"


def lock_dirs() -> list[Path]:
    """The directories lock files may be in, the one new locks go to first (module docstring)."""
    if os.environ.get(LOCK_DIR_ENV):
        return [Path(os.environ[LOCK_DIR_ENV])]
    out: list[Path] = []
    runtime = os.environ.get("RUNTIME_DIRECTORY", "")
    if runtime:
        out.append(Path(runtime.split(":")[0]))
    out.append(SYSTEM_DIR)
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    if xdg:
        out.append(Path(xdg) / "cdcr-ctl")
    out.append(Path(f"/tmp/cdcr-ctl-{os.getuid()}"))
    seen: list[Path] = []
    for d in out:
        if d not in seen:
            seen.append(d)
    return seen


def lock_name(key: str) -> str:
    """File name of the lock of ``key``: readable, bounded, unique (a hash of the whole key)."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", key).strip("_")[-60:]
    return f"{safe}.{hashlib.sha256(key.encode()).hexdigest()[:12]}.lock"


def _holder(path: Path) -> int | None:
    with contextlib.suppress(OSError, ValueError):
        first = path.read_text(encoding="utf-8").split()
        return int(first[0]) if first else None
    return None


def _probe(path: Path, key: str) -> None:
    """Raise :class:`AlreadyOwned` if the existing lock file ``path`` is locked by another."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return  # not there, or not ours to read: nothing to probe
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise AlreadyOwned(key, _holder(path), path) from None
        raise
    finally:
        os.close(fd)


class Ownership:
    """Exclusive locks held together; ``take(key)`` adds one, :meth:`release` drops them all.

    A context manager; a process that owns for its lifetime may simply never release.
    """

    def __init__(self) -> None:
        self._held: dict[str, tuple[int, Path]] = {}
        _LIVE.add(self)

    @property
    def keys(self) -> list[str]:
        return list(self._held)

    def paths(self) -> list[Path]:
        return [p for _, p in self._held.values()]

    def take(self, key: str) -> Path:
        """Lock ``key`` or raise :class:`AlreadyOwned` (another process holds it) or
        :class:`RigError` (no lock directory is writable). Returns the lock file's path."""
        if key in self._held:
            return self._held[key][1]
        dirs = lock_dirs()
        name = lock_name(key)
        home: Path | None = None
        for d in dirs:
            if home is None and _writable_dir(d):
                home = d
                continue
            _probe(d / name, key)
        if home is None:
            tried = ", ".join(str(d) for d in dirs)
            raise RigError(f"{key}: no writable directory for its lock file (tried {tried})")
        path = home / name
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o664)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise AlreadyOwned(key, _holder(path), path) from None
            raise RigError(f"{key}: cannot lock {path}: {exc}") from exc
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {key}\n".encode())
        self._held[key] = (fd, path)
        return path

    def take_all(self, keys: list[str]) -> Ownership:
        """Lock every key, or none: the first refusal releases what this call took."""
        taken: list[str] = []
        try:
            for key in keys:
                if key not in self._held:
                    self.take(key)
                    taken.append(key)
        except BaseException:
            for key in taken:
                self._drop(key)
            raise
        return self

    def _drop(self, key: str) -> None:
        fd, _ = self._held.pop(key)
        # The file stays: unlinking it could let a third process lock a fresh inode while a
        # second one already holds an open descriptor of the old one.
        os.close(fd)

    def release(self) -> None:
        for key in list(self._held):
            self._drop(key)

    def _forget_in_child(self) -> None:
        # A forked child shares the parent's open lock files; closing its copies leaves the
        # parent's lock in place (flock(2): released when the last descriptor closes) and lets
        # the lock end with the process that took it, not with its last forked child.
        for fd, _ in self._held.values():
            os.close(fd)
        self._held.clear()

    def __enter__(self) -> Ownership:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


#: Every live :class:`Ownership`, so a forked child can drop its copies of their descriptors.
_LIVE: weakref.WeakSet[Ownership] = weakref.WeakSet()


def _after_fork_in_child() -> None:
    for owner in list(_LIVE):
        owner._forget_in_child()


os.register_at_fork(after_in_child=_after_fork_in_child)


def _writable_dir(d: Path) -> bool:
    """``d`` exists and is writable, or can be made (mode 0750 for a directory of our own)."""
    try:
        d.mkdir(mode=0o750, parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(d, os.W_OK | os.X_OK)


def check_free(keys: list[str]) -> None:
    """Raise :class:`AlreadyOwned` if any of ``keys`` is locked by another process, without
    taking anything (for a tool that only needs to know)."""
    name_dirs = lock_dirs()
    for key in keys:
        for d in name_dirs:
            _probe(d / lock_name(key), key)


__all__ = [
    "LOCK_DIR_ENV",
    "AlreadyOwned",
    "Ownership",
    "bus_key",
    "check_free",
    "lock_dirs",
    "lock_name",
]
