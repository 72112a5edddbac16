"""One owner per bus, socket and simulator link (:mod:`cdcr_ctl.ownership`): a held lock refuses
naming its holder's pid, a dead holder's lock is free again, and a lock held in any of the lock
directories is seen from a process whose own lock directory is another one."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from cdcr_ctl import ownership
from cdcr_ctl.ownership import AlreadyOwned, Ownership, bus_key, check_free, lock_dirs

HOLD = textwrap.dedent(
    """
    import sys
    from cdcr_ctl.ownership import Ownership
    o = Ownership()
    for key in sys.argv[1:]:
        o.take(key)
    print("held", flush=True)
    sys.stdin.read()
    """
)


def holder(*keys: str, env: dict[str, str] | None = None) -> subprocess.Popen:
    """A process that takes ``keys`` and holds them until its stdin closes."""
    p = subprocess.Popen(
        [sys.executable, "-c", HOLD, *keys],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert p.stdout is not None and p.stdout.readline().strip() == "held"
    return p


@pytest.fixture
def lockdir(tmp_path, monkeypatch):
    d = tmp_path / "locks"
    monkeypatch.setenv(ownership.LOCK_DIR_ENV, str(d))
    return d


def test_a_held_key_refuses_naming_the_holder_and_frees_when_it_dies(lockdir):
    key = bus_key("slcan", "/dev/ttyACM0")
    p = holder(key, "socket:/run/cdcr-ctl/control.sock")
    try:
        with pytest.raises(AlreadyOwned, match=rf"already running \(pid {p.pid};") as err:
            Ownership().take(key)
        assert err.value.pid == p.pid and err.value.key == key
        with pytest.raises(AlreadyOwned):
            check_free([key])
        check_free([bus_key("slcan", "/dev/ttyACM1")])  # another bus is free
    finally:
        p.kill()  # no clean-up of its own: the kernel drops the lock
        p.wait()
    with Ownership() as o:
        o.take(key)
        assert o.paths()[0].parent == lockdir
        assert o.paths()[0].read_text().split()[0] == str(__import__("os").getpid())
        with pytest.raises(AlreadyOwned):
            Ownership().take(key)  # a second owner, even in the same process


def test_take_all_takes_none_when_one_is_held(lockdir):
    p = holder("sim:/tmp/x/loadcells")
    try:
        o = Ownership()
        with pytest.raises(AlreadyOwned):
            o.take_all(["sim:/tmp/x/can", "sim:/tmp/x/loadcells"])
        assert o.keys == []
        check_free(["sim:/tmp/x/can"])  # released again
    finally:
        p.communicate("")


def test_a_lock_in_the_service_directory_is_seen_from_a_users_directory(tmp_path, monkeypatch):
    """The service locks in $RUNTIME_DIRECTORY (/run/cdcr-ctl); an operator's scan, which may
    not write there and so keeps its own locks elsewhere, probes it and refuses."""
    service, user = tmp_path / "run-cdcr", tmp_path / "xdg"
    service.mkdir()
    env = {k: v for k, v in os.environ.items() if k != ownership.LOCK_DIR_ENV}
    key = bus_key("socketcan", "can0")
    p = holder(key, env=env | {"RUNTIME_DIRECTORY": str(service)})
    try:
        monkeypatch.delenv(ownership.LOCK_DIR_ENV, raising=False)
        monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
        monkeypatch.setenv("XDG_RUNTIME_DIR", str(user))
        monkeypatch.setattr(ownership, "SYSTEM_DIR", service)
        writable = ownership._writable_dir
        monkeypatch.setattr(ownership, "_writable_dir", lambda d: d != service and writable(d))
        assert lock_dirs()[:2] == [service, user / "cdcr-ctl"]
        with pytest.raises(AlreadyOwned, match=rf"pid {p.pid}"):
            Ownership().take(key)
    finally:
        p.communicate("")
    with Ownership() as o:  # the service gone: the operator's lock goes to its own directory
        assert o.take(key).parent == user / "cdcr-ctl"


def test_relative_channel_paths_are_one_bus(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert bus_key("slcan", "can") == bus_key("slcan", str(tmp_path / "can"))
    assert bus_key("socketcan", "can0") == "can:socketcan:can0"
